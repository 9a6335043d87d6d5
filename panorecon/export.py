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

Everything is written into a temporary folder beside ``out_dir`` and renamed into place at the end.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from .geometry import PinholeCamera, PointCloud
from .io import PanoreconInputError, write_image

FORMATS = ("colmap", "nerfstudio")
IMAGE_FORMATS = ("png", "jpg")
OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])  # camera axes (x right, y down, z fwd) -> (x right, y up, z back)


def c2w_opengl(viewmat: np.ndarray) -> np.ndarray:
    """World-to-camera 4x4 (OpenCV axes) -> camera-to-world 4x4 in OpenGL camera axes (nerfstudio)."""
    return np.linalg.inv(viewmat) @ OPENCV_TO_OPENGL


def viewmat_from_c2w_opengl(c2w: np.ndarray) -> np.ndarray:
    """Inverse of ``c2w_opengl``: camera-to-world 4x4 in OpenGL axes -> world-to-camera 4x4 in OpenCV axes."""
    return np.linalg.inv(np.asarray(c2w, float) @ OPENCV_TO_OPENGL)


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
    import open3d as o3d

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
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud.xyz.astype(np.float64)))
    pc.colors = o3d.utility.Vector3dVector(np.clip(cloud.rgb, 0, 1).astype(np.float64))  # written as uchar
    if not o3d.io.write_point_cloud(str(root / "sparse_pc.ply"), pc, write_ascii=False):
        raise OSError(f"could not write {root / 'sparse_pc.ply'}")


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
) -> Path:
    """Write ``views`` pseudo-label views (``view_size``² pixels, ``fov_deg`` square FOV, at the panorama
    centre) and ``cloud`` (metres, scene frame) in ``fmt`` ("colmap" | "nerfstudio") to ``out_dir`` -> out_dir.

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
    names = [f"images/view_{i:05d}.{image_format}" for i in range(len(labels))]
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        for lv, name in zip(labels, names):
            write_image(tmp / name, np.clip(np.round(lv.rgb * 255), 0, 255).astype(np.uint8))
        (_write_colmap if fmt == "colmap" else _write_nerfstudio)(tmp, cameras, names, cloud)
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


def add_export_parser(subparsers) -> None:
    """Add ``panorecon export SCENE --source NAME --format colmap|nerfstudio --out DIR``."""
    from . import cli_types as T

    ex = subparsers.add_parser(
        "export", help="export pseudo-label views + a point source's cloud as a COLMAP model or a nerfstudio dataset"
    )
    ex.add_argument("scene", type=T.scene, help="scene name (see `panorecon scenes list`) or an ERP image path")
    ex.add_argument("--source", required=True, help="point source (see `panorecon sources list`)")
    ex.add_argument("--teacher", default=None, type=T.teacher_spec, help="depth teacher, for sources that use one")
    ex.add_argument("--views", type=T.VIEWS, default=None, help="views of the point source")
    ex.add_argument("--format", dest="format", choices=FORMATS, required=True)
    ex.add_argument(
        "--out",
        required=True,
        type=T.out_dir_writing("**"),
        help="output folder (written to a temporary folder, then renamed)",
    )
    ex.add_argument("--width", type=T.ERP_WIDTH, default=None, help="ERP width")
    ex.add_argument(
        "--labels", type=T.LABELS, default=120, help="pseudo-label views on a Fibonacci layout (default 120)"
    )
    ex.add_argument("--res", type=T.LABEL_RES, default=256, help="label view size in pixels (default 256)")
    ex.add_argument(
        "--fov",
        type=T.float_in(1.0, 170.0, "field of view"),
        default=60.0,
        help="label field of view in degrees (default 60)",
    )
    ex.add_argument("--image-format", choices=IMAGE_FORMATS, default="png")
    ex.add_argument("--overwrite", action="store_true", help="replace a non-empty --out")
    ex.set_defaults(fn=run_export)


def run_export(args) -> int:
    """Build the cloud with ``run_source`` and export it with the labels; print one summary line -> 0."""
    from .scenes import scene_from_args
    from .sources import run_source

    scene = scene_from_args(args)
    cloud, report = run_source(scene, args.source, args.teacher, args.views)
    out = export_scene(
        scene, cloud, args.labels, args.format, args.out, args.res, args.fov, args.image_format, args.overwrite
    )
    print(
        f"{scene.name} / {args.source}: {len(cloud)} points, {args.labels} views {args.res}x{args.res} "
        f"({args.format}) -> {out}"
    )
    return 0
