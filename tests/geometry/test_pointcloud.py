

def test_subset_keeps_per_point_scalars_aligned():
    import numpy as np

    from panorecon.geometry import PointCloud

    xyz = np.arange(12, dtype=np.float64).reshape(4, 3)
    pc = PointCloud(xyz, np.zeros((4, 3)), meta={"scalars": {"error_m": np.array([0.1, 0.2, 0.3, 0.4])}})
    sub = pc.subset(np.array([False, True, False, True]))
    np.testing.assert_allclose(sub.meta["scalars"]["error_m"], [0.2, 0.4])
    assert len(pc.meta["scalars"]["error_m"]) == 4
