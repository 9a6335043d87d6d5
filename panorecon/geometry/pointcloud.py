"""The one point-cloud type every point source returns, with PLY I/O through Open3D's tensor API."""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .sphere import erp_directions


@dataclass
class PointCloud:
    """Points in the world frame.

    xyz: [N, 3] float32 metres; rgb: [N, 3] float32 in [0, 1]; normals: [N, 3] float32 unit or None;
    view_id: [N] int32 index of the view that produced each point (-1 when none) or None.
    """

    xyz: np.ndarray
    rgb: np.ndarray
    normals: np.ndarray | None = None
    view_id: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.xyz = np.ascontiguousarray(self.xyz, dtype=np.float32).reshape(-1, 3)
        self.rgb = np.ascontiguousarray(self.rgb, dtype=np.float32).reshape(-1, 3)
        if len(self.rgb) != len(self.xyz):
            raise ValueError(f"PointCloud: {len(self.xyz)} points but {len(self.rgb)} colours")
        if not np.isfinite(self.xyz).all():
            raise ValueError("PointCloud: xyz holds NaN or Inf; drop those points before building the cloud")
        if self.normals is not None:
            self.normals = np.ascontiguousarray(self.normals, dtype=np.float32).reshape(-1, 3)
        if self.view_id is not None:
            self.view_id = np.ascontiguousarray(self.view_id, dtype=np.int32).reshape(-1)

    def __len__(self) -> int:
        return len(self.xyz)

    def subset(self, index: np.ndarray) -> "PointCloud":
        """The points selected by a boolean mask or index array (per-point scalars in meta['scalars'] too)."""
        meta = dict(self.meta)
        if "scalars" in meta:
            meta["scalars"] = {k: np.asarray(v)[index] for k, v in meta["scalars"].items()}
        return PointCloud(
            self.xyz[index],
            self.rgb[index],
            None if self.normals is None else self.normals[index],
            None if self.view_id is None else self.view_id[index],
            meta,
        )

    def to_open3d(self):
        """A legacy ``open3d.geometry.PointCloud`` (xyz, colours, normals)."""
        import open3d as o3d

        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self.xyz.astype(np.float64)))
        pc.colors = o3d.utility.Vector3dVector(self.rgb.astype(np.float64))
        if self.normals is not None:
            pc.normals = o3d.utility.Vector3dVector(self.normals.astype(np.float64))
        return pc

    def save_ply(self, path: str | os.PathLike) -> None:
        """Write a binary PLY (x,y,z, red,green,blue as float, nx,ny,nz, view_id) atomically."""
        import open3d as o3d

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        pc = o3d.t.geometry.PointCloud()
        pc.point.positions = o3d.core.Tensor(self.xyz)
        pc.point.colors = o3d.core.Tensor(self.rgb)
        if self.normals is not None:
            pc.point.normals = o3d.core.Tensor(self.normals)
        if self.view_id is not None:
            pc.point.view_id = o3d.core.Tensor(self.view_id.reshape(-1, 1))
        from ..io import atomic_write

        with atomic_write(path, suffix=".ply") as tmp:
            if not o3d.t.io.write_point_cloud(str(tmp), pc, write_ascii=False):
                raise OSError(f"could not write point cloud to {path}")

    @classmethod
    def load_ply(cls, path: str | os.PathLike) -> "PointCloud":
        """Read a PLY written by ``save_ply`` or any PLY with positions (colours optional), checked: the header,
        the file size against the header's vertex count (binary files), the count Open3D read, and finite
        positions. A bad file raises ``PanoreconInputError`` naming it."""
        import open3d as o3d

        from ..io import PanoreconInputError, quiet_native_stderr

        path = Path(path)
        if not path.is_file():
            raise PanoreconInputError(f"point cloud {path}: no such file")
        n = check_ply_header(path)
        with quiet_native_stderr():  # Open3D prints "Read PLY failed" itself; the checks below say why
            pc = o3d.t.io.read_point_cloud(str(path))
        if "positions" not in pc.point or len(pc.point.positions) != n:
            got = len(pc.point.positions) if "positions" in pc.point else 0
            raise PanoreconInputError(f"point cloud {path}: read {got} of the {n} vertices its header announces "
                                      "(cut-off or corrupt file)")
        xyz = pc.point.positions.numpy()
        if not np.isfinite(xyz).all():
            raise PanoreconInputError(f"point cloud {path}: {int((~np.isfinite(xyz).all(1)).sum())} vertices have "
                                      "NaN or Inf positions")
        rgb = pc.point.colors.numpy() if "colors" in pc.point else np.full_like(xyz, 0.5)
        if rgb.dtype == np.uint8:
            rgb = rgb / 255.0
        normals = pc.point.normals.numpy() if "normals" in pc.point else None
        view_id = pc.point.view_id.numpy().reshape(-1) if "view_id" in pc.point else None
        extra = {k: pc.point[k].numpy().reshape(len(xyz), -1) for k in pc.point
                 if k not in ("positions", "colors", "normals", "view_id")}
        return cls(xyz, rgb, normals, view_id, {"scalars": extra} if extra else {})


_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
              "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}


def check_ply_header(path: Path) -> int:
    """Check a PLY's header (and, for a binary file whose elements have no list properties, its exact size)
    -> the vertex count. Raises ``PanoreconInputError`` naming the file and what is wrong."""
    from ..io import PanoreconInputError

    with open(path, "rb") as f:
        head = f.read(65536)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        raise PanoreconInputError(f"point cloud {path}: not a PLY file (expected a 'ply' header ending in end_header)")
    body_start = head.index(b"\n", end) + 1 if b"\n" in head[end:] else len(head)
    lines = head[:end].decode("ascii", "replace").splitlines()
    fmt, elements, vertex_props = None, [], set()  # elements: [name, count, row bytes or None (list properties)]
    for ln in lines:
        w = ln.split()
        if not w:
            continue
        try:
            if w[0] == "format":
                fmt = w[1]
            elif w[0] == "element":
                elements.append([w[1], int(w[2]), 0])
            elif w[0] == "property" and elements:
                if elements[-1][0] == "vertex":
                    vertex_props.add(w[-1])
                size = None if w[1] == "list" or elements[-1][2] is None else _PLY_SIZES.get(w[1])
                elements[-1][2] = None if size is None else elements[-1][2] + size
        except (IndexError, ValueError):
            raise PanoreconInputError(f"point cloud {path}: malformed PLY header line {ln!r}") from None
    vertex = [e for e in elements if e[0] == "vertex"]
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian") or not vertex or vertex[0][1] <= 0:
        raise PanoreconInputError(f"point cloud {path}: the PLY header has no vertices or an unknown format "
                                  f"({fmt!r}); expected 'element vertex N' with N > 0")
    if not {"x", "y", "z"} <= vertex_props:
        raise PanoreconInputError(f"point cloud {path}: its vertices have no x, y, z properties")
    if fmt == "ascii":
        with open(path, "rb") as f:
            f.seek(body_start)
            rows = sum(1 for line in f if line.strip())
        if rows < sum(e[1] for e in elements):
            raise PanoreconInputError(f"point cloud {path}: {rows} data lines for the {sum(e[1] for e in elements)} "
                                      "rows its header announces (cut-off or corrupt file)")
    elif all(e[2] is not None for e in elements):
        expected = body_start + sum(e[1] * e[2] for e in elements)
        actual = path.stat().st_size
        if actual != expected:
            raise PanoreconInputError(f"point cloud {path}: {actual} bytes, expected {expected} for the "
                                      f"{vertex[0][1]} vertices its header announces (cut-off or corrupt file)")
    return vertex[0][1]


def erp_point_cloud(rgb: np.ndarray, distance: np.ndarray, keep: np.ndarray | None = None,
                    origin=(0.0, 0.0, 0.0)) -> PointCloud:
    """Back-project an ERP image [H, W, 3] (uint8 or float in [0, 1]) and ray distance [H, W] (metres).

    Pixels with non-finite or non-positive distance, or outside ``keep``, give no point.
    """
    H, W = distance.shape
    ok = np.isfinite(distance) & (distance > 0)
    if keep is not None:
        ok &= keep
    d = erp_directions(H, W)[ok]
    xyz = d * distance[ok][:, None] + np.asarray(origin, float)
    col = rgb[ok].astype(np.float32)
    if rgb.dtype == np.uint8:
        col /= 255.0
    return PointCloud(xyz, col, normals=None, view_id=None)
