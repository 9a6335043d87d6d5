"""The eight prompts of the paper's Table 1, and how a prompt is worded for panorama generation."""

from __future__ import annotations

# Table 1 (scene names as panorecon's synthetic scenes use them)
PRESETS = {
    "bathroom": "A luxury bathroom",
    "bedroom": "A bedroom",
    "mountain": "A mountain landscape",
    "grassland": "Hulunbuir grassland with blue sky",
    "beach": "Waves on the beach",
    "library": "Beijing city library",
    "exhibition-hall": "An indoor exhibition hall with multiple art installations, glass display cases, large posters "
    "on the wall, and spotlights",
    "city-plaza": "An outdoor city plaza with a large central fountain, stone benches, tiled ground, and modern "
    "street lamps surrounded by open space",
}

# The panorama trigger phrase, prepended to every prompt (a panorama LoRA's own trigger word goes here too).
TRIGGER = "360-degree equirectangular panorama"


def panorama_prompt(prompt_or_preset: str, trigger: str = TRIGGER) -> str:
    """A preset name or free text -> the prompt given to the text encoder: '<trigger>, <prompt>'."""
    text = PRESETS.get(prompt_or_preset, prompt_or_preset).strip()
    if not text:
        raise ValueError("empty prompt: give text or one of the presets " + ", ".join(PRESETS))
    return f"{trigger}, {text}" if trigger else text
