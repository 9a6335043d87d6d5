import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from panorecon.geometry import PointCloud, intrinsics_from_fov, look_at_viewmat
from panorecon.io import PanoreconInputError
from panorecon.splat.losses import (
    gaussian_window,
    pearson_depth_loss,
    ssim,
    ssim_reference,
    ssim_separable,
    total_loss,
)
from panorecon.splat.model import GaussianModel
from panorecon.splat.ply import load_ply, ply_properties, save_ply
from panorecon.splat.rasterize import cpu_backend, rasterize


def grid_cloud(spacing=0.1, n=6):
    g = np.stack(np.meshgrid(*[np.arange(n) * spacing] * 3, indexing="ij"), -1).reshape(-1, 3) + [2.0, -0.25, -0.25]
    return PointCloud(g, np.random.default_rng(0).random((len(g), 3)))


class TestModel:
    def test_init_from_point_cloud(self):
        pc = grid_cloud()
        m = GaussianModel.from_point_cloud(pc, sh_degree=2, init_opacity=0.1)
        assert len(m) == len(pc) and m.sh().shape == (len(pc), 9, 3) and m.sh_degree == 2
        # interior points of a grid have their 3 nearest neighbours at exactly the spacing
        assert torch.median(m.scales()[:, 0]).item() == pytest.approx(0.1, rel=1e-5)
        torch.testing.assert_close(m.opacities(), torch.full((len(pc),), 0.1))
        torch.testing.assert_close(m.sh0[:, 0] * 0.28209479177387814 + 0.5, torch.from_numpy(pc.rgb).float())

    def test_duplicate_points_stay_finite_and_bad_input(self):
        pc = PointCloud(np.zeros((5, 3)), np.zeros((5, 3)))
        assert torch.isfinite(GaussianModel.from_point_cloud(pc).log_scales).all()
        with pytest.raises(ValueError, match="empty"):
            GaussianModel.from_point_cloud(PointCloud(np.zeros((0, 3)), np.zeros((0, 3))))

    @settings(max_examples=12, deadline=None)
    @given(st.floats(-3, 3), st.integers(0, 2**31 - 1))
    def test_a_scaled_model_renders_the_same_picture_from_the_scaled_camera(self, log_s, seed):
        """Scale-freeness of the render: the model of a cloud s times larger, seen from a camera s times farther
        from the origin, gives the same image (its near plane, ``near_plane_for``, scales with it; a fixed
        0.01 m plane would cull a whole scene at s = 1e-3)."""
        s = 10.0**log_s
        rng = np.random.default_rng(seed)
        pc = grid_cloud(n=5)
        xyz, rgb = pc.xyz + rng.normal(0, 0.02, pc.xyz.shape), rng.random((len(pc), 3))
        m = GaussianModel.from_point_cloud(PointCloud(xyz, rgb), sh_degree=0)
        ms = GaussianModel.from_point_cloud(PointCloud(xyz * s, rgb), sh_degree=0)
        assert ms.near_plane == pytest.approx(s * m.near_plane, rel=1e-4)
        K = torch.tensor(intrinsics_from_fov(32, 32, 60), dtype=torch.float32)[None]
        eye, target = np.array([0.3, 0.1, -0.05]), np.array([2.2, 0.0, 0.0])
        backends = ["torch"] + (["cpu"] if cpu_backend.available() else [])
        for backend in backends:
            imgs = []
            for g, k in ((m, 1.0), (ms, s)):
                V = torch.tensor(look_at_viewmat(eye * k, target * k), dtype=torch.float32)[None]
                imgs.append(
                    rasterize(
                        g.means,
                        g.quats,
                        g.scales(),
                        g.opacities(),
                        g.sh(),
                        V,
                        K,
                        32,
                        32,
                        sh_degree=0,
                        near_plane=g.near_plane,
                        backend=backend,
                    )[1]
                )
            assert imgs[0].max() > 0.5  # the cloud is in the picture
            torch.testing.assert_close(imgs[1], imgs[0], atol=2e-4, rtol=0)

    @settings(max_examples=30, deadline=None)
    @given(st.floats(-8, 8), st.floats(0, 4), st.integers(0, 2**31 - 1))
    def test_near_plane_is_finite_and_positive_on_extreme_clouds(self, log_centre, log_spread, seed):
        from panorecon.splat.model import near_plane_for

        rng = np.random.default_rng(seed)
        r = 10.0 ** (log_centre + log_spread * rng.uniform(-1, 1, 200))
        d = rng.normal(size=(200, 3))
        means = torch.tensor(d / np.linalg.norm(d, axis=1, keepdims=True) * r[:, None], dtype=torch.float32)
        near = near_plane_for(means)
        assert math.isfinite(near) and 0 < near <= 0.01 * float(torch.linalg.vector_norm(means, dim=1).max())


class TestPly:
    def test_header_is_the_standard_3dgs_layout(self, tmp_path):
        m = GaussianModel.from_point_cloud(grid_cloud(n=3), sh_degree=3)
        save_ply(m, tmp_path / "g.ply")
        header = (tmp_path / "g.ply").read_bytes().split(b"end_header\n")[0].decode()
        props = [ln.split()[2] for ln in header.splitlines() if ln.startswith("property")]
        assert props[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        assert props[9:54] == [f"f_rest_{i}" for i in range(45)]
        assert props[54:] == ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
        assert "format binary_little_endian 1.0" in header and props == ply_properties(45)

    def test_round_trip_gives_identical_renders(self, tmp_path):
        m = GaussianModel.from_point_cloud(grid_cloud(), sh_degree=3)
        with torch.no_grad():
            m.shN.normal_(0, 0.2)
            m.quats.normal_()
        save_ply(m, tmp_path / "g.ply")
        m2 = load_ply(tmp_path / "g.ply")
        for a, b in zip(m.parameters(), m2.parameters()):
            torch.testing.assert_close(a.detach(), b.detach())
        K = torch.tensor(intrinsics_from_fov(32, 32, 60), dtype=torch.float32)[None]
        V = torch.tensor(look_at_viewmat([0, 0, 0], [1, 0, 0]), dtype=torch.float32)[None]

        def render(g):
            return rasterize(
                g.means, g.quats, g.scales(), g.opacities(), g.sh(), V, K, 32, 32, sh_degree=3, backend="torch"
            )[0]

        torch.testing.assert_close(render(m), render(m2))

    def test_truncated_or_foreign_files(self, tmp_path):
        save_ply(GaussianModel.from_point_cloud(grid_cloud(n=3)), tmp_path / "g.ply")
        data = (tmp_path / "g.ply").read_bytes()
        (tmp_path / "cut.ply").write_bytes(data[:-50])
        with pytest.raises(PanoreconInputError, match="truncated"):
            load_ply(tmp_path / "cut.ply")
        grid_cloud(n=3).save_ply(tmp_path / "points.ply")
        with pytest.raises(PanoreconInputError, match="3DGS"):
            load_ply(tmp_path / "points.ply")


def ssim_slow(a, b, size=11, sigma=1.5):
    """SSIM by explicit windows (float64 numpy): the reference for the convolutional version."""
    w = gaussian_window(size, sigma, torch.float64).numpy()
    H, W, C = a.shape
    vals = []
    for ch in range(C):
        for i in range(H - size + 1):
            for j in range(W - size + 1):
                x, y = a[i : i + size, j : j + size, ch], b[i : i + size, j : j + size, ch]
                mx, my = (w * x).sum(), (w * y).sum()
                sxx, syy, sxy = (w * x * x).sum() - mx**2, (w * y * y).sum() - my**2, (w * x * y).sum() - mx * my
                vals.append(((2 * mx * my + 1e-4) * (2 * sxy + 9e-4)) / ((mx**2 + my**2 + 1e-4) * (sxx + syy + 9e-4)))
    return np.mean(vals)


class TestLosses:
    def test_ssim_matches_the_windowed_reference(self):
        rng = np.random.default_rng(0)
        a = rng.random((16, 14, 3))
        b = np.clip(a + 0.1 * rng.standard_normal(a.shape), 0, 1)
        got = ssim(torch.from_numpy(a), torch.from_numpy(b)).item()
        assert got == pytest.approx(ssim_slow(a, b), abs=1e-10)
        assert ssim(torch.from_numpy(a), torch.from_numpy(a)).item() == pytest.approx(1.0)

    def test_separable_ssim_matches_the_2d_window_with_gradients(self):
        g = torch.Generator().manual_seed(2)
        a = torch.rand(2, 40, 33, 3, generator=g, dtype=torch.float64)
        b = (a + 0.2 * torch.randn(a.shape, generator=g, dtype=torch.float64)).clamp(0, 1)
        leaves = [a.clone().requires_grad_(True), a.clone().requires_grad_(True)]
        fast, ref = ssim_separable(leaves[0], b), ssim_reference(leaves[1], b)
        torch.testing.assert_close(fast, ref, rtol=0, atol=1e-13)
        fast.backward()
        ref.backward()
        assert leaves[1].grad.abs().max() > 0
        torch.testing.assert_close(leaves[0].grad, leaves[1].grad, rtol=1e-10, atol=1e-15)

    @pytest.mark.skipif(not cpu_backend.available(), reason="the C++ cpu backend could not be built here")
    @pytest.mark.parametrize(
        "case",
        [
            "noisy",
            "constant images",
            "saturated 0 and 1",
            "one output pixel (11 x 11)",
            "batch of 2, 4 channels",
            "rows of 64, 16 and 10 output columns",
        ],
    )
    def test_fused_float32_ssim_matches_the_float64_reference_with_gradients(self, case):
        """The C++ SSIM (float32 CPU images, constant target) against ssim_reference in float64: the mean and the
        gradient w.r.t. the render, on images whose variances vanish (C1, C2 carry the ratio) or saturate. Where
        the image is flat, float32 cancels in E[x^2] - mu^2 and in the gradient's large opposite terms: there the
        bound is PyTorch's own float32 path's error on the same images (2e-4 of the gradient on constant ones)."""
        g = torch.Generator().manual_seed(5)
        shape = {
            "one output pixel (11 x 11)": (1, 11, 11, 3),
            "batch of 2, 4 channels": (2, 30, 27, 4),
            "rows of 64, 16 and 10 output columns": (1, 24, 100, 3),  # the blurs' register blocks and their tail
        }.get(case, (1, 48, 41, 3))
        a = torch.rand(shape, generator=g, dtype=torch.float64)
        b = (a + 0.2 * torch.randn(shape, generator=g, dtype=torch.float64)).clamp(0, 1)
        if case == "constant images":
            a, b = torch.full(shape, 0.3, dtype=torch.float64), torch.full(shape, 0.7, dtype=torch.float64)
        if case == "saturated 0 and 1":
            a, b = (a > 0.5).double(), (b > 0.3).double()
        ref_leaf = a.clone().requires_grad_(True)
        ref = ssim_reference(ref_leaf, b)
        ref.backward()
        scale = ref_leaf.grad.abs().max().clamp_min(1e-12)
        errors = {}
        for name, fn in (("fused", ssim), ("pytorch float32", ssim_separable)):
            leaf = a.float().requires_grad_(True)
            value = fn(leaf, b.float())
            value.backward()
            assert torch.isfinite(leaf.grad).all()
            errors[name] = (
                abs(float(value) - float(ref)),
                float((leaf.grad.double() - ref_leaf.grad).abs().max() / scale),
            )
            if name == "fused":
                assert "Fused" in type(value.grad_fn).__name__
        assert errors["fused"][0] <= max(2e-6, 4 * errors["pytorch float32"][0]), errors
        assert errors["fused"][1] <= max(2e-5, 2 * errors["pytorch float32"][1]), errors

    def test_ssim_of_a_target_that_needs_a_gradient_runs_in_pytorch(self):
        a, b = torch.rand(1, 20, 20, 3, requires_grad=True), torch.rand(1, 20, 20, 3, requires_grad=True)
        value = ssim(a, b)
        value.backward()
        assert b.grad is not None and b.grad.abs().max() > 0
        torch.testing.assert_close(value, ssim_separable(a, b))

    def test_pearson_is_scale_and_shift_invariant(self):
        rng = np.random.default_rng(1)
        x = torch.from_numpy(rng.random((20, 20)))
        y = x + 0.3 * torch.from_numpy(rng.random((20, 20)))
        ref = 1 - np.corrcoef(x.numpy().ravel(), y.numpy().ravel())[0, 1]
        assert pearson_depth_loss(x, y).item() == pytest.approx(ref, abs=1e-12)
        assert pearson_depth_loss(x, 7 * y - 3).item() == pytest.approx(ref, abs=1e-12)
        y_nan = y.clone()
        y_nan[0, 0] = float("nan")
        assert torch.isfinite(pearson_depth_loss(x, y_nan))
        assert pearson_depth_loss(x, torch.ones_like(x)).item() == 0

    def test_total_loss_gradients_are_finite(self):
        r = torch.rand(1, 16, 16, 3, requires_grad=True)
        d = torch.rand(16, 16, requires_grad=True)
        loss = total_loss(r, torch.rand(1, 16, 16, 3), d, torch.rand(16, 16))
        loss.backward()
        assert torch.isfinite(r.grad).all() and torch.isfinite(d.grad).all()


def test_training_the_model_never_touches_the_point_cloud():
    pc = grid_cloud(n=3)
    before = pc.xyz.copy()
    m = GaussianModel.from_point_cloud(pc)
    with torch.no_grad():
        m.means += 1.0
    np.testing.assert_array_equal(pc.xyz, before)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), invalid=st.floats(0.0, 1.0), constant=st.booleans(), few=st.booleans())
def test_sync_free_pearson_equals_the_reference_values_and_gradients(seed, invalid, constant, few):
    """Masked sums against boolean indexing: random masks, NaN/inf teachers, a constant map, < 2 valid pixels."""
    from panorecon.splat.losses import pearson_depth_loss_reference

    g = torch.Generator().manual_seed(seed)
    x = torch.rand(12, 10, generator=g, dtype=torch.float64) * 5
    y = 3 * x + torch.rand(12, 10, generator=g, dtype=torch.float64)
    y[torch.rand(12, 10, generator=g) < invalid / 2] = float("nan")
    y[torch.rand(12, 10, generator=g) < invalid / 4] = float("inf")
    valid = torch.rand(12, 10, generator=g) >= invalid / 2
    if constant:
        y = torch.where(torch.isfinite(y), torch.full_like(y, 2.0), y)
    if few:
        valid = torch.zeros_like(valid)
        valid[0, 0] = True
    a, b = x.clone().requires_grad_(True), x.clone().requires_grad_(True)
    fast, ref = pearson_depth_loss(a, y, valid), pearson_depth_loss_reference(b, y, valid)
    torch.testing.assert_close(fast, ref, rtol=1e-10, atol=1e-12)
    fast.backward()
    ref.backward()
    torch.testing.assert_close(a.grad, b.grad, rtol=1e-8, atol=1e-12)


@pytest.mark.skipif(not cpu_backend.available(), reason="the C++ cpu backend could not be built here")
@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    invalid=st.floats(0.0, 1.0),
    constant=st.booleans(),
    few=st.booleans(),
    decades=st.floats(0.0, 7.0),
)
def test_fused_float32_pearson_matches_the_float64_reference(seed, invalid, constant, few, decades):
    """The C++ depth term (float32 CPU depths, double sums) against pearson_depth_loss_reference in float64, values
    and gradients: random masks, NaN/inf teachers and renders, a constant teacher, < 2 valid pixels, and depths
    spread over up to 7 decades (where float32 sums of the squared deviations would lose the correlation)."""
    from panorecon.splat.losses import _FusedPearson, pearson_depth_loss_reference

    g = torch.Generator().manual_seed(seed)
    x = 10 ** (torch.rand(40, 30, generator=g, dtype=torch.float64) * decades)
    y = 3 * x + x.mean() * torch.rand(40, 30, generator=g, dtype=torch.float64)
    y[torch.rand(40, 30, generator=g) < invalid / 2] = float("nan")
    y[torch.rand(40, 30, generator=g) < invalid / 4] = float("inf")
    x[torch.rand(40, 30, generator=g) < invalid / 8] = float("nan")
    valid = torch.rand(40, 30, generator=g) >= invalid / 2
    if constant:
        y = torch.where(torch.isfinite(y), torch.full_like(y, 2.0), y)
    if few:
        valid = torch.zeros_like(valid)
        valid[0, 0] = True
    x, y = x.float().double(), y.float().double()  # values float32 holds: both sides see the same inputs
    a, b = x.float().requires_grad_(True), x.clone().requires_grad_(True)
    fast, ref = pearson_depth_loss(a, y.float(), valid), pearson_depth_loss_reference(b, y, valid)
    assert type(fast.grad_fn).__name__ == _FusedPearson.__name__ + "Backward"
    torch.testing.assert_close(fast.double(), ref, rtol=0, atol=2e-6)
    fast.backward()
    ref.backward()
    assert torch.isfinite(a.grad).all()
    scale = b.grad.abs().max().clamp_min(1e-30)
    assert float((a.grad.double() - b.grad).abs().max() / scale) < 1e-5


@pytest.mark.skipif(not cpu_backend.available(), reason="the C++ cpu backend could not be built here")
def test_fused_losses_are_the_same_for_one_and_two_threads():
    """The double sums run over fixed chunks added in order: the same bits whatever the thread count."""
    from panorecon.splat.losses import l1

    g = torch.Generator().manual_seed(2)
    x = torch.rand(256, 256, generator=g) * 10
    y = x + torch.rand(256, 256, generator=g)
    out = []
    threads = torch.get_num_threads()
    try:
        for n in (1, 2):
            torch.set_num_threads(n)
            a = x.clone().requires_grad_(True)
            value = pearson_depth_loss(a, y, x > 2) + l1(a, y)
            value.backward()
            out.append((value.detach(), a.grad))
    finally:
        torch.set_num_threads(threads)
    assert torch.equal(out[0][0], out[1][0]) and torch.equal(out[0][1], out[1][1])


@pytest.mark.skipif(not cpu_backend.available(), reason="the C++ cpu backend could not be built here")
@pytest.mark.parametrize("weight", [0.8, -1.3])
def test_fused_l1_gradient_has_the_bits_of_pytorchs(weight):
    """The C++ L1's gradient rounds as autograd's backward of (a - b).abs().mean() (g / n in float32, times sgn),
    ties (a == b) and NaN (torch.sgn: 0) included; its value (double sum) within float32 rounding of PyTorch's."""
    from panorecon.splat.losses import _FusedL1, l1

    g = torch.Generator().manual_seed(5)
    x, y = torch.rand(1, 64, 48, 3, generator=g), torch.rand(1, 64, 48, 3, generator=g)
    y[0, :5] = x[0, :5]
    x[0, 7, 3, 1] = float("nan")
    a, b = x.clone().requires_grad_(True), x.clone().requires_grad_(True)
    fast, ref = l1(a, y), (b - y).abs().mean()
    assert type(fast.grad_fn).__name__ == _FusedL1.__name__ + "Backward"
    (weight * fast).backward()
    (weight * ref).backward()
    assert torch.equal(a.grad, b.grad)
    finite = ~x.isnan()
    torch.testing.assert_close(l1(x[finite], y[finite]), (x - y)[finite].abs().mean(), rtol=1e-6, atol=0)


def test_nearest_neighbour_scale_equals_brute_force():
    from panorecon.splat.model import nearest_neighbour_scale

    rng = np.random.default_rng(3)
    xyz = rng.normal(size=(300, 3))
    xyz[10] = xyz[11]  # a duplicate: distance 0 to its twin
    d = np.linalg.norm(xyz[:, None] - xyz[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    np.testing.assert_allclose(nearest_neighbour_scale(xyz, 3), np.sort(d, 1)[:, :3].mean(1), rtol=1e-12)
    np.testing.assert_allclose(nearest_neighbour_scale(xyz[:2], 3), [d[0, 1], d[0, 1]], rtol=1e-12)
    assert nearest_neighbour_scale(xyz[:1]).tolist() == [1.0]


def test_points_with_a_normal_start_as_discs_on_their_plane():
    from panorecon.splat.model import flatten_to_discs
    from panorecon.splat.rasterize import quat_to_rotmat

    rng = np.random.default_rng(0)
    n = rng.normal(size=(6, 3))
    n[1] = [0, 0, -1]  # straight down: the same disc as straight up
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    normals = n.copy()
    normals[4] = 0  # no normal: isotropic
    normals[5] = np.nan
    pc = PointCloud(rng.normal(size=(6, 3)) * 5, rng.random((6, 3)), normals=normals)
    iso = GaussianModel.from_point_cloud(pc, 0)
    disc = GaussianModel.from_point_cloud(pc, 0)
    flatten_to_discs(disc, normals, 0.1)
    R = quat_to_rotmat(disc.quats.detach() / disc.quats.detach().norm(dim=-1, keepdim=True))
    z = R[..., 2].numpy()  # the local axis the thin scale is along
    assert np.allclose(np.abs(np.einsum("nk,nk->n", z[:4], n[:4])), 1, atol=1e-6)
    s_iso, s_disc = iso.scales().detach(), disc.scales().detach()
    assert torch.allclose(s_disc[:4, :2], s_iso[:4, :2]) and torch.allclose(s_disc[:4, 2], 0.1 * s_iso[:4, 2])
    assert torch.equal(disc.quats[4:], iso.quats[4:]) and torch.equal(s_disc[4:], s_iso[4:])
    with pytest.raises(ValueError, match="normals"):
        flatten_to_discs(disc, normals[:3], 0.1)


def test_rotmat_to_wxyz_is_scipys_up_to_sign_even_at_half_turns():
    from scipy.spatial.transform import Rotation

    from panorecon.splat.model import rotmat_to_wxyz

    rots = Rotation.random(500, random_state=0)
    half_turns = Rotation.from_rotvec(np.pi * np.random.default_rng(1).normal(size=(50, 3)).clip(-1, 1))
    axis_turns = Rotation.from_rotvec(np.pi * np.eye(3))  # w = 0 exactly: the copysign shortcut fails here
    for r in (rots, half_turns, axis_turns, Rotation.identity(3)):
        want = r.as_quat()[:, [3, 0, 1, 2]]
        got = rotmat_to_wxyz(r.as_matrix())
        np.testing.assert_allclose(np.abs((got * want).sum(1)), 1.0, atol=1e-12)  # q and -q are one rotation
