"""``panorecon teachers train``: the learned teacher's training, with validation, checkpoints and resume.

Data (``learned/data.py``): crops of scene variants ``NAME@K`` with K from ``first_variant`` (100: the tables
use the base scenes and the population suite ``@1..3``), of the training families; validation on other
variants of the same families (``seen``) and on the held-out families (``unseen``: never in training). Each
step draws ``batch`` crops (with a horizontal flip half the time) from ``(seed, step)``, so a resumed run is the
same run. Adam with a cosine learning-rate decay to a tenth over ``steps``. Validation: per-crop AbsRel and
delta1 of z-depth after the least-squares scale (at least 0) and shift in disparity that the output allows
(``loss.affine_disparity_metrics``), averaged over the crops. Float32 throughout, on the CPU.

Outputs in ``out``: ``ckpt.pt`` (model, optimiser, step, history; resumed when its config matches), and at
the end ``<name>.pt`` (the float32 state dict), ``<name>.onnx`` + ``<name>.json`` (the ``onnx:`` teacher's
config) and ``<name>.train.json`` (config, command, data, parameters, wall time, validation history).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .. import checks as C
from .. import interrupts
from ..checks import opt
from ..io import PanoreconInputError, atomic_write, write_json
from ..scenes.catalog import SYNTHETIC_SCENES
from .data import Crops, CropSpec, cached_crops
from .export import export_onnx
from .loss import affine_disparity_metrics, ssi_loss
from .model import DepthNet, parameter_count

log = logging.getLogger("panorecon.teachers.train")

INDOOR = ("bedroom", "bathroom", "library", "exhibition-hall")
MEAN = (0.485, 0.456, 0.406)  # ImageNet normalisation, as MiDaS / Depth Anything exports expect
STD = (0.229, 0.224, 0.225)
_families = tuple(SYNTHETIC_SCENES)


@dataclass(frozen=True)
class DepthTrainConfig:
    """The learned teacher's settings, checked when built (one ValueError naming the field)."""

    name: str = opt("teacher", "file stem of the exported model (<name>.onnx, .json, .pt, .train.json)")
    families: tuple[str, ...] = opt(
        ("bedroom", "bathroom", "exhibition-hall", "mountain", "grassland", "beach"),
        "scene families trained on",
        choices=_families,
        many=True,
    )
    holdout: tuple[str, ...] = opt(
        ("library", "city-plaza"),
        "scene families never trained on (the 'unseen' validation split); at least one indoor and one outdoor",
        choices=_families,
        many=True,
    )
    first_variant: int = opt(100, "first variant K of the training scenes NAME@K", check=C.int_in(4, 10**6, "variant"))
    train_variants: int = opt(8, "training variants per family: K = first .. first + n - 1", check=C.int_in(1, 1000))
    val_variants: int = opt(
        2,
        "validation variants per family, after the training ones (held-out families: from first)",
        check=C.int_in(1, 100),
    )
    crops_per_scene: int = opt(48, "training crops per scene", check=C.int_in(1, 10_000))
    val_crops_per_scene: int = opt(16, "validation crops per scene", check=C.int_in(1, 10_000))
    size: int = opt(128, "crop and network input size (pixels; a multiple of 16)", check=C.int_in(16, 1024, "size"))
    erp_width: int = opt(512, "ERP width the crops are resampled from (the tables')", check=C.ERP_WIDTH)
    fov_min: float = opt(55.0, "smallest crop field of view (degrees)", check=C.FOV_DEG)
    fov_max: float = opt(95.0, "largest crop field of view (degrees)", check=C.FOV_DEG)
    roll_deg: float = opt(10.0, "crop roll drawn in +- this (degrees)", check=C.float_in(0.0, 90.0, "roll"))
    shift: float = opt(
        0.1, "principal point moved by up to +- this fraction of the size", check=C.float_in(0.0, 0.5, "shift")
    )
    data_seed: int = opt(0, "seed of the crops' cameras", check=C.SEED)
    width: int = opt(16, "network width: channels at full resolution", check=C.int_in(2, 256, "width"))
    steps: int = opt(2000, "optimisation steps", check=C.STEPS)
    batch: int = opt(8, "crops per step", check=C.int_in(1, 1024, "batch"))
    lr: float = opt(1e-3, "Adam learning rate (cosine decay to a tenth)", check=C.float_in(1e-8, 1.0, "learning rate"))
    alpha: float = opt(0.5, "weight of the gradient-matching term", check=C.LOSS_WEIGHT)
    seed: int = opt(0, "seed of the initial weights and the batches", check=C.SEED)
    val_every: int = opt(250, "steps between validations (and at the end)", check=C.STEPS)
    checkpoint_every: int = opt(100, "steps between checkpoints", check=C.STEPS)
    threads: int = opt(1, "torch CPU threads", check=C.int_in(1, 256, "thread count"))

    def __post_init__(self):
        C.validate(self)
        if self.size % 16:
            raise ValueError(f"size = {self.size}: expected a multiple of 16 (the network pools four times)")
        if self.fov_min > self.fov_max:
            raise ValueError(f"fov_min = {self.fov_min}: expected at most fov_max = {self.fov_max}")
        both = sorted(set(self.families) & set(self.holdout))
        if both:
            raise ValueError(f"holdout = {self.holdout!r}: {', '.join(both)} also in families")
        if not self.families:
            raise ValueError("families = (): expected at least one family to train on")
        kinds = {f in INDOOR for f in self.holdout}
        if kinds != {True, False}:
            raise ValueError(f"holdout = {self.holdout!r}: expected at least one indoor and one outdoor family")
        if not self.name or not all(c.isalnum() or c in "-_." for c in self.name):
            raise ValueError(f"name = {self.name!r}: expected a file stem of letters, digits, '-', '_', '.'")

    def digest(self) -> str:
        return hashlib.sha256(json.dumps(dataclasses.asdict(self), sort_keys=True).encode()).hexdigest()[:16]

    def crop_specs(self) -> dict[str, CropSpec]:
        """The three crop sets: ``train``, ``seen`` (later variants of the training families) and ``unseen``
        (the held-out families)."""
        first, n, nv = self.first_variant, self.train_variants, self.val_variants
        common = dict(
            size=self.size,
            erp_width=self.erp_width,
            fov_deg=(self.fov_min, self.fov_max),
            roll_deg=self.roll_deg,
            shift=self.shift,
        )
        names = {
            "train": [f"{f}@{k}" for f in self.families for k in range(first, first + n)],
            "seen": [f"{f}@{k}" for f in self.families for k in range(first + n, first + n + nv)],
            "unseen": [f"{f}@{k}" for f in self.holdout for k in range(first, first + nv)],
        }
        return {
            split: CropSpec(
                tuple(v),
                self.crops_per_scene if split == "train" else self.val_crops_per_scene,
                seed=self.data_seed + i,
                **common,
            )
            for i, (split, v) in enumerate(names.items())
        }


def to_input(rgb: np.ndarray) -> torch.Tensor:
    """RGB uint8 [N, H, W, 3] -> the network's input [N, 3, H, W] float32: / 255, then (x - MEAN) / STD (the
    ``onnx:`` teacher's preprocessing with the exported config)."""
    x = torch.from_numpy(np.ascontiguousarray(rgb)).float().div_(255.0)
    x = (x - torch.tensor(MEAN)) / torch.tensor(STD)
    return x.permute(0, 3, 1, 2).contiguous()


def predict(model: DepthNet, rgb: np.ndarray, batch: int = 16) -> np.ndarray:
    """Eval-mode disparity [N, H, W] float32 of RGB uint8 crops [N, H, W, 3]."""
    model.eval()
    out = []
    with torch.no_grad():
        for i in range(0, len(rgb), batch):
            out.append(model(to_input(rgb[i : i + batch]))[:, 0].numpy())
    return np.concatenate(out) if out else np.zeros((0,) + rgb.shape[1:3], np.float32)


def validate_on(model: DepthNet, crops: Crops) -> dict:
    """Mean per-crop AbsRel and delta1 after the scale-and-shift alignment in disparity; crops with fewer than
    100 valid pixels (all sky) are left out and counted."""
    pred = predict(model, crops.rgb)
    rows = [affine_disparity_metrics(p, z) for p, z in zip(pred, crops.depth)]
    ok = [r for r in rows if math.isfinite(r[0])]
    if not ok:
        return {"abs_rel": float("nan"), "delta1": float("nan"), "crops": 0}
    return {
        "abs_rel": float(np.mean([r[0] for r in ok])),
        "delta1": float(np.mean([r[1] for r in ok])),
        "crops": len(ok),
    }


def batch_indices(seed: int, step: int, n: int, batch: int) -> tuple[np.ndarray, np.ndarray]:
    """The crops of step ``step`` and whether each is flipped: drawn from ``(seed, step)`` alone."""
    rng = np.random.default_rng([seed, step])
    return rng.integers(0, n, batch), rng.random(batch) < 0.5


def learning_rate(cfg: DepthTrainConfig, step: int) -> float:
    return cfg.lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * step / cfg.steps)))


def train_step(model, optimiser, crops: Crops, idx: np.ndarray, flip: np.ndarray, alpha: float) -> dict:
    """One Adam step on the crops ``idx`` (``flip``: mirrored left-right) -> the loss terms (floats). A
    non-finite loss raises FloatingPointError."""
    rgb, depth = crops.rgb[idx].copy(), crops.depth[idx].copy()
    rgb[flip], depth[flip] = rgb[flip][:, :, ::-1], depth[flip][:, :, ::-1]
    model.train()
    loss, terms = ssi_loss(model(to_input(rgb)), torch.from_numpy(np.ascontiguousarray(depth)), alpha)
    if not torch.isfinite(loss):
        raise FloatingPointError(f"non-finite training loss {float(loss)} (terms {terms})")
    optimiser.zero_grad(set_to_none=True)
    loss.backward()
    optimiser.step()
    return {"loss": float(loss.detach()), **terms}


def onnx_config(cfg: DepthTrainConfig) -> dict:
    """The ``onnx:`` teacher's config beside the model: what a user writes for a MiDaS-style export."""
    return {
        "input_size": [cfg.size, cfg.size],
        "mean": list(MEAN),
        "std": list(STD),
        "channels": "RGB",
        "output": "disparity",
        "mode": "affine",
    }


def train_teacher(cfg: DepthTrainConfig, out: str | Path, command: str = "", progress: bool = True) -> dict:
    """Train (or resume) into ``out`` and export; -> the ``<name>.train.json`` record."""
    out = Path(out)
    torch.set_num_threads(cfg.threads)
    specs = cfg.crop_specs()

    def note(split):
        return lambda i, n, name: progress and print(f"render {split} crops: scene {i + 1}/{n} {name}", flush=True)

    crops = {split: cached_crops(spec, note(split)) for split, spec in specs.items()}
    data = {
        split: {
            "scenes": list(spec.scenes),
            "crops": len(crops[split]),
            "render_seconds": round(crops[split].seconds, 1),
            "cache": spec.digest(),
        }
        for split, spec in specs.items()
    }
    if progress:
        for split, d in data.items():
            print(f"{split}: {d['crops']} crops of {len(d['scenes'])} scenes (rendered in {d['render_seconds']} s)")

    torch.manual_seed(cfg.seed)
    model = DepthNet(cfg.width)
    optimiser = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    ckpt_path = out / "ckpt.pt"
    start, history, seconds = 0, [], 0.0
    if ckpt_path.is_file():
        state = torch.load(ckpt_path, weights_only=True)
        if state.get("config") != cfg.digest():
            raise PanoreconInputError(
                f"{ckpt_path}: a checkpoint of another config ({state.get('config')}, this one {cfg.digest()}); "
                "use another --out or --overwrite"
            )
        model.load_state_dict(state["model"])
        optimiser.load_state_dict(state["optimiser"])
        start, history, seconds = int(state["step"]), json.loads(state["history"]), float(state["seconds"])
        if progress:
            print(f"resumed from {ckpt_path} at step {start}")

    def save(step: int) -> str:
        with atomic_write(ckpt_path) as tmp:
            torch.save(
                {
                    "config": cfg.digest(),
                    "model": model.state_dict(),
                    "optimiser": optimiser.state_dict(),
                    "step": step,
                    "history": json.dumps(history),
                    "seconds": seconds + time.perf_counter() - t0,
                },
                tmp,
            )
        return str(ckpt_path)

    t0 = time.perf_counter()
    train = crops["train"]
    running = []
    for step in interrupts.at_step_boundaries(range(start, cfg.steps), cfg.steps, save):
        for g in optimiser.param_groups:
            g["lr"] = learning_rate(cfg, step)
        terms = train_step(model, optimiser, train, *batch_indices(cfg.seed, step, len(train), cfg.batch), cfg.alpha)
        running.append(terms["loss"])
        done = step + 1
        if done % cfg.val_every == 0 or done == cfg.steps:
            row = {
                "step": done,
                "loss": float(np.mean(running)),
                "seconds": round(seconds + time.perf_counter() - t0, 1),
                **{f"{s}_{k}": v for s in ("seen", "unseen") for k, v in validate_on(model, crops[s]).items()},
            }
            history.append(row)
            running = []
            if progress:
                print(
                    f"step {done}/{cfg.steps}: loss {row['loss']:.4f}; val seen AbsRel {row['seen_abs_rel']:.4f} "
                    f"d1 {row['seen_delta1']:.3f}; unseen AbsRel {row['unseen_abs_rel']:.4f} "
                    f"d1 {row['unseen_delta1']:.3f}; {row['seconds']:.0f} s",
                    flush=True,
                )
        if done % cfg.checkpoint_every == 0 or done == cfg.steps:
            save(done)
    seconds += time.perf_counter() - t0

    model.eval()
    state_dict = {k: v.detach().clone() for k, v in model.state_dict().items()}
    with atomic_write(out / f"{cfg.name}.pt") as tmp:
        torch.save(state_dict, tmp)
    export_onnx(model, cfg.size, out / f"{cfg.name}.onnx")
    write_json(out / f"{cfg.name}.json", onnx_config(cfg))
    record = {
        "command": command,
        "config": dataclasses.asdict(cfg),
        "parameters": parameter_count(model),
        "input_size": [cfg.size, cfg.size],
        "train_seconds": round(seconds, 1),
        "threads": cfg.threads,
        "data": data,
        "history": history,
        "final": history[-1] if history else None,
        "torch": torch.__version__,
    }
    write_json(out / f"{cfg.name}.train.json", record)
    return record
