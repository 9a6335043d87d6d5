"""``panorecon generate``: one panorama from a prompt or a Table 1 preset."""

from __future__ import annotations

from pathlib import Path

from ..io import PanoreconInputError


def run_generate(args) -> int:
    """``panorecon generate`` (a ``configs.GenerateCommandConfig``): generate, write ``--out`` atomically,
    print its size and seam score; bad input raises PanoreconInputError."""
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
