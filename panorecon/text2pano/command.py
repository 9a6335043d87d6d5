"""``panorecon generate``: one panorama from a prompt or a Table 1 preset."""

from __future__ import annotations

from pathlib import Path

from ..io import PanoreconInputError


def run_generate(options) -> int:
    """``panorecon generate`` (a ``configs.GenerateCommandConfig``): generate, write ``--out`` atomically,
    print its size and seam score; bad input raises PanoreconInputError."""
    from ..io import write_image
    from ..metrics.seam import seam_discontinuity
    from .generator import GenerateConfig, PanoramaGenerator

    cfg = GenerateConfig(
        width=options.width,
        steps=options.steps,
        seed=options.seed,
        window=options.window,
        stride=options.stride,
        seam_block=not options.no_seam_block,
    )
    cfg.check()
    if options.lora is not None and not Path(options.lora).exists():  # before the model is loaded (minutes)
        raise PanoreconInputError(f"--lora {options.lora}: no such file or folder (expected LoRA weights)")
    gen = PanoramaGenerator.from_pretrained(options.model, options.lora)
    img = gen.generate(options.preset or options.prompt, cfg, progress=True)
    write_image(options.out, img)
    print(f"{options.out}: {img.shape[1]}x{img.shape[0]}, seam score {seam_discontinuity(img):.3f}")
    return 0
