"""``panorecon mesh CLOUD.ply --out mesh.ply``: a surface from a point cloud by pymeshlab's screened Poisson.

Normals are estimated from the 16 nearest neighbours (Open3D) and turned towards the panorama centre (every
point was seen from there, so its surface faces it); the Poisson surface's vertices of lowest density (the
per-vertex scalar MeshLab writes: how many samples support them) are trimmed with their faces, which removes
the surface Poisson invents where nothing was seen. On a synthetic scene the Chamfer distance to the true
mesh is reported: area-uniform samples of each mesh, exact point-to-triangle distance to the other; a cloud
from a non-metric teacher is first scaled by the median factor its source report applied to its own metrics.
pymeshlab is the ``mesh`` extra.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from .geometry import PointCloud
from .io import PanoreconInputError, atomic_write

MIN_POINTS = 10  # fewer points fit no surface


def oriented_normals(xyz: np.ndarray, centre=(0.0, 0.0, 0.0), knn: int = 16) -> np.ndarray:
    """Unit normals [N, 3] float64 from a k-NN plane fit, each flipped to face ``centre`` (metres)."""
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(xyz, np.float64)))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=knn))
    n = np.asarray(pc.normals)
    flip = np.einsum("ij,ij->i", n, np.asarray(centre, float) - xyz) < 0
    n[flip] *= -1
    return n


def poisson_mesh(pc: PointCloud, depth: int = 9, trim: float = 0.1, centre=(0.0, 0.0, 0.0)):
    """(vertices [V,3] float64 m, faces [F,3] int, colours [V,3] in [0,1]) of the screened Poisson surface of
    ``pc`` at octree ``depth``, less the vertices below the ``trim`` quantile of density and their faces."""
    try:
        import pymeshlab
    except ImportError:
        raise PanoreconInputError("`panorecon mesh` needs pymeshlab: pip install 'panorecon[mesh]'") from None
    if len(pc) < MIN_POINTS:
        raise PanoreconInputError(f"the point cloud has {len(pc)} points: a surface needs at least {MIN_POINTS}")
    if not 0 <= trim < 1:
        raise PanoreconInputError(f"--trim {trim}: expected a density quantile in [0, 1)")
    xyz = pc.xyz.astype(np.float64)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(
        pymeshlab.Mesh(
            vertex_matrix=xyz,
            v_normals_matrix=oriented_normals(xyz, centre),
            v_color_matrix=np.c_[np.clip(pc.rgb, 0, 1), np.ones(len(pc))].astype(np.float64),
        )
    )
    # one thread: its OpenMP workers spin, and on a shared or busy machine that made it 20x slower here
    ms.generate_surface_reconstruction_screened_poisson(depth=depth, preclean=True, threads=1)
    m = ms.current_mesh()
    v, f = m.vertex_matrix(), m.face_matrix()
    keep = m.vertex_scalar_array() >= np.quantile(m.vertex_scalar_array(), trim)
    faces = f[keep[f].all(1)]
    index = np.cumsum(keep) - 1
    return v[keep], index[faces], m.vertex_color_matrix()[keep, :3]


def save_mesh(path, vertices: np.ndarray, faces: np.ndarray, colours: np.ndarray) -> None:
    """A binary PLY of the triangle mesh with vertex colours, written atomically (Open3D)."""
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(faces))
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.clip(colours, 0, 1))
    with atomic_write(path, suffix=".ply") as tmp:
        if not o3d.io.write_triangle_mesh(str(tmp), mesh):
            raise OSError(f"could not write {path}")


def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """``n`` points [n, 3] uniform by area on the triangles (metres)."""
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(faces), n, p=area / area.sum())
    u, v = rng.uniform(size=(2, n))
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[pick]
    return t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])


def distance_to_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Exact distance [N] (metres) from each point to the nearest triangle (Open3D RaycastingScene)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32)))
    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy().astype(np.float64)


def mesh_chamfer(v1, f1, v2, f2, samples: int = 100_000, seed: int = 0) -> dict:
    """accuracy (mean distance of mesh 1's samples to mesh 2), completeness (the reverse) and chamfer (their
    mean), metres."""
    acc = float(distance_to_mesh(sample_surface(v1, f1, samples, seed), v2, f2).mean())
    comp = float(distance_to_mesh(sample_surface(v2, f2, samples, seed + 1), v1, f1).mean())
    return {"accuracy": acc, "completeness": comp, "chamfer": 0.5 * (acc + comp), "samples": samples}


def _report_of(cloud: Path) -> dict:
    """The point source's report beside the cloud (X_cloud.ply -> X_report.json), or {}."""
    rep = cloud.with_name(cloud.name.replace("_cloud.ply", "_report.json"))
    return json.loads(rep.read_text()) if rep != cloud and rep.is_file() else {}


def cmd_mesh(cfg) -> int:
    """``panorecon mesh`` (a ``configs.MeshConfig``): the Poisson mesh of a cloud, and its Chamfer to a true mesh."""
    cloud = Path(cfg.cloud)
    try:
        pc = PointCloud.load_ply(cloud)
    except (FileNotFoundError, ValueError) as e:
        raise PanoreconInputError(str(e)) from None
    if len(pc) < MIN_POINTS:
        raise PanoreconInputError(f"{cloud}: {len(pc)} points; a surface needs at least {MIN_POINTS}")
    centre = cfg.centre
    report = _report_of(cloud)
    name = cfg.scene or report.get("scene")
    # the source's protocol: a non-metric teacher's cloud is compared after its median scale (sources/run.py)
    scale = float(report.get("points", {}).get("scale_applied", 1.0)) if not cfg.scene else 1.0
    scene = None
    if name:  # before the mesh is made or written: a bad --scene fails first
        from .scenes import load_scene

        scene = load_scene(name, 64)
    t = time.perf_counter()
    v, f, c = poisson_mesh(pc, cfg.depth, cfg.trim, centre)
    seconds = time.perf_counter() - t
    save_mesh(cfg.out, v, f, c)
    line = f"{cloud}: {len(pc)} points -> {len(v)} vertices, {len(f)} triangles in {seconds:.1f} s -> {cfg.out}"
    if scene is not None:
        if scene.world is None:
            line += f"; Chamfer n/a: scene {name!r} has no true mesh"
        else:
            true = scene.world.mesh()
            d = mesh_chamfer(v * scale, f, np.asarray(true.vertices), np.asarray(true.triangles))
            line += (
                f"; to {name}'s true mesh"
                + (f" (mesh scaled by the source's median factor {scale:.4f})" if scale != 1.0 else "")
                + f": Chamfer {d['chamfer']:.4f} m (accuracy {d['accuracy']:.4f}, completeness "
                f"{d['completeness']:.4f}, incl. surfaces the panorama cannot see)"
            )
    print(line)
    return 0
