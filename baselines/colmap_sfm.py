"""Sparse structure-from-motion baselines with pycolmap on K panoramas of one scene.

Each panorama is split into a perspective rig (``n_views`` 90-degree pinhole views sharing its centre:
``n_views - 2`` around the horizon, one up, one down). COLMAP's SIFT features are extracted and matched
exhaustively between views of different panoramas (views of one panorama share a centre, so their pairs
carry no parallax and are skipped). Then

(a) triangulation with the known poses: a ``pycolmap.Reconstruction`` built from the database's cameras,
    rig and frames, each frame posed at its panorama's true centre, then ``pycolmap.triangulate_points``
    (intrinsics and rig fixed); its points are in the scene frame, metric;
(b) incremental mapping (``pycolmap.incremental_mapping``, poses unknown, rig fixed), brought into the
    scene frame by a similarity (Umeyama) fitted from its frame centres to the true panorama centres.

Image names are ``cam{j}/pano{k}.png``: view j of panorama k (COLMAP's rig convention: one folder per sensor).
"""

from __future__ import annotations

import contextlib
import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from panorecon.geometry import PinholeCamera, PointCloud, centred_camera, erp_to_perspective
from panorecon.io import PanoreconInputError, write_image

FOV_DEG = 90.0
MIN_VIEWS = 6  # 4 around the horizon + up + down tile the sphere at 90 degrees


def rig_directions(n_views: int) -> np.ndarray:
    """Unit view directions [n_views, 3]: n_views - 2 evenly around the horizon (first along +x), then +z, -z."""
    if n_views < MIN_VIEWS:
        raise PanoreconInputError(
            f"views={n_views}: a 90-degree rig needs at least {MIN_VIEWS} views to cover the sphere"
        )
    a = 2 * math.pi * np.arange(n_views - 2) / (n_views - 2)
    ring = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1)
    return np.concatenate([ring, [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]])


@dataclass(frozen=True)
class RigImage:
    """One perspective view of one panorama: COLMAP image name, panorama index k, view index j, camera."""

    name: str
    panorama: int
    view: int
    camera: PinholeCamera


def split_panoramas(panoramas, n_views: int, size: int) -> list[tuple[RigImage, np.ndarray]]:
    """(position [3], ERP rgb [H, W, 3] uint8, ...) per panorama -> (RigImage, view rgb [size, size, 3] uint8)
    for every view of every panorama, panorama-major."""
    out = []
    for k, (position, rgb, *_) in enumerate(panoramas):
        for j, d in enumerate(rig_directions(n_views)):
            cam = centred_camera(d, size, FOV_DEG, np.asarray(position, float))
            out.append((RigImage(f"cam{j}/pano{k}.png", k, j, cam), erp_to_perspective(rgb, cam)))
    return out


@contextlib.contextmanager
def quiet_colmap(level: int = 2):
    """Raise glog's minimum level (2: errors only) while COLMAP runs, then restore it."""
    import pycolmap

    old = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = level
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = old


def _rigid(viewmat: np.ndarray):
    import pycolmap

    return pycolmap.Rigid3d(pycolmap.Rotation3d(viewmat[:3, :3]), viewmat[:3, 3].copy())


def extract_and_match(image_dir: Path, database: Path, images: list[RigImage], threads: int) -> dict:
    """SIFT extraction (PINHOLE cameras with the views' K, one camera per rig sensor), the rig written into
    the database, exhaustive matching across panoramas -> counts (keypoints, verified pairs, inlier matches)."""
    import pycolmap

    K = images[0].camera.K
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    reader.camera_params = f"{K[0, 0]},{K[1, 1]},{K[0, 2]},{K[1, 2]}"
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = threads
    pycolmap.extract_features(
        database,
        image_dir,
        image_names=[im.name for im in images],
        camera_mode=pycolmap.CameraMode.PER_FOLDER,
        reader_options=reader,
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )
    first = {im.view: im.camera for im in images if im.panorama == 0}
    ref = first[0].viewmat[:3, :3]
    rig = pycolmap.RigConfig()
    sensors = []
    for j, cam in sorted(first.items()):
        s = pycolmap.RigConfigCamera()
        s.image_prefix = f"cam{j}/"
        s.ref_sensor = j == 0
        if j:
            s.cam_from_rig = pycolmap.Rigid3d(pycolmap.Rotation3d(cam.viewmat[:3, :3] @ ref.T), np.zeros(3))
        sensors.append(s)
    rig.cameras = sensors
    db = pycolmap.Database.open(database)
    try:
        pycolmap.apply_rig_config([rig], db)
    finally:
        db.close()
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = threads
    matching.skip_image_pairs_in_same_frame = True
    pycolmap.match_exhaustive(database, matching_options=matching, device=pycolmap.Device.cpu)
    db = pycolmap.Database.open(database)
    try:
        return {
            "keypoints": int(db.num_keypoints()),
            "verified_pairs": int(db.num_verified_image_pairs()),
            "inlier_matches": int(db.num_inlier_matches()),
        }
    finally:
        db.close()


def pipeline_options(threads: int, seed: int):
    """IncrementalPipelineOptions with the intrinsics and the rig held fixed (both are known exactly)."""
    import pycolmap

    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = threads
    opts.random_seed = seed
    opts.ba_refine_focal_length = False
    opts.ba_refine_principal_point = False
    opts.ba_refine_extra_params = False
    opts.ba_refine_sensor_from_rig = False
    # short baselines inside a room: start from pairs with smaller parallax than COLMAP's 16 degrees
    opts.mapper.init_min_tri_angle = 4.0
    opts.mapper.init_min_num_inliers = 50
    return opts


def known_pose_reconstruction(database: Path, images: list[RigImage]):
    """A pycolmap.Reconstruction of the database's cameras, rig, frames and images (ids as in the database),
    every frame registered at its panorama's true pose (rig frame = view 0's camera frame)."""
    import pycolmap

    ref_view = {im.name: im for im in images}
    rec = pycolmap.Reconstruction()
    db = pycolmap.Database.open(database)
    try:
        db_images = {im.image_id: im for im in db.read_all_images()}
        for cam in db.read_all_cameras():
            rec.add_camera(cam)
        for rig in db.read_all_rigs():
            rec.add_rig(rig)
        for frame in db.read_all_frames():
            names = [db_images[d.id].name for d in frame.image_ids]
            ref = next(ref_view[n] for n in names if ref_view[n].view == 0)
            frame.rig_from_world = _rigid(ref.camera.viewmat)
            rec.add_frame(frame)
        for im in db_images.values():
            rec.add_image(im)
    finally:
        db.close()
    for frame_id in rec.frames:
        rec.register_frame(frame_id)
    return rec


def umeyama(src: np.ndarray, tgt: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity tgt ~ s R src + t from points src, tgt [N, 3] -> (s, R [3, 3], t [3]).

    Works for coplanar points (pycolmap's estimator rejects them; panorama centres on a ring are coplanar).
    """
    mx, my = src.mean(0), tgt.mean(0)
    x, y = src - mx, tgt - my
    U, D, Vt = np.linalg.svd(y.T @ x / len(src))
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = float(np.trace(np.diag(D) @ S) / (x**2).sum(1).mean())
    return s, R, my - s * R @ mx


def reconstruction_stats(rec) -> dict:
    """Registered frames and images, points, mean track length, mean reprojection error (pixels)."""
    return {
        "registered_frames": int(rec.num_reg_frames()),
        "registered_images": int(rec.num_reg_images()),
        "images": int(rec.num_images()),
        "points": int(rec.num_points3D()),
        "mean_track_length": float(rec.compute_mean_track_length()) if rec.num_points3D() else 0.0,
        "mean_reprojection_error_px": float(rec.compute_mean_reprojection_error())
        if rec.num_points3D()
        else float("nan"),
    }


def reconstruction_cloud(rec) -> PointCloud:
    """The reconstruction's 3D points as a PointCloud (colours from COLMAP, in [0, 1])."""
    pts = list(rec.points3D.values())
    xyz = np.array([p.xyz for p in pts], np.float64).reshape(-1, 3)
    rgb = np.array([p.color for p in pts], np.float32).reshape(-1, 3) / 255.0
    return PointCloud(xyz, rgb)


def align_mapping(rec, images: list[RigImage]) -> dict:
    """Move a mapped reconstruction into the scene frame (in place) by the similarity from its registered frame
    centres to the true panorama centres -> alignment report (scale, RMS centre residual in metres), or
    {'aligned': False, 'reason': ...} when the registered centres cannot fix a similarity (fewer than 3
    panoramas, or collinear ones)."""
    import pycolmap

    by_name = {im.name: im for im in images}
    src, tgt = [], []
    for im in rec.images.values():
        if im.has_pose and by_name[im.name].view == 0:
            src.append(im.projection_center())
            tgt.append(by_name[im.name].camera.position)
    if len(src) < 3:
        return {"aligned": False, "reason": f"{len(src)} panorama(s) registered; a similarity needs 3 non-collinear"}
    src, tgt = np.array(src), np.array(tgt)
    sv = np.linalg.svd(tgt - tgt.mean(0), compute_uv=False)
    if sv[1] <= 1e-3 * sv[0]:
        return {"aligned": False, "reason": "the registered panorama centres are collinear"}
    s, R, t = umeyama(src, tgt)
    rec.transform(pycolmap.Sim3d(s, pycolmap.Rotation3d(R), t))
    res = (s * src @ R.T + t) - tgt
    return {"aligned": True, "scale": s, "centre_rms_m": float(np.sqrt((res**2).sum(1).mean()))}


@dataclass
class SfmResult:
    """cloud: the known-pose triangulation (scene frame, metres); mapped: the incremental-mapping cloud
    aligned to the scene frame, or None; report: matching counts and, per path, what ran and its stats."""

    cloud: PointCloud
    mapped: PointCloud | None
    report: dict


def run_colmap_sfm(
    panoramas,
    n_views: int = 8,
    view_size: int = 128,
    mapping: bool = True,
    threads: int = 2,
    seed: int = 0,
    workdir: str | Path | None = None,
) -> SfmResult:
    """Both SfM paths on panoramas [(position [3] metres, ERP rgb [H, W, 3] uint8, ...), ...].

    ``workdir`` keeps COLMAP's images/, database.db and the models triangulated/ and mapped/ there
    (default: a temporary folder, removed). The report's ``seconds`` holds each stage's wall time.
    """
    import pycolmap

    if len(panoramas) < 2:
        raise PanoreconInputError(f"{len(panoramas)} panorama(s): structure from motion needs at least 2 positions")
    pycolmap.set_random_seed(seed)
    with contextlib.ExitStack() as stack:
        root = (
            Path(workdir) if workdir else Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="colmap-sfm-")))
        )
        image_dir, database = root / "images", root / "database.db"
        database.unlink(missing_ok=True)
        t = time.perf_counter()
        views = split_panoramas(panoramas, n_views, view_size)
        for im, rgb in views:
            write_image(image_dir / im.name, rgb)
        images = [im for im, _ in views]
        seconds = {"views": time.perf_counter() - t}
        stack.enter_context(quiet_colmap())
        t = time.perf_counter()
        report = {
            "panoramas": len(panoramas),
            "views_per_panorama": n_views,
            "view_size": view_size,
            "fov_deg": FOV_DEG,
            "matching": extract_and_match(image_dir, database, images, threads),
        }
        seconds["features"] = time.perf_counter() - t
        t = time.perf_counter()
        opts = pipeline_options(threads, seed)
        (root / "triangulated").mkdir(exist_ok=True)
        tri = pycolmap.triangulate_points(
            known_pose_reconstruction(database, images), database, image_dir, root / "triangulated", options=opts
        )
        report["triangulation"] = {"ran": True, **reconstruction_stats(tri)}
        seconds["triangulation"] = time.perf_counter() - t
        mapped = None
        if not mapping:
            report["mapping"] = {"ran": False, "reason": "not requested"}
        else:
            t = time.perf_counter()
            (root / "mapped").mkdir(exist_ok=True)
            models = pycolmap.incremental_mapping(database, image_dir, root / "mapped", options=opts)
            if not models:
                report["mapping"] = {
                    "ran": True,
                    "registered_images": 0,
                    "aligned": False,
                    "reason": "incremental mapping found no initial pair / model",
                }
            else:
                best = max(models.values(), key=lambda m: m.num_reg_images())
                report["mapping"] = {"ran": True, "models": len(models), **reconstruction_stats(best)}
                report["mapping"].update(align_mapping(best, images))
                if report["mapping"]["aligned"]:
                    mapped = reconstruction_cloud(best)
            seconds["mapping"] = time.perf_counter() - t
        report["seconds"] = seconds
        return SfmResult(reconstruction_cloud(tri), mapped, report)
