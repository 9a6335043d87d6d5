"""Text -> 360° panorama: sliding-window latent diffusion with a seam block (paper §2.2)."""

from .generator import GenerateConfig, PanoramaGenerator, generate_cached
from .presets import PRESETS, TRIGGER, panorama_prompt
from .windows import seam_columns, seam_weights, window_starts

__all__ = [
    "GenerateConfig",
    "PanoramaGenerator",
    "generate_cached",
    "PRESETS",
    "TRIGGER",
    "panorama_prompt",
    "seam_columns",
    "seam_weights",
    "window_starts",
]
