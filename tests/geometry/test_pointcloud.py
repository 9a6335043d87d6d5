def test_subset_keeps_per_point_scalars_aligned():
    import numpy as np

    from panorecon.geometry import PointCloud

    xyz = np.arange(12, dtype=np.float64).reshape(4, 3)
    pc = PointCloud(xyz, np.zeros((4, 3)), meta={"scalars": {"error_m": np.array([0.1, 0.2, 0.3, 0.4])}})
    sub = pc.subset(np.array([False, True, False, True]))
    np.testing.assert_allclose(sub.meta["scalars"]["error_m"], [0.2, 0.4])
    assert len(pc.meta["scalars"]["error_m"]) == 4


def _cloud(n=50, extras=True):
    import numpy as np

    from panorecon.geometry import PointCloud

    rng = np.random.default_rng(0)
    return PointCloud(
        rng.normal(size=(n, 3)),
        rng.random((n, 3)),
        rng.normal(size=(n, 3)) if extras else None,
        np.arange(n) % 7 if extras else None,
    )


def test_ply_round_trip_in_numpy_and_through_open3d(tmp_path):
    """The NumPy writer and reader against Open3D's: either reads the other's file, all fields intact."""
    import numpy as np
    import open3d as o3d

    from panorecon.geometry import PointCloud

    for extras in (True, False):
        pc = _cloud(extras=extras)
        pc.save_ply(tmp_path / "a.ply")
        back = PointCloud.load_ply(tmp_path / "a.ply")
        np.testing.assert_array_equal(back.xyz, pc.xyz)
        np.testing.assert_array_equal(back.rgb, pc.rgb)
        assert (back.normals is None) == (not extras) and (back.view_id is None) == (not extras)
        if extras:
            np.testing.assert_array_equal(back.normals, pc.normals)
            np.testing.assert_array_equal(back.view_id, pc.view_id)
        theirs = o3d.t.io.read_point_cloud(str(tmp_path / "a.ply"))
        np.testing.assert_array_equal(theirs.point.positions.numpy(), pc.xyz)
        np.testing.assert_array_equal(theirs.point.colors.numpy(), pc.rgb)
    # files Open3D writes: binary (read in NumPy) and ASCII (read through Open3D), uint8 colours scaled
    pc = _cloud(extras=False)
    t = o3d.t.geometry.PointCloud()
    t.point.positions = o3d.core.Tensor(pc.xyz)
    t.point.colors = o3d.core.Tensor((pc.rgb * 255).round().astype(np.uint8))
    t.point.error_m = o3d.core.Tensor(np.arange(len(pc), dtype=np.float32).reshape(-1, 1))
    for ascii_ in (False, True):
        o3d.t.io.write_point_cloud(str(tmp_path / "o.ply"), t, write_ascii=ascii_)
        back = PointCloud.load_ply(tmp_path / "o.ply")
        np.testing.assert_allclose(back.xyz, pc.xyz, atol=1e-5 if ascii_ else 0)
        np.testing.assert_allclose(back.rgb, (pc.rgb * 255).round() / 255, atol=1e-6)
        np.testing.assert_allclose(back.meta["scalars"]["error_m"][:, 0], np.arange(len(pc)))


def test_a_truncated_or_empty_ply_is_refused(tmp_path):
    import pytest

    from panorecon.geometry import PointCloud
    from panorecon.io import PanoreconInputError

    _cloud().save_ply(tmp_path / "a.ply")
    raw = (tmp_path / "a.ply").read_bytes()
    (tmp_path / "t.ply").write_bytes(raw[:-10])
    with pytest.raises(PanoreconInputError, match="cut-off or corrupt"):
        PointCloud.load_ply(tmp_path / "t.ply")
    with pytest.raises(PanoreconInputError, match="no such file"):
        PointCloud.load_ply(tmp_path / "none.ply")
