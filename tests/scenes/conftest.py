"""Dataset fixtures written with each DATASET's own conventions, independently of panorecon's geometry code.

The scene is analytic: boxes (rooms) in the dataset's world frame, textured by a smooth function of the world
point, ray-cast here. Each writer turns a pixel into a direction with the dataset's own formula, re-derived in
this file from the dataset's code (cited), never with ``panorecon.geometry``; the adapters must then recover
the same world points.
"""

from __future__ import annotations

import json

import cv2
import numpy as np

from panorecon.io import write_image

ROOM = np.array([[0.0, 5.0], [0.0, 4.0], [0.0, 2.8]])  # metres: [x, y, z] bounds of a box room, not square
FAR_ROOM = ROOM + np.array([[9.0], [0.0], [0.0]])  # another room 4 m beyond the first's +x wall: sees none of it


# furniture along ROOM's walls, [x, y, z] bounds (metres): wardrobes and shelves that hide much of the wall band
# (|latitude| < 17 deg) of a panorama near them, none of the floor or ceiling
FURNITURE = (
    np.array([[0.0, 0.6], [0.0, 2.6], [0.0, 2.2]]),
    np.array([[0.0, 3.0], [0.0, 0.5], [0.0, 2.0]]),
    np.array([[4.4, 5.0], [1.0, 3.5], [0.0, 1.9]]),
)


def _box_entry(origin: np.ndarray, dirs: np.ndarray, box: np.ndarray) -> np.ndarray:
    """Distance [...] along unit ``dirs`` from ``origin`` (outside ``box``) to where the ray enters the box
    (slab method), inf where it misses."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (box[:, 0] - origin) / dirs
        t1 = (box[:, 1] - origin) / dirs
    near = np.nan_to_num(np.minimum(t0, t1), nan=-np.inf).max(-1)
    far = np.nan_to_num(np.maximum(t0, t1), nan=np.inf).min(-1)
    return np.where((near <= far) & (near > 1e-9), near, np.inf)


def cast(origin: np.ndarray, dirs: np.ndarray, room: np.ndarray = ROOM, furniture=()) -> np.ndarray:
    """Distance [...] from ``origin`` (inside ``room``, outside every box of ``furniture``) along unit ``dirs``
    [..., 3] to the nearest of the room's walls and the furniture boxes."""
    t = np.full(dirs.shape[:-1], np.inf)
    for axis in range(3):
        for bound in room[axis]:
            with np.errstate(divide="ignore", invalid="ignore"):
                ti = (bound - origin[axis]) / dirs[..., axis]
            t = np.minimum(t, np.where(ti > 1e-9, ti, np.inf))
    for box in furniture:
        t = np.minimum(t, _box_entry(origin, dirs, box))
    return t


def colour(points: np.ndarray) -> np.ndarray:
    """A smooth texture of the world point [..., 3] metres -> uint8 [..., 3] (the same from every panorama)."""
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    rgb = [
        128 + 90 * np.sin(2 * np.pi * x / 0.9 + z),
        128 + 90 * np.sin(2 * np.pi * y / 0.7),
        128 + 90 * np.cos(3 * z + x),
    ]
    return np.clip(np.stack(rgb, -1), 0, 255).round().astype(np.uint8)


def walls_annotation() -> dict:
    """ROOM's planes in Structured3D's annotation_3d.json form (mm; normal . x + offset = 0, normal towards the
    empty space: data_organization.md, visualize_3d.py)."""
    planes = []
    kinds = {0: "wall", 1: "wall", 2: None}
    for axis in range(3):
        for side, bound in enumerate(ROOM[axis]):
            n = np.zeros(3)
            n[axis] = 1.0 if side == 0 else -1.0
            kind = kinds[axis] or ("floor" if side == 0 else "ceiling")
            planes.append(
                {"ID": len(planes), "type": kind, "normal": n.tolist(), "offset": float(-n[axis] * bound * 1000)}
            )
    return {
        "junctions": [],
        "lines": [],
        "planes": planes,
        "semantics": [],
        "planeLineMatrix": [],
        "lineJunctionMatrix": [],
    }


def structured3d_directions(h: int, w: int) -> np.ndarray:
    """Structured3D misc/panorama.py: coords2uv with 1-based pixel coordinates (middle = W/2 + 0.5),
    u = (x - middle) / W * 2 pi, v = -(y - middle) / H * pi; uv2xyzN (planeID 1): (cos v sin u, cos v cos u, sin v)."""
    xs, ys = np.meshgrid(np.arange(1, w + 1, dtype=float), np.arange(1, h + 1, dtype=float))
    u = (xs - (w / 2 + 0.5)) / w * 2 * np.pi
    v = -(ys - (h / 2 + 0.5)) / h * np.pi
    return np.stack([np.cos(v) * np.sin(u), np.cos(v) * np.cos(u), np.sin(v)], -1)


def png16(path, metres, units_per_metre, missing=0):
    path.parent.mkdir(parents=True, exist_ok=True)
    v = np.where(np.isfinite(metres), np.round(metres * units_per_metre), missing)
    cv2.imwrite(str(path), np.clip(v, 0, 65535).astype(np.uint16))


def write_structured3d_room(
    root, scene, room, centre, h=64, room_box=ROOM, depth_units_per_metre=1000.0, roll=0, furniture=(), mirror=False
):
    """One Structured3D room panorama (full/rgb_rawlight.png, full/depth.png in mm, camera_xyz.txt in mm) seen
    from ``centre`` (metres, world), with ``furniture`` boxes in the room. ``roll`` shifts the written image's
    columns (a deliberately rotated panorama), ``mirror`` flips them left-right; ``depth_units_per_metre`` other
    than 1000 writes a depth in the wrong unit. Returns the world points [H, W, 3] of its pixels (before any
    roll or mirror)."""
    dirs = structured3d_directions(h, 2 * h)
    dist = cast(np.asarray(centre, float), dirs, room_box, furniture)
    pts = np.asarray(centre, float) + dist[..., None] * dirs
    pano = root / scene / "2D_rendering" / str(room) / "panorama"
    rgb, stored = np.roll(colour(pts), roll, axis=1), np.roll(dist, roll, axis=1)
    if mirror:
        rgb, stored = rgb[:, ::-1], stored[:, ::-1]
    write_image(pano / "full" / "rgb_rawlight.png", rgb)
    png16(pano / "full" / "depth.png", stored, depth_units_per_metre)
    (pano / "camera_xyz.txt").write_text(" ".join(f"{v * 1000:.1f}" for v in centre))
    ann = root / scene / "annotation_3d.json"
    if not ann.exists():
        ann.write_text(json.dumps(walls_annotation()))
    return pts


def yaw(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def write_exr_xyz(path, xyz):
    import OpenEXR

    path.parent.mkdir(parents=True, exist_ok=True)
    chans = {c: np.ascontiguousarray(xyz[..., i].astype(np.float32)) for i, c in enumerate("RGB")}
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, chans) as f:
        f.write(str(path))


def write_stanford2d3d_pano(root, area, pano, centre, yaw_deg, h=64, global_xyz=True):
    """One 2D-3D-S panorama: pano/{rgb,depth,pose,global_xyz}/<pano>_frame_equirectangular_domain_*; depth
    1/512 m, 65535 missing; pose JSON with camera_location (m) and a per-panorama rotation; global_xyz the world
    position of every pixel (zeros where missing). The dataset documents no pixel convention for its
    panoramas, only this per-pixel world position, so the image is taken in some non-mirrored frame turned by
    ``yaw_deg`` about +z (here: Structured3D's formula, rotated). Returns the world points [H, W, 3]."""
    dirs = structured3d_directions(h, 2 * h) @ yaw(yaw_deg).T
    dist = cast(np.asarray(centre, float), dirs)
    pts = np.asarray(centre, float) + dist[..., None] * dirs
    base = root / area / "pano"
    stem = f"{pano}_frame_equirectangular_domain_"
    write_image(base / "rgb" / f"{stem}rgb.png", colour(pts))
    png16(base / "depth" / f"{stem}depth.png", dist, 512, missing=65535)
    (base / "pose").mkdir(parents=True, exist_ok=True)
    (base / "pose" / f"{stem}pose.json").write_text(
        json.dumps(
            {"camera_location": list(map(float, centre)), "final_camera_rotation": [np.pi / 2, 0, np.radians(yaw_deg)]}
        )
    )
    if global_xyz:
        write_exr_xyz(base / "global_xyz" / f"{stem}global_xyz.exr", pts)
    return pts


# ---------------------------------------------------------------- a posed-panoramas folder (panorecon's own layout)
def documented_directions(h: int, w: int) -> np.ndarray:
    """Camera-frame ray of every pixel [h, w, 3] as docs/guide.md "Your own posed panoramas" states it (not
    panorecon.geometry): pixel (r, c) looks at lon = 2 pi ((c + 0.5) / w - 0.5), lat = pi (0.5 - (r + 0.5) / h),
    direction (cos lat cos lon, -cos lat sin lon, sin lat): the centre column along +x, +y a quarter of the width
    from the left edge, +z the top row."""
    lon = 2 * np.pi * ((np.arange(w) + 0.5) / w - 0.5)
    lat = np.pi * (0.5 - (np.arange(h) + 0.5) / h)
    lon, lat = np.meshgrid(lon, lat)
    return np.stack([np.cos(lat) * np.cos(lon), -np.cos(lat) * np.sin(lon), np.sin(lat)], -1)


def axis_angle(axis, deg: float) -> np.ndarray:
    """Rodrigues: the rotation [3, 3] by ``deg`` (right hand) about ``axis``."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    t = np.radians(deg)
    return np.eye(3) + np.sin(t) * kx + (1 - np.cos(t)) * kx @ kx


def axis_angle_quaternion(axis, deg: float) -> list[float]:
    """The same rotation as a unit quaternion [w, x, y, z]: (cos t/2, sin t/2 * axis)."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    t = np.radians(deg)
    return [float(np.cos(t / 2)), *map(float, np.sin(t / 2) * k)]


def write_posed_panorama(root, name, centre, rotation, h=64, unit_per_m=1000.0, depth=True, furniture=()):
    """``root/<name>.png`` (and ``root/<name>_depth.png``, 16-bit, ``unit_per_m`` stored values per metre) of
    ROOM seen from ``centre`` with camera axes ``rotation`` (world = rotation @ camera). Returns the pose entry
    (rotation as a matrix) and the world points [h, 2h, 3] of its pixels."""
    dirs = documented_directions(h, 2 * h) @ np.asarray(rotation, float).T
    dist = cast(np.asarray(centre, float), dirs, ROOM, furniture)
    pts = np.asarray(centre, float) + dist[..., None] * dirs
    write_image(root / f"{name}.png", colour(pts))
    entry = {"name": name, "image": f"{name}.png", "position": list(map(float, centre))}
    entry["rotation"] = np.asarray(rotation, float).tolist()
    if depth:
        png16(root / f"{name}_depth.png", dist, unit_per_m)
        entry["depth"] = f"{name}_depth.png"
    return entry, pts


def write_poses(root, entries, **top):
    (root / "poses.json").write_text(json.dumps({**top, "panoramas": entries}))
