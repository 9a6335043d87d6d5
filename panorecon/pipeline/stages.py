"""The pipeline's stages, each cached by content hash (see ``cache.py``): scene -> points -> train.

A row of an ablation names a scene (and its ERP width; ``prompt:<text>`` generates one, see
``load_row_scene``), a point source with its teacher and view count, and,
when it trains, a ``TrainConfig``. ``points`` runs the source (teacher depths and fusion inside it) and keeps
its cloud (``cloud.ply``: the fused distances along the ERP rays) and report; ``train`` fits Gaussians from that
cloud. Scenes are re-rendered on
load (deterministic, well under a second at the widths suites use) and enter every key by name and width.
Each stage records its wall seconds, the CPU seconds of its process (all threads: on a loaded machine the
cost a run would have had alone, at one thread), the 1-minute load average when it started, and the peak
resident memory of the process that computed it.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..checks import identity
from ..io import atomic_write, peak_rss_mb, write_json
from ..teachers import teacher_fingerprint
from .cache import StageCache, code_digest, stage_key

if TYPE_CHECKING:
    from ..fusion import FusionConfig, FusionOptions

POINTS_CODE = ("geometry", "fusion", "sources", "teachers", "scenes", "metrics", "io")
TRAIN_CODE = POINTS_CODE + ("splat",)


@dataclass(frozen=True)
class Row:
    """One run of an ablation grid. ``train`` holds TrainConfig overrides, or None for a row that trains nothing.
    ``seed`` seeds the simulated teacher's errors and a random point source (the suite sets the training seed,
    ``train["seed"]``, to the same value); it enters the points key only where it changes the stage
    (``sources.uses_seed``), so rows that differ only in seed share a seed-independent point cloud."""

    scene: str
    width: int
    source: str
    teacher: str | None
    views: int | None = None
    train: dict | None = None
    label: str = ""
    extra: dict = field(default_factory=dict, compare=False)  # suite columns carried into results (not keyed)
    depth: tuple | None = None  # (path, metres per unit or None, "distance" | "z"): a real panorama's true depth
    seed: int = 0
    fusion: dict | None = None  # FusionOptions overrides (edge_jump, edge_reach)

    def _scene_params(self) -> dict:
        return {"scene": self.scene, "width": self.width, **({"depth": list(self.depth)} if self.depth else {})}

    def _points_params(self) -> dict:
        return {
            **self._scene_params(),
            "source": self.source,
            "teacher": teacher_fingerprint(self._teacher_for_points()),
            "views": self.views,
            # a seed-independent stage keeps the key it had before suites had seeds (its cache stays valid)
            **({"seed": self.seed} if self._points_seeded() else {}),
            # fusion settings away from the values that behave as before they existed (none: the key as it was)
            **({"fusion": fusion} if (fusion := identity(self.fusion_options())) else {}),
        }

    def _train_params(self) -> dict:
        return {
            **self._scene_params(),
            "teacher": teacher_fingerprint(self.teacher),
            "seed": self.seed,
            "config": identity(self.train_config()),
        }

    def points_key(self) -> str:
        return stage_key("points", self._points_params(), code=POINTS_CODE)

    def train_key(self) -> str:
        return stage_key("train", self._train_params(), (self.points_key(),), TRAIN_CODE)

    def run_id(self) -> str:
        """SHA-256 (20 hex) of the row's settings, without the code digests of the stage keys: the same run on
        any machine and any version of the code (``ablate`` resumes from a results.csv by it; the ``code``
        column says which code computed a row). Settings enter as ``checks.identity`` gives them: an option
        added later, at the value that behaves as before it existed, leaves the identity as it was."""
        params = {"points": self._points_params(), "train": self._train_params() if self.train is not None else None}
        return hashlib.sha256(json.dumps(params, sort_keys=True, default=str).encode()).hexdigest()[:20]

    def train_config(self):
        """The row's ``TrainConfig``."""
        from ..splat.trainer import TrainConfig

        return TrainConfig(**(self.train or {}))

    def fusion_options(self):
        """The row's ``FusionOptions``."""
        from ..fusion import FusionOptions

        return FusionOptions(**(self.fusion or {}))

    def _points_seeded(self) -> bool:
        from ..sources import uses_seed

        return uses_seed(self.source, self.teacher)

    def _teacher_for_points(self) -> str | None:
        from ..sources import get_source

        return self.teacher if get_source(self.source).uses_teacher else None


PROMPT_PREFIX = "prompt:"
TEXT2PANO_MODEL_ENV = "PANORECON_TEXT2PANO_MODEL"


def load_row_scene(name: str, width: int, cache: StageCache, depth: tuple | None = None):
    """A registered scene, dataset panorama or image path (with ``depth`` = ``Row.depth``, its true depth), or
    ``prompt:<preset or text>``: a panorama generated once by
    ``text2pano`` at the row's width (model from $PANORECON_TEXT2PANO_MODEL, steps from
    $PANORECON_TEXT2PANO_STEPS, default 50; cached by prompt, model, seed and settings under the cache's
    text2pano/ folder) and then loaded like any ERP image. Only prompt scenes import the diffusion stack."""
    from ..scenes import load_scene

    if not name.startswith(PROMPT_PREFIX):
        from pathlib import Path

        from ..scenes.real import DepthSpec

        return load_scene(name, width, DepthSpec(Path(depth[0]), depth[1], depth[2]) if depth else None)
    import os

    from ..io import PanoreconInputError
    from ..scenes.real import scene_from_image
    from ..text2pano import GenerateConfig, generate_cached

    model = os.environ.get(TEXT2PANO_MODEL_ENV)
    if not model:
        raise PanoreconInputError(
            f"scene {name!r} is a prompt: set ${TEXT2PANO_MODEL_ENV} to a local diffusers "
            "model folder (see `panorecon generate --help`)"
        )
    cfg = GenerateConfig(width=width, steps=int(os.environ.get("PANORECON_TEXT2PANO_STEPS", 50)))
    png = generate_cached(name[len(PROMPT_PREFIX) :], model, cfg, cache.root / "text2pano")
    return scene_from_image(png, width, name=name, description=f"generated from {name!r} by {model}")


def teacher_depth_fn(scene, teacher_spec: str | None, cache_dir: Path | None = None, seed: int = 0):
    """cameras -> list of z-like depth maps [h, w] float32 from the teacher, for the trainer's Pearson term (scale
    and shift do not matter to it; disparity is inverted), or None without a teacher. With ``cache_dir`` the maps
    of one call are kept in ``cache_dir/<key>.npz``, the key hashing the teacher's fingerprint, the teacher and
    geometry code, the scene's pixels and the cameras, so a network runs once per set of label views. The
    teacher is loaded on the first call that is not cached, with ``seed`` (``get_teacher``; it enters the key where
    the teacher is seeded)."""
    if not teacher_spec:
        return None
    from ..teachers import get_teacher, seeded_teacher, teacher_fingerprint

    teacher = []
    fingerprint = teacher_fingerprint(teacher_spec)

    def compute(cameras):
        if not teacher:
            teacher.append(get_teacher(teacher_spec, seed))
        with np.errstate(divide="ignore"):
            return [
                (v.depth if v.kind != "disparity" else 1.0 / v.depth).astype(np.float32)
                for v in teacher[0].predict_views(scene, cameras)
            ]

    def depth_fn(cameras):
        if cache_dir is None:
            return compute(cameras)
        keyed = [fingerprint, code_digest(("teachers", "geometry"))] + ([seed] if seeded_teacher(teacher_spec) else [])
        h = hashlib.sha256(json.dumps(keyed).encode())
        h.update(np.ascontiguousarray(scene.rgb).tobytes())
        for c in cameras:
            h.update(
                np.asarray([c.width, c.height], np.float64).tobytes()
                + np.asarray(c.K, np.float64).tobytes()
                + np.asarray(c.viewmat, np.float64).tobytes()
            )
        path = Path(cache_dir) / f"{h.hexdigest()[:20]}.npz"
        if path.is_file():
            with np.load(path) as z:
                return [z[f"d{i}"] for i in range(len(cameras))]
        depths = compute(cameras)
        with atomic_write(path) as tmp:
            np.savez(tmp, **{f"d{i}": d for i, d in enumerate(depths)})
        return depths

    return depth_fn


def fusion_config_for(device, options: FusionOptions | None = None) -> FusionConfig:
    """The fusion settings for a run on ``device`` (a torch.device) with ``options`` (default: the defaults): the
    torch CG on a GPU, else SciPy's CG. The device is not part of any stage key: results agree to the solver's
    tolerance."""
    from ..fusion import FusionOptions

    options = options or FusionOptions()
    return options.config(cg_device=str(device)) if device is not None and device.type == "cuda" else options.config()


def run_points(
    cache: StageCache, row: Row, key: str | None = None, provenance: dict | None = None, device=None
) -> dict:
    """The point source's record: report, seconds, peak_rss_mb, cached (bool); cloud.ply in its folder. Without
    a cloud, ``unavailable`` says why: "n/a: ..." (the source cannot run here) or "failed: ..." (it ran and gave
    no point).
    ``key``: the stage key as the caller computed it (a run keeps the keys it started with even if the code
    changes meanwhile); default ``row.points_key()``. ``provenance`` (e.g. the commit) is stored in the record
    when the stage is computed, so a cached result keeps the provenance of the run that made it."""
    key = key or row.points_key()
    done = cache.done("points", key)
    if done is not None:
        return {**done, "cached": True}
    with cache.lock("points", key):  # another process may be computing it: wait, then read its result
        done = cache.done("points", key)
        if done is not None:
            return {**done, "cached": True}
        return {**_compute_points(cache, row, key, provenance, device), "cached": False}


def _compute_points(cache: StageCache, row: Row, key: str, provenance: dict | None, device) -> dict:
    from ..io import PanoreconInputError
    from ..sources import EmptyCloudError, run_source

    t, cpu, load = time.perf_counter(), time.process_time(), os.getloadavg()[0]
    scene = load_row_scene(row.scene, row.width, cache, row.depth)
    scene_s = time.perf_counter() - t
    try:
        pc, report = run_source(
            scene,
            row.source,
            row._teacher_for_points(),
            row.views,
            fusion_config_for(device, row.fusion_options()),
            seed=row.seed,
        )
    except PanoreconInputError as e:
        # a source that cannot run here says why ("n/a: needs a CUDA build ..."); one that ran and gave no point
        # (COLMAP triangulating nothing) has that as the run's outcome ("failed: ...")
        failed = isinstance(e, EmptyCloudError)
        if not (failed or str(e).startswith("n/a")):
            raise
        record = {
            "stage": "points",
            "key": key,
            "unavailable": f"failed: {e}" if failed else str(e),
            "scene_seconds": scene_s,
            "seconds": time.perf_counter() - t,
            "cpu_seconds": time.process_time() - cpu,
            "load_average": load,
            "peak_rss_mb": peak_rss_mb(),
            **(provenance or {}),
        }
        return cache.finish("points", key, record)
    folder = cache.folder("points", key)
    pc.save_ply(folder / "cloud.ply")
    write_json(folder / "report.json", report)
    record = {
        "stage": "points",
        "key": key,
        "report": report,
        "scene_seconds": scene_s,
        "seconds": report["seconds"]["total"],
        "cpu_seconds": time.process_time() - cpu,
        "load_average": load,
        "peak_rss_mb": peak_rss_mb(),
        "points": len(pc),
        **(provenance or {}),
    }
    return cache.finish("points", key, record, files=("cloud.ply", "report.json"))


def run_train(
    cache: StageCache,
    row: Row,
    progress: bool = False,
    key: str | None = None,
    points_key: str | None = None,
    provenance: dict | None = None,
    device=None,
) -> dict:
    """The trainer's record: metrics (metrics.json), seconds, peak_rss_mb, cached; resumes an interrupted run.
    ``provenance`` as in :func:`run_points`; ``device`` a torch.device (None: 'auto')."""
    key = key or row.train_key()
    done = cache.done("train", key)
    if done is not None:
        return {**done, "cached": True}
    points = run_points(cache, row, points_key, provenance, device)
    if "unavailable" in points:  # nothing to train from; the row reads n/a with the source's reason
        return {"stage": "train", "key": key, "unavailable": points["unavailable"], "cached": False}
    with cache.lock("train", key):
        done = cache.done("train", key)
        if done is not None:
            return {**done, "cached": True}
        return {**_compute_train(cache, row, key, points, progress, provenance, device), "cached": False}


def _compute_train(
    cache: StageCache, row: Row, key: str, points: dict, progress: bool, provenance: dict | None, device
) -> dict:
    from ..geometry import PointCloud
    from ..sources import cloud_scale
    from ..splat.trainer import TrainConfig, train

    cpu, load = time.process_time(), os.getloadavg()[0]
    scene = load_row_scene(row.scene, row.width, cache, row.depth)
    cloud_path = cache.folder("points", points["key"]) / "cloud.ply"
    cloud = PointCloud.load_ply(cloud_path)
    inputs = {
        "scene": row.scene,
        "width": row.width,
        "source": row.source,
        "teacher": row.teacher,
        "points_key": points["key"],
    }
    metrics = train(
        scene,
        cloud,
        TrainConfig(**(row.train or {})),
        cache.folder("train", key),
        teacher_depth_fn(scene, row.teacher, cache.root / "teacher_views", row.seed),
        progress=progress,
        inputs=inputs,
        device=device or "auto",
        heldout_scale=cloud_scale(points.get("report") or {}),
    )
    record = {
        "stage": "train",
        "key": key,
        "metrics": metrics,
        "seconds": metrics["seconds"]["total"],
        "cpu_seconds": time.process_time() - cpu,
        "load_average": load,
        "peak_rss_mb": peak_rss_mb(),
        **(provenance or {}),
    }
    return cache.finish("train", key, record, files=("metrics.json", "point_cloud.ply"))
