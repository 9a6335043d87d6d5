"""`panorecon mesh`: normals towards the centre, a Poisson surface close to the truth, its Chamfer, bad input."""

import numpy as np
import open3d as o3d
import pytest

from panorecon.cli import main
from panorecon.geometry import PointCloud, fibonacci_directions
from panorecon.io import PanoreconInputError
from panorecon.mesh import distance_to_mesh, mesh_chamfer, oriented_normals, poisson_mesh, sample_surface

pytest.importorskip("pymeshlab")


def sphere(radius=2.0, n=3000) -> PointCloud:
    d = fibonacci_directions(n)
    return PointCloud(d * radius, 0.5 + 0.4 * d)


def true_sphere(radius=2.0):
    m = o3d.geometry.TriangleMesh.create_sphere(radius, resolution=60)
    return np.asarray(m.vertices), np.asarray(m.triangles)


def test_normals_face_the_centre():
    pc = sphere()
    n = oriented_normals(pc.xyz, centre=(0.3, 0.0, 0.0))
    assert np.allclose(np.linalg.norm(n, axis=1), 1, atol=1e-6)
    assert (np.einsum("ij,ij->i", n, (0.3, 0, 0) - pc.xyz) > 0).all()
    assert np.mean(np.einsum("ij,ij->i", n, -pc.xyz / 2.0)) > 0.99  # inward radial, for a sphere


def test_distance_to_mesh_and_chamfer_on_known_shapes():
    v, f = true_sphere(2.0)
    p = fibonacci_directions(200) * 3.0
    np.testing.assert_allclose(distance_to_mesh(p, v, f), 1.0, atol=0.01)  # the tessellation's sag is < 1 cm
    samples = sample_surface(v, f, 5000)
    assert np.abs(np.linalg.norm(samples, axis=1) - 2.0).max() < 0.01
    d = mesh_chamfer(v, f, v * 1.1, f, samples=5000)  # concentric spheres 0.2 m apart
    assert d["accuracy"] == pytest.approx(0.2, abs=0.01) and d["chamfer"] == pytest.approx(0.2, abs=0.01)


def test_poisson_surface_of_a_sphere_is_close_and_trimmed():
    v, f, c = poisson_mesh(sphere(), depth=5, trim=0.1)
    assert len(f) > 500 and f.max() < len(v) and c.shape == v.shape
    tv, tf = true_sphere()
    d = mesh_chamfer(v, f, tv, tf, samples=20_000)
    assert d["chamfer"] < 0.05, d
    v0, f0, _ = poisson_mesh(sphere(), depth=5, trim=0.0)
    assert len(v) < len(v0)  # the trim removed the lowest-density vertices


def test_cli_writes_the_mesh_and_rejects_bad_input(tmp_path, capsys):
    sphere().save_ply(tmp_path / "c.ply")
    assert main(["mesh", str(tmp_path / "c.ply"), "--out", str(tmp_path / "m.ply"), "--depth", "5"]) == 0
    m = o3d.io.read_triangle_mesh(str(tmp_path / "m.ply"))
    assert len(m.triangles) > 500 and m.has_vertex_colors()
    assert "triangles" in capsys.readouterr().out
    assert main(["mesh", str(tmp_path / "missing.ply"), "--out", str(tmp_path / "x.ply")]) == 2
    assert main(["mesh", str(tmp_path / "c.ply"), "--out", str(tmp_path / "x.ply"), "--trim", "1.5"]) == 2
    assert "--trim" in capsys.readouterr().err and not (tmp_path / "x.ply").exists()
    with pytest.raises(PanoreconInputError, match="at least 10"):
        poisson_mesh(PointCloud(np.zeros((3, 3)), np.zeros((3, 3))))


def test_chamfer_to_the_true_mesh_uses_the_source_reports_scale(tmp_path, capsys):
    """A cloud at twice the true scale, with a report saying its source scaled it by 0.5 for its metrics, is
    measured at the true scale; the same cloud taken as metric (--scene) is not."""
    import json
    import re

    from panorecon.scenes import load_scene

    gt = load_scene("bedroom", 128).point_cloud()
    PointCloud(gt.xyz * 2, gt.rgb).save_ply(tmp_path / "x_cloud.ply")
    (tmp_path / "x_report.json").write_text(json.dumps({"scene": "bedroom", "points": {"scale_applied": 0.5}}))
    accuracy = []
    for extra in ([], ["--scene", "bedroom"]):
        assert (
            main(
                [
                    "mesh",
                    str(tmp_path / "x_cloud.ply"),
                    "--out",
                    str(tmp_path / "m.ply"),
                    "--depth",
                    "6",
                    "--centre",
                    "0,0,0",
                ]
                + extra
            )
            == 0
        )
        accuracy.append(float(re.search(r"accuracy ([0-9.]+)", capsys.readouterr().out).group(1)))
    assert accuracy[0] < 0.05 < 0.5 < accuracy[1], accuracy
