"""Export a scene's pseudo-label views and an initial point cloud for other Gaussian-splatting trainers.

Views: ``make_pseudo_labels`` cameras at the panorama centre on a Fibonacci layout, their colours resampled
from the ERP, written as images/view_00000.png (or .jpg).

* ``colmap``: sparse/0/{cameras,images,points3D}.bin through ``pycolmap.Reconstruction.write``: one
  PINHOLE camera shared by every view, one image per view (named relative to images/, COLMAP's usual
  layout) with its world-to-camera pose (OpenCV axes,
  the scene's world frame, +z up, metres), the cloud as 3D points with empty tracks.
* ``nerfstudio``: transforms.json (camera-to-world matrices in OpenGL axes: x right, y up, z backward,
  as nerfstudio expects; the world frame is the scene's, already +z up) and sparse_pc.ply (x, y, z,
  uchar red/green/blue) named by its ``ply_file_path``.

* ``sparse_pc.ply`` / points: float32 positions (``PointCloud.save_ply``, uchar colours: the layout OpenSplat's
  reader assumes; it misreads doubles silently).

Scene size. Every consumer sizes the scene by its cameras' spread (``consumer_scales``: OpenSplat, nerfstudio,
gsplat's simple_trainer, the original 3DGS), and the label views share one centre, where their colours are true:
a spread of 0 gives OpenSplat NaN Gaussians, nerfstudio a ZeroDivisionError and gsplat/3DGS frozen means and a
scene pruned to nothing. So when the label views span no baseline the export adds two *scale anchors*
(``scale_anchors``): views on the vertical axis at about the cloud's extent (its 90th-percentile distance, the
extent panorecon's own trainer scales its learning rate by), looking away from the cloud with no point in view,
with black images. They see no point, so they give no Gaussian a gradient, but their baseline makes every consumer's
scene size the cloud's extent. They stand on a vertical line slightly off the centre, at heights that may differ, so
that the cameras' mean (OpenSplat's and nerfstudio's origin) is ``OFF_CENTRE`` x extent from the label centre, away
from every label view's plane: OpenSplat's CPU projection divides by each Gaussian's depth in every view, and at
the label centre float32 cancellation gives exactly 0 (NaN gradients) for Gaussians training moves across a plane.
``export.json`` and ``README.txt`` give each consumer's scale and its command.

Everything is written into a temporary folder beside ``out_dir`` and renamed into place at the end.
"""

from __future__ import annotations

import json
import logging
import math
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from .geometry import PinholeCamera, PointCloud, centred_camera, fibonacci_directions
from .io import PanoreconInputError, write_image, write_json

log = logging.getLogger(__name__)

FORMATS = ("colmap", "nerfstudio")
IMAGE_FORMATS = ("png", "jpg")
OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])  # camera axes (x right, y down, z fwd) -> (x right, y up, z back)
EXTENT_PERCENTILE = 90.0  # the cloud's extent: this percentile of its points' distances from the label centre
ANCHOR_MARGIN = 0.05  # anchors sit this fraction of the extent beyond the height where they would see a point
NO_BASELINE = 1e-3  # label views spread by less than this fraction of the extent span "no baseline"
OFF_CENTRE = 1e-3  # the label centre's distance from the mean of all camera centres, as a fraction of the extent
OFF_CENTRE_CANDIDATES = 1001  # Fibonacci directions searched for the label centre's offset (off_centre_direction)
OFF_CENTRE_MIN_DEPTH = 1e-6  # refuse a layout where a label view's depth of that mean is below this x extent


def c2w_opengl(viewmat: np.ndarray) -> np.ndarray:
    """World-to-camera 4x4 (OpenCV axes) -> camera-to-world 4x4 in OpenGL camera axes (nerfstudio)."""
    return np.linalg.inv(viewmat) @ OPENCV_TO_OPENGL


def viewmat_from_c2w_opengl(c2w: np.ndarray) -> np.ndarray:
    """Inverse of ``c2w_opengl``: camera-to-world 4x4 in OpenGL axes -> world-to-camera 4x4 in OpenCV axes."""
    return np.linalg.inv(np.asarray(c2w, float) @ OPENCV_TO_OPENGL)


def cloud_extent(cloud: PointCloud, centre: np.ndarray) -> float:
    """The cloud's size (metres or the cloud's units): the ``EXTENT_PERCENTILE``-th percentile of its points'
    distances from ``centre`` [3] -> float > 0 (float64)."""
    if len(cloud) == 0:
        raise PanoreconInputError("export: the point cloud is empty (expected at least one point)")
    extent = float(np.percentile(np.linalg.norm(cloud.xyz.astype(np.float64) - centre, axis=1), EXTENT_PERCENTILE))
    if not (np.isfinite(extent) and extent > 0):
        raise PanoreconInputError(f"export: the point cloud's extent is {extent!r} (every point at the view centre)")
    return extent


def off_centre_direction(axes: np.ndarray) -> tuple[np.ndarray, float]:
    """The unit direction u [3] (float64), among ``OFF_CENTRE_CANDIDATES`` Fibonacci directions, farthest from
    every plane through the centre perpendicular to a view axis in ``axes`` [N, 3] (unit) -> (u, min |axes u|)."""
    cands = fibonacci_directions(OFF_CENTRE_CANDIDATES)
    score = np.abs(cands @ np.asarray(axes, np.float64).T).min(1)
    best = int(np.argmax(score))
    return cands[best], float(score[best])


def scale_anchors(
    cloud: PointCloud, centre: np.ndarray, extent: float, size: int, fov_deg: float, mean_shift=(0.0, 0.0, 0.0)
):
    """Two views on the vertical line through ``centre`` + s, one at height a looking up and one at -b looking
    down: a and b at least the ``extent`` or, where the cloud reaches into that view, the lowest height at which
    no point lies inside the cone around the square view (half-angle atan(sqrt 2 tan(fov / 2))) plus
    ``ANCHOR_MARGIN`` x extent, so their true image is empty. s (horizontal) and a - b are set so that the two
    anchors' centres sum to 2 ``centre`` + ``mean_shift`` [3] (metres; the default keeps them on the vertical
    axis through ``centre`` at the same height) -> ([PinholeCamera] x 2, ["anchor_up", "anchor_down"])."""
    shift = np.asarray(mean_shift, np.float64)
    line = centre + [shift[0] / 2, shift[1] / 2, 0.0]
    p = cloud.xyz.astype(np.float64) - line
    cone = math.tan(math.radians(fov_deg) / 2) * math.sqrt(2)  # a point is seen only if r < (height above - a) cone
    r = np.hypot(p[:, 0], p[:, 1])
    margin = ANCHOR_MARGIN * extent
    up = max(extent, float((p[:, 2] - r / cone).max()) + margin)
    down = max(extent, float((-p[:, 2] - r / cone).max()) + margin)
    if up - down >= shift[2]:  # raise one of them (never lower) until a - b = the vertical shift
        down = up - shift[2]
    else:
        up = down + shift[2]
    cams = [
        centred_camera(np.array([0.0, 0.0, 1.0]), size, fov_deg, line + [0.0, 0.0, up]),
        centred_camera(np.array([0.0, 0.0, -1.0]), size, fov_deg, line - [0.0, 0.0, down]),
    ]
    return cams, ["anchor_up", "anchor_down"]


def consumer_scales(c2w: np.ndarray) -> dict[str, float]:
    """The scene size each consumer derives from camera-to-world poses ``c2w`` [N, 4, 4] (OpenCV axes), float64,
    inf or NaN where the layout is degenerate. Each rule follows the consumer's code:

    * ``opensplat``: the factor its world is multiplied by, 1 / max |C - mean C| over all coordinates
      (pierotofy/OpenSplat tensor_math.cpp ``autoScaleAndCenterPoses``, called by nerfstudio.cpp and colmap.cpp).
    * ``nerfstudio``: ``scale_factor`` = 1 / max |t| after ``auto_orient_and_center_poses`` (method "up", centre
      "poses"), the default ``auto_scale_poses`` of nerfstudio_dataparser.py and colmap_dataparser.py.
    * ``gsplat``: ``scene_scale`` = 1.1 x max |C - mean C| (examples/datasets/colmap.py ``Parser``, x 1.1 in
      simple_trainer.py ``Runner``) with ``--no-normalize-world-space``; ``gsplat-normalized``: the factor its
      default normalisation applies, 1 / median |C - focus| (examples/datasets/normalize.py
      ``similarity_from_cameras``), infinite whenever most cameras share one centre.
    * ``3dgs``: ``cameras_extent`` = 1.1 x max |C - mean C| (graphdeco-inria/gaussian-splatting
      scene/dataset_readers.py ``getNerfppNorm``), which scales its means learning rate and densification.
    """
    c2w = np.asarray(c2w, np.float64)
    C = c2w[:, :3, 3]
    spread = np.linalg.norm(C - C.mean(0), axis=1).max()
    with np.errstate(divide="ignore", invalid="ignore"):
        opensplat = 1.0 / np.abs(C - C.mean(0)).max()
        up = -c2w[:, :3, 1].mean(0)  # OpenGL camera y (up) = -OpenCV y
        R = _rotation_between(up / np.linalg.norm(up), np.array([0.0, 0.0, 1.0]))
        nerfstudio = 1.0 / np.abs((C - C.mean(0)) @ R.T).max()
        fwd = c2w[:, :3, 2]
        nearest = C + ((fwd * -C).sum(-1))[:, None] * fwd  # gsplat's "focus" centre, before its z-up rotation
        t = C - np.median(nearest, axis=0)
        normalized = 1.0 / np.median(np.linalg.norm(t, axis=1))
    return {
        "opensplat": float(opensplat),
        "nerfstudio": float(nerfstudio),
        "gsplat": float(1.1 * spread),
        "gsplat-normalized": float(normalized),
        "3dgs": float(1.1 * spread),
    }


def label_centre_depth(c2w: np.ndarray, n_labels: int) -> float:
    """min over the first ``n_labels`` views of |depth of the mean camera centre| (metres, float64) for
    camera-to-world ``c2w`` [N, 4, 4] (OpenCV axes): how far the point OpenSplat and nerfstudio centre the world on
    lies from the plane through each label camera perpendicular to its axis (0 when it is the label centre)."""
    c2w = np.asarray(c2w, np.float64)
    mean = c2w[:, :3, 3].mean(0)
    labels = c2w[:n_labels]
    return float(np.abs(np.einsum("nk,nk->n", labels[:, :3, 2], mean - labels[:, :3, 3])).min())


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation [3, 3] taking unit ``a`` to unit ``b`` (Rodrigues; nerfstudio's ``rotation_matrix_between``)."""
    v = np.cross(a, b)
    if np.abs(v).sum() < 1e-6:
        v = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 1e-6 else [0, 1.0, 0])
    v = v / np.linalg.norm(v)
    S = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    theta = np.arccos(np.clip(a @ b, -1, 1))
    return np.eye(3) + np.sin(theta) * S + (1 - np.cos(theta)) * S @ S


def consumer_commands(out: Path, fmt: str) -> dict[str, str]:
    """Per consumer, the command that trains on export ``out`` in format ``fmt`` (its own documented flags)."""
    d = str(out)
    cmds = {
        "opensplat": f"opensplat {d} --keep-crs -o {d}/opensplat.ply",
        "nerfstudio": f"ns-train splatfacto --data {d}"
        + (" colmap --colmap-path sparse/0" if fmt == "colmap" else " nerfstudio-data"),
    }
    if fmt == "colmap":  # gsplat's simple_trainer and the original 3DGS read COLMAP models only
        cmds["gsplat"] = (
            f"python examples/simple_trainer.py default --data-dir {d} --data-factor 1 "
            f"--no-normalize-world-space --result-dir {d}/gsplat"
        )
        cmds["3dgs"] = f"python train.py -s {d} -m {d}/3dgs"
    return cmds


def _write_colmap(root: Path, cameras: list[PinholeCamera], names: list[str], cloud: PointCloud) -> None:
    import pycolmap

    K, w, h = cameras[0].K, cameras[0].width, cameras[0].height
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(
        pycolmap.Camera(camera_id=1, model="PINHOLE", width=w, height=h, params=[K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
    )
    for i, (cam, name) in enumerate(zip(cameras, names), start=1):
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(cam.viewmat[:3, :3]), cam.viewmat[:3, 3].copy())
        # COLMAP names images relative to the image folder (root/images)
        rec.add_image_with_trivial_frame(pycolmap.Image(name=Path(name).name, camera_id=1, image_id=i), pose)
    rgb = np.clip(np.round(cloud.rgb * 255), 0, 255).astype(np.uint8)
    for xyz, c in zip(cloud.xyz.astype(np.float64), rgb):
        rec.add_point3D(xyz, pycolmap.Track(), c)
    (root / "sparse" / "0").mkdir(parents=True)
    rec.write(root / "sparse" / "0")


def _write_nerfstudio(root: Path, cameras: list[PinholeCamera], names: list[str], cloud: PointCloud) -> None:
    K, w, h = cameras[0].K, cameras[0].width, cameras[0].height
    meta = {
        "camera_model": "OPENCV",
        "fl_x": K[0, 0],
        "fl_y": K[1, 1],
        "cx": K[0, 2],
        "cy": K[1, 2],
        "w": w,
        "h": h,
        "k1": 0.0,
        "k2": 0.0,
        "p1": 0.0,
        "p2": 0.0,
        "ply_file_path": "sparse_pc.ply",
        "frames": [
            {"file_path": name, "transform_matrix": c2w_opengl(cam.viewmat).tolist()}
            for cam, name in zip(cameras, names)
        ],
    }
    (root / "transforms.json").write_text(json.dumps(meta, indent=2))
    PointCloud(cloud.xyz, cloud.rgb).save_ply(root / "sparse_pc.ply", uchar_rgb=True)  # x, y, z, red, green, blue


def export_scene(
    scene,
    cloud: PointCloud,
    views: int,
    fmt: str,
    out_dir: str | os.PathLike,
    view_size: int = 256,
    fov_deg: float = 60.0,
    image_format: str = "png",
    overwrite: bool = False,
    about: dict | None = None,
) -> Path:
    """Write ``views`` pseudo-label views (``view_size``² pixels, ``fov_deg`` square FOV, at the panorama
    centre), two scale anchors when those views span no baseline (module docstring) and ``cloud`` (metres, scene
    frame) in ``fmt`` ("colmap" | "nerfstudio") to ``out_dir``, with export.json (views, anchors, extent, each
    consumer's scale and command, warnings; ``about``, e.g. scene and source names, copied in) and README.txt
    -> out_dir.

    An existing non-empty ``out_dir`` is replaced only with ``overwrite``.
    """
    from .splat.labels import make_pseudo_labels

    if fmt not in FORMATS:
        raise PanoreconInputError(f"export format {fmt!r}: expected one of {', '.join(FORMATS)}")
    if image_format not in IMAGE_FORMATS:
        raise PanoreconInputError(f"image format {image_format!r}: expected one of {', '.join(IMAGE_FORMATS)}")
    out = Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not overwrite:
        raise PanoreconInputError(f"{out} exists and is not empty (pass overwrite=True / --overwrite to replace it)")
    labels = make_pseudo_labels(scene, views, view_size, fov_deg)
    cameras = [lv.camera for lv in labels]
    images = [np.clip(np.round(lv.rgb * 255), 0, 255).astype(np.uint8) for lv in labels]
    names = [f"images/view_{i:05d}.{image_format}" for i in range(len(labels))]
    centres = np.stack([c.position for c in cameras])
    centre = centres.mean(0)
    extent = cloud_extent(cloud, centre)
    baseline = float(np.linalg.norm(centres - centre, axis=1).max())
    anchors, warnings = [], []
    if baseline < NO_BASELINE * extent:
        # OpenSplat and nerfstudio centre the world on the cameras' mean; the anchors keep the label centre off it
        u, _ = off_centre_direction(np.stack([c.forward for c in cameras]))
        offset = OFF_CENTRE * extent * u  # label centre - mean of all camera centres
        n_all = len(cameras) + 2
        anchor_cams, anchor_names = scale_anchors(cloud, centre, extent, view_size, fov_deg, mean_shift=-n_all * offset)
        anchors = [f"images/{n}.{image_format}" for n in anchor_names]
        cameras, names = cameras + anchor_cams, names + anchors
        images += [np.zeros((view_size, view_size, 3), np.uint8)] * len(anchor_cams)
        heights = ", ".join(f"{c.position[2] - centre[2]:+.3f}" for c in anchor_cams)
        warnings.append(
            f"the {len(labels)} label views share one centre (baseline {baseline:.2g} against a cloud extent of "
            f"{extent:.3f}): OpenSplat, nerfstudio, gsplat and 3DGS size the scene by the cameras' spread, which "
            "would be 0 (OpenSplat: scale 1/0 and NaN Gaussians; nerfstudio: ZeroDivisionError; gsplat, 3DGS: "
            "frozen means and every Gaussian pruned as too big). Added 2 scale-anchor views at z = "
            f"{heights} from the centre, black, looking away with no point in view: each consumer's scene size is "
            "now about the cloud's extent (README.txt)"
        )
    c2w = np.stack([np.linalg.inv(c.viewmat) for c in cameras])
    depth = label_centre_depth(c2w, len(labels))
    if anchors and not depth >= OFF_CENTRE_MIN_DEPTH * extent:  # guards off_centre_direction's choice
        raise PanoreconInputError(
            f"export: the label views' centre lies {depth:.3g} from a view plane through the cameras' mean "
            f"(expected at least {OFF_CENTRE_MIN_DEPTH:g} x the extent {extent:.3f}; too many label views?)"
        )
    scales = consumer_scales(c2w)
    commands = consumer_commands(out.resolve(), fmt)
    bad = [k for k in commands if not (np.isfinite(scales[k]) and scales[k] > 0)]
    if bad:  # cannot happen with the anchors; guards a future layout
        raise PanoreconInputError(f"export: degenerate scene for {', '.join(bad)}: scales {scales}")
    for w in warnings:
        log.warning(w)
    report = {
        **(about or {}),
        "format": fmt,
        "label_views": names[: len(labels)],
        "label_centre": centre,
        "label_baseline": baseline,
        "cloud_points": len(cloud),
        "cloud_extent": extent,
        "extent_rule": f"{EXTENT_PERCENTILE:g}th percentile of the points' distances from the label centre",
        "anchors": {n: c.position for n, c in zip(anchors, cameras[len(labels) :])},
        "label_centre_depth": depth,
        "consumer_scales": {k: scales[k] for k in ("opensplat", "nerfstudio", "gsplat", "3dgs") if k in commands},
        "commands": commands,
        "warnings": warnings,
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        for img, name in zip(images, names):
            write_image(tmp / name, img)
        (_write_colmap if fmt == "colmap" else _write_nerfstudio)(tmp, cameras, names, cloud)
        write_json(tmp / "export.json", report)
        (tmp / "README.txt").write_text(_readme(report))
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old.", dir=out.parent))
            os.replace(out, old / out.name)
            os.replace(tmp, out)
            shutil.rmtree(old)
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


SCALE_MEANING = {
    "opensplat": "multiplies the world (cameras to [-1, 1]); its thresholds (densify-size-thresh 0.01, cull 0.5) "
    "are in those units",
    "nerfstudio": "scale_factor multiplying the world (auto_scale_poses); splatfacto's thresholds are in those units",
    "gsplat": "scene_scale: means learning rate and grow/prune size thresholds are multiples of it "
    "(needs --no-normalize-world-space: its default normalisation divides by the median camera distance, 0 here)",
    "3dgs": "cameras_extent (getNerfppNorm): means learning rate, percent_dense and the 'too big' prune scale with "
    "it (train cameras only: with --eval, llffhold may hold out one anchor; the other keeps it finite)",
}


def _readme(report: dict) -> str:
    """README.txt of an export: what is in it, the scene size each consumer derives, the commands."""
    lines = [
        f"panorecon export ({report['format']}): {len(report['label_views'])} pseudo-label views from one panorama "
        f"centre and a {report['cloud_points']}-point initial cloud (float32 positions), scene frame (+z up).",
        f"Cloud extent {report['cloud_extent']:.4f} ({report['extent_rule']}).",
        "",
    ]
    if report["anchors"]:
        lines += [
            "Scale anchors: " + ", ".join(report["anchors"]),
            "  Every consumer below sizes the scene by its cameras' spread; the label views share one centre",
            "  (their colours are only true there), so a spread of 0 would break them all. The two anchors sit on",
            "  a vertical line near the centre at about the cloud's extent, looking away from it with no point in",
            "  view: their true image is empty (black), they give no Gaussian a gradient, and their baseline makes",
            "  each consumer's scene size the cloud's extent. Leave them in; drop them only with views of your own",
            "  that span a baseline.",
            "",
        ]
    lines.append("Scene size each consumer derives from these cameras (its own rule; tests/test_export.py):")
    for k, v in report["consumer_scales"].items():
        lines.append(f"  {k:<10} {v:.4f}  ({SCALE_MEANING[k]})")
    lines += ["", "Commands that train on this export (run from the trainer's checkout where it is a script):"]
    lines += [f"  {k:<10} {c}" for k, c in report["commands"].items()]
    return "\n".join(lines) + "\n"


def run_export(cfg) -> int:
    """``panorecon export`` (a ``configs.ExportConfig``): build the cloud with ``run_source`` and export it with
    the labels (warnings go to the log, stderr); print a summary and each consumer's command -> 0."""
    from .sources import run_source

    scene = cfg.scene.load()
    src = cfg.source
    cloud, report = run_source(scene, src.source, src.teacher, src.views, src.fusion.config())
    about = {"scene": scene.name, "source": src.source, "teacher": report.get("teacher")}
    out = export_scene(
        scene, cloud, cfg.labels, cfg.format, cfg.out, cfg.res, cfg.fov, cfg.image_format, cfg.overwrite, about
    )
    meta = json.loads((out / "export.json").read_text())
    print(
        f"{scene.name} / {src.source}: {len(cloud)} points, {cfg.labels} views {cfg.res}x{cfg.res} "
        f"+ {len(meta['anchors'])} scale anchors ({cfg.format}) -> {out}"
    )
    for k, c in meta["commands"].items():
        print(f"  {k} (scene scale {meta['consumer_scales'][k]:.4f}): {c}")
    return 0
