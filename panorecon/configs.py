"""One typed config per ``panorecon`` command: the single declaration of its settings.

Each command's options are the fields of its frozen dataclass (``checks.opt``: type, default, help, check or
choices, path role); ``panorecon.cli`` makes the parser from them, and a suite file's row is checked against the
same fields (``evaluation/suite.py``: ``SceneArgs``, ``SourceArgs`` and ``TrainConfig``). Shared parts are nested:
the scene and its true depth (``SceneArgs``), the point source and teacher (``SourceArgs``), the trainer
(``splat.trainer.TrainConfig``). Building a config checks it (``__post_init__``), so a command's code below the
parser gets values that are already valid.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from . import checks as C
from .checks import nest, opt
from .device import DEVICE_NAME
from .fusion import FusionOptions
from .learned.train import DepthTrainConfig
from .splat.trainer import TrainConfig
from .teachers.spec import TEACHER_SPEC, TeacherSpec

# what each command writes into its --out folder (relative fnmatch patterns; ``*`` crosses folders): the path
# collision check (cli_types.path_collisions) and the run-folder claim (io.runs.claim_run) both use them
RENDER_WRITES = ("pano.png", "mask.png", "distance.npy", "scene.json", "heldout_*.npz")
TRAIN_WRITES = (
    "*_cloud.ply",
    "*_report.json",
    "point_cloud.ply",
    "sky.png",
    "cameras.json",
    "metrics.json",
    "ckpt.pt",
    "ckpt.pt.bad",
    "renders/*",
)
DEMO_WRITES = (*RENDER_WRITES, *TRAIN_WRITES, "gt_cloud.ply", "gt_cloud.png", "*_cloud.png", "panorama.png")
ABLATE_WRITES = (
    "results.csv",
    "results.md",
    "*.png",
    "report.html",
    "cache/*",
    "*/results.csv",
    "*/results.md",
    "*/*.png",
    "*/report.html",
    "verify.md",
    "*/verify.md",
)
MAX_RUNS = 10_000  # a larger suite needs an explicit --max-runs
# `train`'s point-source views where they differ from the source's own default (Fibonacci: 20, the paper's):
# 40 views give each direction twice the overlaps to average the teacher's per-view error over (issue 19;
# docs/benchmarks.md "Time to quality")
TRAIN_VIEWS = {"fibonacci": 40}

DEPTH_GROUP = "true depth of a real panorama"
TEACHER_HELP = (
    "sim:<profile> | onnx:<model.onnx> | file:<depth>[?scale=S] | hf:<model id or folder> | moge:<checkpoint> "
    "(see `panorecon teachers list`)"
)


def _device() -> dataclasses.Field:
    return opt(
        "auto",
        "auto (CUDA when present), cpu or cuda[:K]: where fusion's CG and training run",
        check=DEVICE_NAME,
        suite=False,
    )


def _out_dir(writes: tuple[str, ...], help: str = "output folder", default=None):
    return opt(default, help, role="out-dir", writes=writes, required=default is None, suite=False)


def _overwrite(help: str = "delete another run's outputs in --out first"):
    return opt(False, help, suite=False)


@dataclass(frozen=True)
class SceneArgs:
    """A scene and, for a real panorama, its true depth (see ``panorecon.io.depth``)."""

    scene: str | None = opt(
        None,
        "scene name (see `panorecon scenes list`), a dataset panorama or an ERP image path",
        role="scene",
        positional=True,
        required=True,
    )
    width: int | None = opt(
        None, "ERP width in pixels (height = width / 2; default: the scene's own)", check=C.ERP_WIDTH
    )
    depth: str | None = opt(
        None,
        "true depth file (16-bit .png, .exr, .npy) of the same pixel size as the image",
        role="in",
        group=DEPTH_GROUP,
    )
    depth_scale: float | None = opt(
        None,
        "metres per stored unit (default 0.001 for 16-bit PNG, i.e. millimetres as Structured3D; Stanford2D3D: "
        "1/512 = 0.001953125; Matterport3D: 1/4000 = 0.00025; 1 for .exr/.npy)",
        check=C.DEPTH_SCALE,
        group=DEPTH_GROUP,
    )
    depth_kind: str | None = opt(
        None, "distance along the ray (default) or cube-face z-depth", choices=("distance", "z"), group=DEPTH_GROUP
    )

    def __post_init__(self):
        C.validate(self)
        if self.depth is None and (self.depth_scale is not None or self.depth_kind is not None):
            raise ValueError("--depth-scale/--depth-kind without --depth: expected a depth file to read")

    def depth_spec(self):
        """The true depth as a ``scenes.real.DepthSpec`` (None without --depth)."""
        if self.depth is None:
            return None
        from .scenes.real import DepthSpec

        return DepthSpec(Path(self.depth), self.depth_scale, self.depth_kind or "distance")

    def load(self, width: int | None = None):
        """The scene at ``width`` (default: this config's width) -> ``scenes.Scene``."""
        from .scenes import load_scene

        return load_scene(self.scene, width or self.width, self.depth_spec())

    def identity(self) -> dict:
        """The scene, width and depth options as JSON scalars, files by their SHA-256 (what decides results)."""
        import os

        from .io import file_sha256

        def ident(path):
            return None if path is None else f"{path}#{file_sha256(path)[:16]}" if os.path.isfile(path) else str(path)

        return {
            "scene": ident(self.scene),
            "width": self.width,
            "depth": ident(self.depth),
            "depth_scale": self.depth_scale,
            "depth_kind": self.depth_kind,
        }


@dataclass(frozen=True)
class SourceArgs:
    """A point source, its depth teacher and view count."""

    source: str | None = opt(None, "point source (see `panorecon sources list`)", required=True)
    teacher: str | None = opt(None, TEACHER_HELP, role="teacher", check=TEACHER_SPEC)
    views: int | None = opt(
        None, "views of the point source (fibonacci, latlong; default: the source's own)", check=C.VIEWS
    )
    fusion: FusionOptions = nest(FusionOptions)

    def __post_init__(self):
        C.validate(self)
        if self.teacher is not None:  # parsed once, here: what runs below gets the TeacherSpec
            object.__setattr__(self, "teacher", TeacherSpec(str(self.teacher)))


@dataclass(frozen=True)
class ScenesListConfig:
    root: str | None = opt(
        None,
        "list instead the dataset panoramas (Stanford2D3D, Structured3D, Matterport3D) found under this folder, "
        "as scene names",
        role="in",
    )


@dataclass(frozen=True)
class ScenesCheckConfig:
    root: str | None = opt(
        None, "a dataset folder (as for `scenes list --root`)", role="in", positional=True, required=True
    )
    width: int = opt(512, "ERP width to check at", check=C.int_in(64, 8192, "width", even=True))
    json: str | None = opt(None, "also write the results as JSON to this file", role="out-file")

    def __post_init__(self):
        C.validate(self)


@dataclass(frozen=True)
class RenderConfig:
    scene: SceneArgs = nest(SceneArgs)
    out: str | None = _out_dir(RENDER_WRITES)
    overwrite: bool = _overwrite()
    heldout: int = opt(
        8,
        "synthetic scenes: true held-out views to record (as `train --heldout`; 0: none)",
        check=C.int_in(0, 1000, "held-out view count"),
    )
    heldout_res: tuple[int, ...] = opt(
        (128,), "sizes of the recorded held-out views (each a `train --res`)", check=C.LABEL_RES, many=True
    )
    heldout_seeds: tuple[int, ...] = opt(
        (0,),
        "training seeds whose held-out views to record (each seed draws its own cameras; a suite's seeds)",
        check=C.SEED,
        many=True,
    )

    def __post_init__(self):
        C.validate(self)


@dataclass(frozen=True)
class GtCloudConfig:
    scene: SceneArgs = nest(SceneArgs)
    out: str | None = opt(None, "output .ply", role="out-file", required=True)


@dataclass(frozen=True)
class InspectConfig:
    cloud: str | None = opt(None, "a .ply point cloud", role="in", positional=True, required=True)
    screenshot: str | None = opt(None, "render off-screen to this PNG instead of opening a window", role="out-file")
    color: str | None = opt(None, "colour by this per-point scalar (e.g. view_id, error) instead of RGB")
    point_size: float = opt(2.0, "point size in pixels", check=C.float_in(0.1, 100.0, "point size"))
    clip_z: float | None = opt(None, "hide points above this height (metres), e.g. a ceiling", check=C.FINITE_FLOAT)

    def __post_init__(self):
        C.validate(self)


@dataclass(frozen=True)
class ListConfig:
    """A listing command without options."""


TEACHER_TRAIN_WRITES = ("ckpt.pt", "*.pt", "*.onnx", "*.json")


@dataclass(frozen=True)
class TeachersTrainConfig:
    train: DepthTrainConfig = nest(DepthTrainConfig)
    no_progress: bool = opt(False, "no progress lines", suite=False)
    out: str | None = _out_dir(
        TEACHER_TRAIN_WRITES, "output folder (ckpt.pt, resumed; <name>.onnx, .json, .pt, .train.json)"
    )
    overwrite: bool = _overwrite()


@dataclass(frozen=True)
class PointsConfig:
    scene: SceneArgs = nest(SceneArgs)
    source: SourceArgs = nest(SourceArgs)
    view_size: int | None = opt(
        None, "perspective view size in pixels (default: ERP width / 4, at most 512)", check=C.VIEW_SIZE
    )
    max_points: int | None = opt(
        None,
        "thin the cloud evenly over the sphere (Fibonacci lattice) to at most this many points",
        check=C.int_in(1, None, "point count"),
    )
    out: str | None = opt(None, "output .ply", role="out-file", required=True, suite=False)
    report: str | None = opt(None, "output report .json", role="out-file", suite=False)
    distance_out: str | None = opt(
        None, "also write the fused ERP ray distance (.npy, float32 metres)", role="out-file", suite=False
    )
    device: str = _device()

    def __post_init__(self):
        C.validate(self)


@dataclass(frozen=True)
class TrainCommandConfig:
    scene: SceneArgs = nest(SceneArgs)
    source: SourceArgs = nest(
        SourceArgs,
        views={
            "help": f"views of the point source (default: {', '.join(f'{v} for {k}' for k, v in TRAIN_VIEWS.items())}"
            ", the source's own otherwise)"
        },
    )
    train: TrainConfig = nest(TrainConfig)
    device: str = _device()
    no_progress: bool = opt(False, "no progress bar", suite=False)
    out: str | None = _out_dir(TRAIN_WRITES, "output folder (point_cloud.ply, renders/, metrics.json; resumes ckpt.pt)")
    overwrite: bool = _overwrite()

    def views(self) -> int | None:
        """The point source's views: as given, else TRAIN_VIEWS' for the source, else None (its own)."""
        return self.source.views if self.source.views is not None else TRAIN_VIEWS.get(self.source.source)


@dataclass(frozen=True)
class AblateConfig:
    suite: tuple[str, ...] = opt(
        (),
        "suite files, e.g. eval/suites/quick.toml; several run as one grid, a run they share once, each suite's "
        "outputs in OUT/<file stem>/ (with --from-csv: one, optional, for its titles)",
        role="in",
        positional=True,
        many=True,
    )
    out: str | None = _out_dir(ABLATE_WRITES, "output folder (its cache/ makes a rerun or a resumed run cheap)")
    jobs: int = opt(1, "parallel worker processes", check=C.JOBS)
    threads: int = opt(
        0,
        "torch threads per worker (0: cores // jobs); results are bit-identical only at one thread count",
        check=C.int_in(0, 1024, "thread count"),
    )
    set: tuple[str, ...] = opt(
        (),
        "override a suite's [defaults] setting in every suite given, e.g. --set iters=10000 (repeatable; the runs "
        "are then other runs, with their own results)",
        many=True,
        repeat=True,
        metavar="KEY=VALUE",
    )
    engine: str = opt(
        "local", "local process pool, or Dask (a LocalCluster, or --scheduler ADDRESS)", choices=("local", "dask")
    )
    scheduler: str | None = opt(None, "address of a running Dask scheduler (with --engine dask)")
    cache: str | None = opt(
        None, "stage cache folder shared between suites (default OUT/cache)", role="out-dir", writes=("*",)
    )
    no_progress: bool = opt(False, "no progress bar")
    max_runs: int = opt(
        MAX_RUNS, "refuse a suite that expands to more runs than this", check=C.int_in(1, None, "run count")
    )
    root: str | None = opt(None, "dataset root for a suite's {root} (default $PANORECON_DATASET_ROOT)", role="in")
    scene_dir: str | None = opt(
        None,
        "read each suite scene NAME from its `panorecon render` folder DIR/NAME instead of building it (a machine "
        "without Open3D, e.g. a GPU machine); the rows' scene is then the folder, with its own runs",
        role="in",
        metavar="DIR",
    )
    unpinned: bool = opt(
        False,
        "read each suite without its [pinned] settings: a committed table rerun under today's defaults (give it "
        "another --out)",
    )
    retry_unavailable: bool = opt(
        False, "try again the runs that read n/a in results.csv (their source could not run where they were made)"
    )
    verify: int = opt(
        0,
        "recompute this many committed rows of each suite's results.csv on the current code and set each metric "
        "beside its committed value, with a verdict against the seed-to-seed spread (OUT/.../verify.md); nothing "
        "else is run or rewritten",
        check=C.int_in(0, 10_000, "row count"),
    )
    from_csv: str | None = opt(
        None,
        "re-render results.md, report.html and plots from a results.csv into --out; nothing is run",
        role="in",
        metavar="CSV",
    )
    device: str = _device()

    def __post_init__(self):
        C.validate(self)


@dataclass(frozen=True)
class BenchConfig:
    quick: bool = opt(False, "tiny sizes (CI)")
    suite: str = opt("eval/suites/bench.toml", "the tiny ablation suite", role="in")
    baseline: str = opt("benchmarks/baseline.json", "the stored baseline to compare with", role="in")
    out: str | None = opt(None, "also write the result JSON here", role="out-file")
    update_baseline: bool = opt(False, "store this run as the baseline")
    device: str = _device()


def _presets() -> tuple[str, ...]:
    from .text2pano.presets import PRESETS

    return tuple(sorted(PRESETS))


@dataclass(frozen=True)
class GenerateCommandConfig:
    prompt: str | None = opt(None, "scene description (the panorama trigger phrase is prepended)", exclusive="what")
    preset: str | None = opt(None, "one of the paper's Table 1 prompts", choices=_presets, exclusive="what")
    model: str | None = opt(
        None, "local diffusers folder, or a model id already in the local HF cache", role="in", required=True
    )
    lora: str | None = opt(None, "LoRA weights (loaded with diffusers' own loader)", role="in")
    steps: int = opt(50, "denoising steps", check=C.STEPS)
    seed: int = opt(0, "random seed", check=C.SEED)
    width: int = opt(2048, "panorama width (height = width / 2)", check=C.ERP_WIDTH)
    window: int = opt(64, "sliding-window width in latent columns (8 px each)", check=C.int_in(1, 4096, "window"))
    stride: int = opt(16, "latent columns between sliding windows", check=C.int_in(1, 4096, "stride"))
    no_seam_block: bool = opt(False, "turn the seam block off (for comparison)")
    out: str | None = opt(None, "output PNG", role="out-file", required=True)

    def __post_init__(self):
        C.validate(self)


def _formats() -> tuple[str, ...]:
    from .export import FORMATS

    return FORMATS


def _image_formats() -> tuple[str, ...]:
    from .export import IMAGE_FORMATS

    return IMAGE_FORMATS


@dataclass(frozen=True)
class ExportConfig:
    scene: SceneArgs = nest(SceneArgs)
    source: SourceArgs = nest(SourceArgs, teacher={"help": "depth teacher, for sources that use one"})
    format: str | None = opt(None, "colmap or nerfstudio", choices=_formats, required=True)
    out: str | None = _out_dir(("**",), "output folder (written to a temporary folder, then renamed)")
    labels: int = opt(120, "pseudo-label views on a Fibonacci layout", check=C.LABELS)
    res: int = opt(256, "label view size in pixels", check=C.LABEL_RES)
    fov: float = opt(60.0, "label field of view in degrees", check=C.FOV_DEG)
    image_format: str = opt("png", "image file format of the views", choices=_image_formats)
    overwrite: bool = _overwrite("replace a non-empty --out")

    def __post_init__(self):
        C.validate(self)


@dataclass(frozen=True)
class ViewConfig:
    path: str | None = opt(
        None, "a 3DGS point_cloud.ply, any point-cloud .ply, or a run folder", role="in", positional=True, required=True
    )
    port: int = opt(8080, "HTTP port", check=C.int_in(1, 65535, "port"))
    host: str = opt("0.0.0.0", "interface to listen on")

    def __post_init__(self):
        C.validate(self)


@dataclass(frozen=True)
class MeshConfig:
    cloud: str | None = opt(
        None, "a point-cloud .ply (e.g. a run's fibonacci_cloud.ply)", role="in", positional=True, required=True
    )
    out: str | None = opt(None, "output mesh .ply", role="out-file", required=True)
    depth: int = opt(9, "Poisson octree depth", check=C.int_in(4, 16, "Poisson depth"))
    trim: float = opt(0.1, "drop vertices below this density quantile", check=C.float_in(0.0, 0.99, "trim quantile"))
    centre: tuple[float, float, float] = opt(
        (0.0, 0.0, 0.0), "panorama centre x,y,z in metres; normals face it", check=C.FiniteVector(3, "centre")
    )
    scene: str | None = opt(
        None,
        "synthetic scene for the Chamfer to its true mesh, cloud taken as metric (default: the scene and scale in "
        "the cloud's *_report.json)",
    )

    def __post_init__(self):
        C.validate(self)


@dataclass(frozen=True)
class DemoConfig:
    out: str = _out_dir(DEMO_WRITES, default="out/demo")
    overwrite: bool = _overwrite()
    scene: SceneArgs = nest(
        SceneArgs,
        scene={"positional": False, "required": False, "help": "scene name (default: the built-in default scene)"},
        width={"default": 512, "help": "ERP width in pixels (height = width / 2)"},
    )
    teacher: str = opt("sim:relative", "depth teacher for the method's point cloud", role="teacher", check=TEACHER_SPEC)
    iters: int = opt(300, "training steps", check=C.ITERS)
    res: int = opt(128, "label view size in pixels for training", check=C.LABEL_RES)

    def __post_init__(self):
        C.validate(self)
        object.__setattr__(self, "teacher", TeacherSpec(str(self.teacher)))
