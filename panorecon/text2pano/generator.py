"""Text -> 360° panorama by sliding-window latent diffusion with a seam block (paper §2.2).

Per denoising step: every sliding window of the wide latent gets the UNet's noise prediction (classifier-free
guidance), predictions are averaged where windows overlap, the seam block (rightmost + leftmost half-windows,
denoised together) is blended in with its adaptive weight (``windows.seam_weights``), and one scheduler step
is taken on the whole latent with the merged prediction (merging noise predictions keeps multistep
schedulers valid; for DDIM it equals MultiDiffusion's averaging of the denoised windows). At decode the
latent is padded circularly by ``decode_pad`` columns on each side, decoded, and the central region kept, so
the decoder sees across the wrap.

Components come from a diffusers folder (``model_index.json`` with unet/, vae/, text_encoder/, tokenizer/,
scheduler/) or a model id already in the local Hugging Face cache; nothing is downloaded.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from ..io import PanoreconInputError
from .presets import panorama_prompt
from .windows import seam_columns, seam_weights, window_starts


@dataclass
class GenerateConfig:
    width: int = 2048  # panorama width in pixels (height = width / 2); a multiple of 8 x window stride
    steps: int = 50
    guidance: float = 7.5
    window: int = 64  # latent columns per sliding window (64 = 512 px)
    stride: int = 16  # latent columns between windows
    seam_block: bool = True
    decode_pad: int = 8  # latent columns of circular padding on each side at decode
    seed: int = 0
    negative_prompt: str = ""

    def check(self) -> None:
        if self.width % 16 or self.width < 32:
            raise PanoreconInputError(f"--width {self.width}: expected a multiple of 16, at least 32")
        if self.steps < 1:
            raise PanoreconInputError(f"--steps {self.steps}: expected at least 1")


def _load_error(model: str, why: str) -> PanoreconInputError:
    return PanoreconInputError(
        f"text-to-panorama model {model!r}: {why}. Provide a diffusers folder (model_index.json with unet/, vae/, "
        "text_encoder/, tokenizer/, scheduler/), e.g. made on a machine with network access by "
        "`huggingface-cli download stabilityai/stable-diffusion-2-1-base --local-dir DIR`, and pass --model DIR; "
        "panorecon never downloads at run time.")


class PanoramaGenerator:
    """Holds the diffusers components; ``generate(prompt, config)`` -> uint8 [H, W, 3] panorama."""

    def __init__(self, unet, vae, text_encoder, tokenizer, scheduler):
        self.unet, self.vae, self.text_encoder, self.tokenizer, self.scheduler = unet, vae, text_encoder, tokenizer, scheduler
        self.vae_factor = 2 ** (len(vae.config.block_out_channels) - 1)

    @classmethod
    def from_pretrained(cls, model: str | Path, lora: str | Path | None = None) -> "PanoramaGenerator":
        """Load from a local folder or the local HF cache (``local_files_only``); one clear error when absent."""
        from diffusers import AutoencoderKL, DDIMScheduler, UNet2DConditionModel
        from transformers import CLIPTextModel, CLIPTokenizer

        model = str(model)
        path = Path(model)
        if path.exists() and not (path / "model_index.json").is_file() and not (path / "unet").is_dir():
            raise _load_error(model, f"{path} has no model_index.json or unet/ folder")
        if not path.exists() and ("/" not in model or model.startswith((".", "/"))):
            raise _load_error(model, f"no such folder {path.resolve()}")
        kw = {"local_files_only": True}
        try:
            gen = cls(UNet2DConditionModel.from_pretrained(model, subfolder="unet", **kw),
                      AutoencoderKL.from_pretrained(model, subfolder="vae", **kw),
                      CLIPTextModel.from_pretrained(model, subfolder="text_encoder", **kw),
                      CLIPTokenizer.from_pretrained(model, subfolder="tokenizer", **kw),
                      DDIMScheduler.from_pretrained(model, subfolder="scheduler", **kw))
        except (OSError, ValueError) as e:
            raise _load_error(model, f"not found locally ({str(e).splitlines()[0]})") from None
        if lora is not None:
            gen.load_lora(lora)
        return gen

    def load_lora(self, lora: str | Path) -> None:
        """Apply a LoRA (diffusers / kohya format) to the UNet and text encoder with diffusers' own loader."""
        from diffusers import StableDiffusionPipeline

        if not Path(lora).exists():
            raise PanoreconInputError(f"--lora {lora}: no such file or folder")
        pipe = StableDiffusionPipeline(vae=self.vae, text_encoder=self.text_encoder, tokenizer=self.tokenizer,
                                       unet=self.unet, scheduler=self.scheduler, safety_checker=None,
                                       feature_extractor=None, requires_safety_checker=False)
        pipe.load_lora_weights(str(lora))
        pipe.fuse_lora()

    @torch.no_grad()
    def encode_prompt(self, text: str) -> torch.Tensor:
        ids = self.tokenizer(text, padding="max_length", max_length=self.tokenizer.model_max_length,
                             truncation=True, return_tensors="pt").input_ids
        return self.text_encoder(ids)[0]

    def _noise_prediction(self, latent, t, cond, uncond, guidance):
        """Classifier-free-guided noise prediction for a batch of windows [B, C, h, w]."""
        both = torch.cat([latent, latent])
        emb = torch.cat([uncond.expand(len(latent), -1, -1), cond.expand(len(latent), -1, -1)])
        eps_u, eps_c = self.unet(both, t, encoder_hidden_states=emb).sample.chunk(2)
        return eps_u + guidance * (eps_c - eps_u)

    @torch.no_grad()
    def denoise(self, prompt: str, cfg: GenerateConfig, progress: bool = False) -> torch.Tensor:
        """The denoising loop -> final latent [1, C, h, w] (float32)."""
        from tqdm import tqdm

        cfg.check()
        h, w = cfg.width // 2 // self.vae_factor, cfg.width // self.vae_factor
        window = min(cfg.window, w)
        g = torch.Generator().manual_seed(cfg.seed)
        latent = torch.randn(1, self.unet.config.in_channels, h, w, generator=g) * self.scheduler.init_noise_sigma
        cond, uncond = self.encode_prompt(prompt), self.encode_prompt(cfg.negative_prompt)
        starts = window_starts(w, window, cfg.stride)
        seam_cols = torch.from_numpy(seam_columns(w, window))
        seam_w = torch.from_numpy(seam_weights(w, window, cfg.stride)).float()
        self.scheduler.set_timesteps(cfg.steps)
        for t in tqdm(self.scheduler.timesteps, disable=not progress, desc="denoise"):
            x = self.scheduler.scale_model_input(latent, t)
            eps_sum, weight = torch.zeros_like(latent), torch.zeros(w)
            patches = torch.cat([x[..., s:s + window] for s in starts])
            for s, eps in zip(starts, self._noise_prediction(patches, t, cond, uncond, cfg.guidance)):
                eps_sum[..., s:s + window] += eps
                weight[s:s + window] += 1
            if cfg.seam_block:
                eps = self._noise_prediction(x[..., seam_cols], t, cond, uncond, cfg.guidance)[0]
                eps_sum[..., seam_cols] += eps * seam_w
                weight[seam_cols] += seam_w
            latent = self.scheduler.step(eps_sum / weight, t, latent).prev_sample
        return latent

    @torch.no_grad()
    def decode(self, latent: torch.Tensor, decode_pad: int) -> np.ndarray:
        """Latent [1, C, h, w] -> uint8 [H, W, 3]: circular padding of ``decode_pad`` columns, central crop."""
        pad = min(decode_pad, latent.shape[-1])
        wide = torch.cat([latent[..., -pad:], latent, latent[..., :pad]], -1) if pad else latent
        img = self.vae.decode(wide / self.vae.config.scaling_factor).sample
        crop = pad * self.vae_factor
        img = img[..., crop:img.shape[-1] - crop] if crop else img
        if not torch.isfinite(img).all():
            raise FloatingPointError("the decoder produced non-finite pixels")
        return ((img[0].permute(1, 2, 0).clamp(-1, 1) + 1) * 127.5).round().to(torch.uint8).numpy()

    def generate(self, prompt_or_preset: str, cfg: GenerateConfig, progress: bool = False) -> np.ndarray:
        """Preset name or text -> uint8 [width / 2, width, 3] equirectangular panorama."""
        return self.decode(self.denoise(panorama_prompt(prompt_or_preset), cfg, progress), cfg.decode_pad)


def cache_key(prompt: str, model: str, lora: str | None, cfg: GenerateConfig) -> str:
    """Content hash of what determines a panorama: prompt wording, model, LoRA, every setting."""
    blob = json.dumps({"prompt": panorama_prompt(prompt), "model": str(Path(model).resolve() if Path(model).exists() else model),
                       "lora": str(lora) if lora else None, "config": asdict(cfg)}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:20]


def generate_cached(prompt: str, model: str, cfg: GenerateConfig, cache_dir, lora: str | None = None,
                    progress: bool = False) -> Path:
    """The panorama PNG for these inputs, generated once and kept under ``cache_dir/<key>.png``."""
    from ..io import write_image

    out = Path(cache_dir) / f"{cache_key(prompt, model, lora, cfg)}.png"
    if not out.is_file():
        img = PanoramaGenerator.from_pretrained(model, lora).generate(prompt, cfg, progress)
        write_image(out, img)
    return out
