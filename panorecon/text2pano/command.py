"""``panorecon generate``: one panorama from a prompt or a Table 1 preset."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..io import PanoreconInputError
from .presets import PRESETS


def add_generate_parser(sub) -> None:
    """Register ``panorecon generate`` on the CLI's subparsers."""
    from .. import cli_types as T

    g = sub.add_parser("generate", help="text -> 360° panorama (sliding-window diffusion with a seam block)")
    what = g.add_mutually_exclusive_group(required=True)
    what.add_argument("--prompt", help="scene description (the panorama trigger phrase is prepended)")
    what.add_argument("--preset", choices=sorted(PRESETS), help="one of the paper's Table 1 prompts")
    g.add_argument(
        "--model",
        required=True,
        type=T.in_path,
        help="local diffusers folder, or a model id already in the local HF cache",
    )
    g.add_argument("--lora", default=None, type=T.in_path, help="LoRA weights (loaded with diffusers' own loader)")
    g.add_argument("--steps", type=T.STEPS, default=50)
    g.add_argument("--seed", type=T.SEED, default=0)
    g.add_argument("--width", type=T.ERP_WIDTH, default=2048, help="panorama width (height = width / 2)")
    g.add_argument(
        "--window",
        type=T.int_in(1, 4096, "window"),
        default=64,
        help="sliding-window width in latent columns (8 px each)",
    )
    g.add_argument(
        "--stride", type=T.int_in(1, 4096, "stride"), default=16, help="latent columns between sliding windows"
    )
    g.add_argument("--no-seam-block", action="store_true", help="turn the seam block off (for comparison)")
    g.add_argument("--out", required=True, type=T.out_file, help="output PNG")
    g.set_defaults(fn=run_generate)


def run_generate(args: argparse.Namespace) -> int:
    """Generate, write ``--out`` atomically, print its size and seam score; bad input raises PanoreconInputError."""
    from ..io import write_image
    from ..metrics.seam import seam_discontinuity
    from .generator import GenerateConfig, PanoramaGenerator

    cfg = GenerateConfig(
        width=args.width,
        steps=args.steps,
        seed=args.seed,
        window=args.window,
        stride=args.stride,
        seam_block=not args.no_seam_block,
    )
    cfg.check()
    if args.lora is not None and not Path(args.lora).exists():  # before the model is loaded (minutes)
        raise PanoreconInputError(f"--lora {args.lora}: no such file or folder (expected LoRA weights)")
    gen = PanoramaGenerator.from_pretrained(args.model, args.lora)
    img = gen.generate(args.preset or args.prompt, cfg, progress=True)
    write_image(args.out, img)
    print(f"{args.out}: {img.shape[1]}x{img.shape[0]}, seam score {seam_discontinuity(img):.3f}")
    return 0
