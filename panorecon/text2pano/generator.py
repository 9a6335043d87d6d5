"""Text -> 360° panorama by sliding-window latent diffusion with a seam block (paper §2.2).

Per denoising step: every sliding window of the wide latent gets the UNet's noise prediction (classifier-free
guidance), predictions are averaged where windows overlap, the seam block (rightmost + leftmost half-windows,
denoised together) is blended in with its adaptive weight (``windows.seam_weights``), and one scheduler step
is taken on the whole latent with the merged prediction (merging noise predictions keeps multistep
schedulers valid; for DDIM it equals MultiDiffusion's averaging of the denoised windows). The whole latent is
the full 360°: its last column is the left neighbour of its first.

Decode: every 3x3 conv of the VAE decoder pads circularly along the width (zeros along the height), so with
``decode_pad=0`` the decoder is exactly wrap-consistent: decode(roll(z, k)) = roll(decode(z), 8k). With
``decode_pad > 0`` the latent is also wrapped by that many columns on each side before decoding and the
central region (the panorama) is kept, as diffusers' ``circular_padding`` does.

Components come from a diffusers folder (``model_index.json`` with unet/, vae/, text_encoder/, tokenizer/,
scheduler/) or a model id already in the local Hugging Face cache; nothing is downloaded.
"""

from __future__ import annotations

import copy
import hashlib
import json
from dataclasses import asdict, dataclass
from functools import partial
from pathlib import Path

import numpy as np
import torch

from ..io import PanoreconInputError
from .presets import panorama_prompt
from .windows import seam_columns, seam_weights, window_starts


@dataclass
class GenerateConfig:
    width: int = 2048  # panorama width in pixels (height = width / 2); a multiple of 16
    steps: int = 50
    guidance: float = 7.5
    window: int = 64  # latent columns per sliding window (64 = 512 px; clipped to the latent width)
    stride: int = 16  # latent columns between windows (window 128, stride 16 at width 2048: StitchDiffusion's 9 views)
    seam_block: bool = True
    decode_pad: int = 8  # latent columns of circular padding on each side at decode
    seed: int = 0
    negative_prompt: str = ""

    def check(self) -> None:
        if self.width % 16 or self.width < 32:
            raise PanoreconInputError(f"--width {self.width}: expected a multiple of 16, at least 32")
        if self.steps < 1:
            raise PanoreconInputError(f"--steps {self.steps}: expected at least 1")
        if not 0 < self.stride <= self.window:
            raise PanoreconInputError(f"--window {self.window} --stride {self.stride}: expected 0 < stride <= window")
        if self.decode_pad < 0:
            raise PanoreconInputError(f"decode_pad {self.decode_pad}: expected >= 0")


def _load_error(model: str, why: str) -> PanoreconInputError:
    return PanoreconInputError(
        f"text-to-panorama model {model!r}: {why}. Provide a diffusers folder (model_index.json with unet/, vae/, "
        "text_encoder/, tokenizer/, scheduler/), e.g. made on a machine with network access by "
        "`huggingface-cli download stabilityai/stable-diffusion-2-1-base --local-dir DIR`, and pass --model DIR; "
        "panorecon never downloads at run time."
    )


def _pad_width_circular(pad: int, conv: torch.nn.Conv2d, args: tuple) -> tuple:
    return (torch.nn.functional.pad(args[0], (pad, pad, 0, 0), mode="circular"), *args[1:])


def wrap_width_padding(module: torch.nn.Module) -> None:
    """Make every zero-padded Conv2d in ``module`` pad its input [B, C, H, W] circularly along W (zeros along
    H), in place; idempotent (a conv already changed has no width padding left)."""
    for conv in module.modules():
        if (
            isinstance(conv, torch.nn.Conv2d)
            and conv.padding_mode == "zeros"
            and isinstance(conv.padding, tuple)
            and conv.padding[1] > 0
        ):
            pad_h, pad_w = conv.padding
            conv.padding = (pad_h, 0)
            conv.register_forward_pre_hook(partial(_pad_width_circular, pad_w))


class PanoramaGenerator:
    """Holds the diffusers components; ``generate(prompt, config)`` -> uint8 [H, W, 3] panorama.

    The VAE decoder's convs are switched to circular width padding (``wrap_width_padding``) on construction."""

    def __init__(self, unet, vae, text_encoder, tokenizer, scheduler):
        self.unet, self.vae, self.text_encoder = unet, vae, text_encoder
        self.tokenizer, self.scheduler = tokenizer, scheduler
        self.vae_factor = 2 ** (len(vae.config.block_out_channels) - 1)
        wrap_width_padding(vae.decoder)

    @classmethod
    def from_pretrained(cls, model: str | Path, lora: str | Path | None = None) -> PanoramaGenerator:
        """Load from a local folder or the local HF cache (``local_files_only``); one clear error when absent."""
        from diffusers import AutoencoderKL, DDIMScheduler, UNet2DConditionModel
        from transformers import CLIPTextModel, CLIPTokenizer

        model = str(model)
        path = Path(model)
        if path.exists() and not (path / "model_index.json").is_file() and not (path / "unet").is_dir():
            raise _load_error(model, f"{path} has no model_index.json or unet/ folder")
        if not path.exists() and ("/" not in model or model.startswith((".", "/"))):
            raise _load_error(model, f"no such folder {path.resolve()}")
        if not path.exists():  # a hub id: only the local cache counts; checked before diffusers warns about anything
            from huggingface_hub import try_to_load_from_cache

            if not isinstance(try_to_load_from_cache(model, "unet/config.json"), str):
                raise _load_error(model, "not found locally (not a folder, and not in the local Hugging Face cache)")
        kw = {"local_files_only": True}
        try:
            gen = cls(
                UNet2DConditionModel.from_pretrained(model, subfolder="unet", **kw),
                AutoencoderKL.from_pretrained(model, subfolder="vae", **kw),
                CLIPTextModel.from_pretrained(model, subfolder="text_encoder", **kw),
                CLIPTokenizer.from_pretrained(model, subfolder="tokenizer", **kw),
                DDIMScheduler.from_pretrained(model, subfolder="scheduler", **kw),
            )
        except (OSError, ValueError) as e:
            raise _load_error(model, f"not found locally ({str(e).splitlines()[0]})") from None
        if lora is not None:
            gen.load_lora(lora)
        return gen

    def load_lora(self, lora: str | Path) -> None:
        """Apply a LoRA (diffusers / kohya format) to the UNet and text encoder with diffusers' own loader (it
        needs the ``peft`` package); a LoRA that cannot be applied is a PanoreconInputError saying why."""
        from diffusers import StableDiffusionPipeline

        if not Path(lora).exists():
            raise PanoreconInputError(f"--lora {lora}: no such file or folder")
        # a copy of the scheduler: the pipeline's constructor may rewrite its config (steps_offset, clip_sample)
        pipe = StableDiffusionPipeline(
            vae=self.vae,
            text_encoder=self.text_encoder,
            tokenizer=self.tokenizer,
            unet=self.unet,
            scheduler=copy.deepcopy(self.scheduler),
            safety_checker=None,
            feature_extractor=None,
            requires_safety_checker=False,
        )
        try:
            pipe.load_lora_weights(str(lora))
            pipe.fuse_lora()
        except (OSError, ValueError, KeyError) as e:
            raise PanoreconInputError(
                f"--lora {lora}: could not be applied ({str(e).splitlines()[0]}); expected "
                "LoRA weights for this model (diffusers loads them with peft)"
            ) from None

    @torch.no_grad()
    def encode_prompt(self, text: str) -> torch.Tensor:
        ids = self.tokenizer(
            text, padding="max_length", max_length=self.tokenizer.model_max_length, truncation=True, return_tensors="pt"
        ).input_ids
        return self.text_encoder(ids)[0]

    def _noise_prediction(self, latent, t, cond, uncond, guidance):
        """Classifier-free-guided noise prediction for a batch of windows [B, C, h, w]."""
        both = torch.cat([latent, latent])
        emb = torch.cat([uncond.expand(len(latent), -1, -1), cond.expand(len(latent), -1, -1)])
        eps_u, eps_c = self.unet(both, t, encoder_hidden_states=emb).sample.chunk(2)
        return eps_u + guidance * (eps_c - eps_u)

    @torch.no_grad()
    def denoise(self, prompt: str, cfg: GenerateConfig, progress: bool = False) -> torch.Tensor:
        """Prompt as given to the text encoder -> final latent [1, C, width / 16, width / 8] (float32)."""
        from tqdm import tqdm

        cfg.check()
        h, w = cfg.width // 2 // self.vae_factor, cfg.width // self.vae_factor
        window = min(cfg.window, w)
        stride = min(cfg.stride, window)
        g = torch.Generator().manual_seed(cfg.seed)
        latent = torch.randn(1, self.unet.config.in_channels, h, w, generator=g) * self.scheduler.init_noise_sigma
        cond, uncond = self.encode_prompt(prompt), self.encode_prompt(cfg.negative_prompt)
        starts = window_starts(w, window, stride)
        seam_cols = torch.from_numpy(seam_columns(w, window))
        seam_w = torch.from_numpy(seam_weights(w, window, stride)).float()
        self.scheduler.set_timesteps(cfg.steps)
        for t in tqdm(self.scheduler.timesteps, disable=not progress, desc="denoise"):
            x = self.scheduler.scale_model_input(latent, t)
            eps_sum, weight = torch.zeros_like(latent), torch.zeros(w)
            patches = torch.cat([x[..., s : s + window] for s in starts])
            for s, eps in zip(starts, self._noise_prediction(patches, t, cond, uncond, cfg.guidance)):
                eps_sum[..., s : s + window] += eps
                weight[s : s + window] += 1
            if cfg.seam_block:
                eps = self._noise_prediction(x[..., seam_cols], t, cond, uncond, cfg.guidance)[0]
                eps_sum[..., seam_cols] += eps * seam_w
                weight[seam_cols] += seam_w
            latent = self.scheduler.step(eps_sum / weight, t, latent).prev_sample
        return latent

    @torch.no_grad()
    def decode(self, latent: torch.Tensor, decode_pad: int) -> np.ndarray:
        """Latent [1, C, h, w] -> uint8 [8h, 8w, 3] (8 = ``vae_factor``): the latent wrapped by ``decode_pad``
        columns on each side, decoded by the width-circular decoder, the central 8w columns kept."""
        pad = min(decode_pad, latent.shape[-1])
        wide = torch.cat([latent[..., -pad:], latent, latent[..., :pad]], -1) if pad else latent
        img = self.vae.decode(wide / self.vae.config.scaling_factor).sample
        crop = pad * self.vae_factor
        img = img[..., crop : img.shape[-1] - crop] if crop else img
        if not torch.isfinite(img).all():
            raise FloatingPointError("the decoder produced non-finite pixels")
        return ((img[0].permute(1, 2, 0).clamp(-1, 1) + 1) * 127.5).round().to(torch.uint8).numpy()

    def generate(self, prompt_or_preset: str, cfg: GenerateConfig, progress: bool = False) -> np.ndarray:
        """Preset name or text -> uint8 [width / 2, width, 3] equirectangular panorama."""
        return self.decode(self.denoise(panorama_prompt(prompt_or_preset), cfg, progress), cfg.decode_pad)


def _fingerprint(path: str | None) -> list | str | None:
    """A local file or folder -> [relative path, size, mtime_ns] of every file in it; anything else (a model id
    in the HF cache, None) -> itself. Replacing weights in place changes the fingerprint."""
    if path is None or not Path(path).exists():
        return path
    root = Path(path).resolve()
    files = [root] if root.is_file() else sorted(f for f in root.rglob("*") if f.is_file())
    return [[str(f.relative_to(root)) if f != root else f.name, f.stat().st_size, f.stat().st_mtime_ns] for f in files]


def cache_key(prompt: str, model: str, lora: str | None, cfg: GenerateConfig) -> str:
    """Content hash of what determines a panorama: prompt wording, model and LoRA files, seed, every setting."""
    blob = json.dumps(
        {
            "prompt": panorama_prompt(prompt),
            "model": _fingerprint(str(model)),
            "lora": _fingerprint(str(lora) if lora else None),
            "config": asdict(cfg),
        },
        sort_keys=True,
    )
    return hashlib.sha256(blob.encode()).hexdigest()[:20]


def generate_cached(
    prompt: str, model: str, cfg: GenerateConfig, cache_dir, lora: str | None = None, progress: bool = False
) -> Path:
    """The panorama PNG for these inputs, generated once and kept under ``cache_dir/<cache_key>.png``; the
    seed and all settings travel in ``cfg``."""
    from ..io import write_image

    out = Path(cache_dir) / f"{cache_key(prompt, model, lora, cfg)}.png"
    if not out.is_file():
        img = PanoramaGenerator.from_pretrained(model, lora).generate(prompt, cfg, progress)
        write_image(out, img)
    return out
