import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from panorecon.fusion import FusionConfig, fuse_views
from panorecon.fusion.affine import _reference_shift_gauge, align_affine_views
from panorecon.geometry import ViewDepth, centred_camera, erp_directions, make_layout
from panorecon.metrics import depth_metrics

from .conftest import box_distance, make_views


class TestAccuracy:
    def test_exact_views_recover_the_truth_up_to_one_scale(self, fib20, box_truth):
        views = make_views(fib20, 128, np.random.default_rng(0))
        r = fuse_views(views, 64, 128)
        m = depth_metrics(r.distance, box_truth(64))
        assert r.seen.all() and m["abs_rel"] < 5e-3, m
        # the per-view scales it found undo the random ones: scale_i * raw_i agree with each other
        assert r.report["residual"] < 1e-3

    def test_fusion_really_fuses_noisy_views(self, fib20, box_truth):
        rng = np.random.default_rng(1)
        views = make_views(fib20, 128, rng, noise=0.03)
        fused = depth_metrics(fuse_views(views, 64, 128).distance, box_truth(64))["abs_rel"]
        per_view = np.median(
            [depth_metrics(v.to_distance(), box_distance(v.camera.world_rays()))["abs_rel"] for v in views]
        )
        assert fused <= 0.7 * per_view, (fused, per_view)

    def test_overlapping_views_average_their_noise(self, box_truth):
        """The footprint-averaged bilinear warp averages per-pixel teacher noise that nearest-neighbour
        passes through (12 views of 90 degrees, 128 px, on a 256 x 128 ERP: 2 x 2 sub-rays per pixel)."""
        views = make_views(make_layout("icosahedron-vertices", fov_deg=90), 128, np.random.default_rng(5), noise=0.02)
        err = {
            s: depth_metrics(fuse_views(views, 128, 256, FusionConfig(sampling=s)).distance, box_truth(128))["abs_rel"]
            for s in ("linear", "nearest")
        }
        assert err["linear"] <= 0.7 * err["nearest"], err

    def test_affine_disparity_views_are_aligned(self, fib20, box_truth):
        rng = np.random.default_rng(3)
        views, c = [], rng.uniform(-0.05, 0.05, 20)
        c -= c.mean()  # what the mean-shift gauge assumes; the default reference gauge needs no such thing
        for f, ci in zip(fib20.directions, c):
            cam = centred_camera(f, 96, fib20.fov_deg)
            z = box_distance(cam.world_rays()) / cam.z_to_distance_factor()
            alpha = rng.uniform(0.5, 2)
            raw = alpha / z + ci * alpha  # disparity up to scale alpha and shift
            views.append(ViewDepth(cam, raw.astype(np.float32), "disparity", np.ones(raw.shape, bool), affine=True))
        r = fuse_views(views, 64, 128)
        assert depth_metrics(r.distance, box_truth(64))["abs_rel"] < 1e-2
        dists, shifts, rep = align_affine_views(views)
        assert rep["pairs"] > 20 and len(dists) == 20

    @pytest.mark.parametrize("gauge, scale_rtol, fused_max", [("mean-shift", 0.05, 0.015), ("reference", 0.12, 0.015)])
    def test_noisy_affine_views_keep_their_relative_scales(self, fib20, box_truth, gauge, scale_rtol, fused_max):
        """3 % noise on disparity: a least-squares solve with a_ref = 1 shrinks the other views' scales (errors
        in variables; the reference gauge's least-squares step alone: 11 % off, fused AbsRel 0.029); the
        alignment must recover the true ratios."""
        views, alphas = _noisy_disparity_views(fib20, noise=0.03, offset=0.0)
        dists, shifts, rep = align_affine_views(views, gauge=gauge)
        ref = rep["reference_view"]
        np.testing.assert_allclose(np.array(rep["scale"]), alphas[ref] / alphas, rtol=scale_rtol)
        fused = fuse_views(views, 64, 128, FusionConfig(affine_gauge=gauge)).distance
        assert depth_metrics(fused, box_truth(64))["abs_rel"] < fused_max

    def test_an_offset_output_is_aligned_by_the_reference_gauge_not_by_mean_shift(self, fib20, box_truth):
        """A network's raw disparity has an offset of its own (raw = alpha (1/z + c_i) - 3: the shifts do not
        average to zero): the reference gauge recovers the truth, the mean-shift gauge cannot."""
        views, _ = _noisy_disparity_views(fib20, noise=0.0, offset=3.0)
        err = {
            g: depth_metrics(fuse_views(views, 64, 128, FusionConfig(affine_gauge=g)).distance, box_truth(64))[
                "abs_rel"
            ]
            for g in ("reference", "mean-shift")
        }
        assert err["reference"] < 5e-3 and err["mean-shift"] > 0.1, err

    def test_a_teacher_of_noise_still_gets_positive_distances_on_the_reference(self):
        """Raw values that carry no depth (a random-weight network: tiny, noisy, overlaps that agree on nothing):
        the misfit ratio's minimum may put every reference pixel at t <= 0; beta is kept where the reference's t
        is positive, so the reference view keeps a finite distance on every pixel."""
        rng = np.random.default_rng(0)
        layout = make_layout("fibonacci", 6)
        views = []
        for f in layout.directions:
            cam = centred_camera(f, 32, layout.fov_deg)
            raw = rng.uniform(0, 1e-9) + rng.uniform(-3e-11, 1e-9) * rng.random((32, 32))
            views.append(ViewDepth(cam, raw.astype(np.float32), "disparity", np.ones(raw.shape, bool), affine=True))
        dists, _, rep = align_affine_views(views)
        ref = rep["reference_view"]
        assert np.isfinite(dists[ref]).all() and (dists[ref] > 0).all()

    @settings(max_examples=25, deadline=None)
    @given(seed=st.integers(0, 10_000), noise=st.floats(0.0, 0.05))
    def test_reference_shift_is_the_minimum_of_the_misfit_ratio(self, seed, noise):
        """The closed form (a generalised eigenproblem) against the obviously-correct slow path: E(beta) / D(beta)
        by a least-squares solve per beta over a fine grid, then a bounded scalar minimisation."""
        from scipy.optimize import minimize_scalar

        M, ref = _random_overlap_equations(np.random.default_rng(seed), noise)
        _, b = _reference_shift_gauge(M, ref)

        def ratio(beta):
            y = np.array([1.0, beta])
            rest = [k for k in range(M.shape[1]) if k not in (2 * ref, 2 * ref + 1)]
            rhs = -M[:, [2 * ref, 2 * ref + 1]] @ y
            x = np.linalg.lstsq(M[:, rest], rhs, rcond=None)[0]
            return np.sum((M[:, rest] @ x - rhs) ** 2) / np.sum(rhs**2)

        grid = np.linspace(-20, 20, 801)
        best = grid[np.argmin([ratio(v) for v in grid])]
        slow = minimize_scalar(ratio, bounds=(best - 0.06, best + 0.06), method="bounded", options={"xatol": 1e-10})
        assert ratio(b[ref]) <= slow.fun * (1 + 1e-6) + 1e-15
        assert b[ref] == pytest.approx(slow.x, abs=1e-3 * max(1.0, abs(slow.x)))

    def test_a_view_without_overlap_is_reported_unconnected(self, fib20):
        views = make_views(fib20, 32, np.random.default_rng(22))
        views = [ViewDepth(v.camera, 1.0 / v.depth, "disparity", v.valid, affine=True) for v in views]
        far = centred_camera(np.array([0.0, 0.0, 1.0]), 8, 1.0)  # a 1-degree view straight up: overlaps nothing
        views.append(ViewDepth(far, np.ones((8, 8), np.float32), "disparity", np.ones((8, 8), bool), affine=True))
        _, _, rep = align_affine_views(views[:3] + views[-1:])
        assert 3 in rep["unconnected_views"] and rep["scale"][3] == 1.0 and rep["shift"][3] == 0.0


class TestNumericalStability:
    def test_huge_depth_range_1e_minus_3_to_1e4(self, fib20):
        def field(d):  # log10 distance sweeps -3 .. 4 smoothly over the sphere
            return 10.0 ** (0.5 + 3.5 * np.tanh(3 * d[..., 0]))

        views = make_views(fib20, 96, np.random.default_rng(4), field=field)
        truth = field(erp_directions(48, 96))
        assert truth.min() < 2e-3 and truth.max() > 5e3
        whole = fuse_views(views, 48, 96, FusionConfig(edge_jump=None))
        assert np.isfinite(whole.distance).all()
        assert depth_metrics(whole.distance, truth)["abs_rel"] < 0.05
        # by default the band where the field rises by more than 1.5x per view pixel is not observed (an edge to
        # the views: depth_edge_pixels); everything else is, as accurately
        r = fuse_views(views, 48, 96)
        assert r.seen.mean() > 0.8 and np.isfinite(r.distance[r.seen]).all() and np.isnan(r.distance[~r.seen]).all()
        assert depth_metrics(r.distance, truth)["abs_rel"] < 0.05

    def test_sky_pixels_and_unseen_pixels(self, fib20):
        def field(d):  # an open box: sky above the horizon
            out = box_distance(d)
            return np.where(d[..., 2] > 0.1, np.inf, out)

        views = make_views(fib20, 96, np.random.default_rng(5), field=field)
        for v in views:
            assert not v.valid[np.isinf(field(v.camera.world_rays()))].any()
        r = fuse_views(views, 48, 96)
        sky = erp_directions(48, 96)[..., 2] > 0.15
        assert np.isnan(r.distance[sky]).all() and not r.seen[sky].any()
        ground = erp_directions(48, 96)[..., 2] < 0.0
        assert np.isfinite(r.distance[ground]).all()

    def test_a_view_with_no_valid_pixel_and_a_single_view(self, fib20):
        views = make_views(fib20, 64, np.random.default_rng(6))
        views[3] = ViewDepth(views[3].camera, np.full((64, 64), np.nan, np.float32), "z", np.zeros((64, 64), bool))
        assert np.isfinite(fuse_views(views, 32, 64).distance[fuse_views(views, 32, 64).seen]).all()
        one = fuse_views(views[:1], 32, 64)
        assert one.seen.any() and not one.seen.all()
        assert np.isfinite(one.distance[one.seen]).all() and np.isnan(one.distance[~one.seen]).all()

    def test_two_hundred_views(self):
        layout = make_layout("fibonacci", 200)
        r = fuse_views(make_views(layout, 16, np.random.default_rng(7)), 32, 64)
        assert r.seen.all() and np.isfinite(r.distance).all() and len(r.view_scale) == 200

    def test_tiny_panorama_16x8(self, fib20):
        r = fuse_views(make_views(fib20, 16, np.random.default_rng(8)), 8, 16)
        assert r.distance.shape == (8, 16) and np.isfinite(r.distance[r.seen]).all()

    @pytest.mark.slow
    def test_large_panorama_4096x2048(self, fib20, box_truth):
        r = fuse_views(make_views(fib20, 512, np.random.default_rng(9)), 2048, 4096)
        assert depth_metrics(r.distance, box_truth(2048))["abs_rel"] < 1e-2

    @pytest.mark.parametrize("fov", [1.0, 179.0])
    def test_extreme_fields_of_view(self, fov):
        layout = make_layout("fibonacci", 20, fov_deg=fov)
        views = make_views(layout, 32, np.random.default_rng(10))
        r = fuse_views(views, 32, 64)
        assert r.seen.any() and np.isfinite(r.distance[r.seen]).all()
        if fov > 170:  # every pixel is seen; the default drops some: a 32 px view of 179 degrees has a central
            # pixel 148 degrees wide, whose neighbours' distances bend by more than edge_jump (depth_edge_pixels)
            assert fuse_views(views, 32, 64, FusionConfig(edge_jump=None)).seen.all()

    def test_nan_inf_zero_negative_teacher_values_are_ignored(self, fib20, box_truth):
        views = make_views(fib20, 64, np.random.default_rng(11))
        rng = np.random.default_rng(12)
        for v in views:
            bad = rng.random(v.depth.shape) < 0.05
            v.depth[bad] = rng.choice([np.nan, np.inf, 0.0, -3.0], bad.sum()).astype(np.float32)
            v.valid[:] = True  # a teacher that vouches for everything
        r = fuse_views(views, 32, 64)
        assert np.isfinite(r.distance[r.seen]).all()
        assert depth_metrics(r.distance, box_truth(32))["abs_rel"] < 0.02

    @settings(max_examples=12, deadline=None)
    @given(st.floats(-6, 6), st.floats(-6, 6), st.floats(-6, 6))
    def test_any_weights_from_1e_minus_6_to_1e6(self, lg, ll, ld):
        views = make_views(make_layout("fibonacci", 12), 24, np.random.default_rng(13), noise=0.02)
        cfg = FusionConfig(w_grad=10.0**lg, w_lap=10.0**ll, w_data=10.0**ld, maxiter=100)
        r = fuse_views(views, 16, 32, cfg)
        assert np.isfinite(r.distance[r.seen]).all() and r.seen.all()
        assert all(isinstance(i, int) for i in r.report["iterations"]) and math.isfinite(r.report["residual"])
        # every term is consistent with the truth up to each view's scale, so whatever their balance the map is
        # the truth plus filtered teacher noise: within 2.5x one view's mean error, 0.02 sqrt(2 / pi) = 0.016
        # (the 3^3 corner grid of these weights measured 0.014 to 0.030 here)
        assert depth_metrics(r.distance, box_distance(erp_directions(16, 32)))["abs_rel"] < 2.5 * 0.02 * math.sqrt(
            2 / math.pi
        )

    @pytest.mark.parametrize(
        "field,value",
        [
            ("w_data", 0.0),
            ("w_lap", -1.0),
            ("w_grad", float("nan")),
            ("preconditioner", "ilu"),
            ("border_px", -1),
            ("border_px", 2.5),
            ("border_anchor", 0.0),
            ("border_smooth", float("inf")),
            ("border_laplacian", -1.0),
            ("sampling", "cubic"),
            ("supersample", 0),
            ("edge_log", 0.0),
        ],
    )
    def test_bad_config_is_one_clear_error(self, field, value, fib20):
        with pytest.raises(ValueError, match=field):
            fuse_views(make_views(fib20, 16, np.random.default_rng(0)), 8, 16, FusionConfig(**{field: value}))

    def test_bad_sizes(self, fib20):
        views = make_views(fib20, 16, np.random.default_rng(0))
        with pytest.raises(ValueError, match="width = 2 x height"):
            fuse_views(views, 10, 30)
        with pytest.raises(ValueError, match="no views"):
            fuse_views([], 8, 16)


def _open_box(d):
    """The box room without a ceiling: sky (infinite) above 0.1 of elevation."""
    return np.where(d[..., 2] > 0.1, np.inf, box_distance(d))


def _flying_pixel_views(layout, size, rng, width_px=3, factor=20.0):
    """Open-box views whose depth within ``width_px`` of the sky is ``factor`` times too far, as a teacher that
    blends the wall with the sky behind it."""
    views = make_views(layout, size, rng, field=_open_box)
    for v in views:
        sky = ~v.valid
        if sky.any():
            import cv2

            near = cv2.distanceTransform((~sky).astype(np.uint8), cv2.DIST_L2, 5) <= width_px
            v.depth[near & v.valid] *= factor
    return views


class TestSkyBorder:
    def test_region_border_ignores_isolated_drops_and_follows_large_regions(self):
        from panorecon.fusion.warp import region_border

        valid = np.ones((40, 60), bool)
        valid[5, 7] = valid[20, 30] = valid[33, 50] = False  # dropped pixels
        assert not region_border(valid, 4).any()
        valid[:10, :] = False  # a sky band across the top
        border = region_border(valid, 4)
        rows = np.flatnonzero(border.any(1))
        assert rows.min() == 10 and rows.max() == 13  # within 4 px of the sky, valid pixels only
        assert not (border & ~valid).any() and not region_border(valid, 0).any()

    def test_flying_pixels_at_the_sky_border_are_filled_from_the_wall(self, fib20):
        views = _flying_pixel_views(fib20, 96, np.random.default_rng(15))
        truth = _open_box(erp_directions(48, 96))
        used = fuse_views(views, 48, 96, FusionConfig(border_px=0))
        filled = fuse_views(views, 48, 96, FusionConfig(border_px=4))
        np.testing.assert_array_equal(used.seen, filled.seen)  # the border is filled, not dropped
        assert np.isfinite(filled.distance[filled.seen]).all()
        e_used = depth_metrics(used.distance, truth)["abs_rel"]
        e_filled = depth_metrics(filled.distance, truth)["abs_rel"]
        assert e_filled < 0.3 * e_used and e_filled < 0.05, (e_used, e_filled)

    def test_a_region_reached_only_by_border_pixels_keeps_the_teacher_value(self, fib20):
        """A thin strip between sky above and below, all of it within 8 px of the sky in every view: nothing
        reliable to fill it from, so its border observations are used as ordinary ones."""
        from panorecon.fusion.warp import region_border

        def strip(d):
            return np.where(np.abs(d[..., 2]) < 0.04, box_distance(d), np.inf)

        views = make_views(fib20, 64, np.random.default_rng(16), field=strip)
        assert all((region_border(v.valid, 8) == v.valid).all() for v in views)
        truth = strip(erp_directions(64, 128))
        plain = fuse_views(views, 64, 128, FusionConfig(border_px=0))
        r = fuse_views(views, 64, 128, FusionConfig(border_px=8))
        assert r.seen.sum() > 100 and np.isfinite(r.distance[r.seen]).all()
        np.testing.assert_allclose(r.distance[r.seen], plain.distance[plain.seen], rtol=1e-5)
        assert depth_metrics(r.distance, truth)["abs_rel"] < 0.01

    @settings(max_examples=8, deadline=None)
    @given(st.floats(-6, 6), st.floats(-6, 6), st.integers(0, 8))
    def test_any_border_weights(self, la, lm, px):
        views = _flying_pixel_views(make_layout("fibonacci", 12), 32, np.random.default_rng(17))
        r = fuse_views(
            views, 16, 32, FusionConfig(border_px=px, border_anchor=10.0**la, border_smooth=10.0**lm, maxiter=100)
        )
        assert r.seen.any() and np.isfinite(r.distance[r.seen]).all() and math.isfinite(r.report["residual"])
        if px == 0:  # no border pixel: the border weights must not touch the solve
            plain = fuse_views(views, 16, 32, FusionConfig(border_px=0, maxiter=100))
            np.testing.assert_array_equal(r.distance, plain.distance)


def test_jacobi_and_amg_agree(fib20):
    views = make_views(fib20, 64, np.random.default_rng(14), noise=0.02)
    a = fuse_views(views, 64, 128, FusionConfig(preconditioner="amg", tol=1e-8, coarse_tol=1e-8, maxiter=2000))
    b = fuse_views(views, 64, 128, FusionConfig(preconditioner="jacobi", tol=1e-8, coarse_tol=1e-8, maxiter=2000))
    np.testing.assert_allclose(a.distance, b.distance, rtol=1e-4)


def test_stacked_operator_matches_its_parts():
    import scipy.sparse as sp

    from panorecon.fusion.operators import (
        difference_matrix,
        horizontal_pairs,
        laplacian_matrix,
        stacked_operator,
        vertical_pairs,
    )

    H, W = 5, 10
    B, rows = stacked_operator(H, W)
    ref = sp.vstack(
        [
            difference_matrix(*horizontal_pairs(H, W), H * W),
            difference_matrix(*vertical_pairs(H, W), H * W),
            laplacian_matrix(H, W),
            sp.identity(H * W),
        ]
    )
    assert abs(B - ref).max() == 0
    np.testing.assert_array_equal(rows, np.repeat(np.arange(B.shape[0]), np.diff(B.indptr)))


def _torch_vs_scipy(fib20, device):
    views = make_views(fib20, 64, np.random.default_rng(15), noise=0.02)
    ref = fuse_views(views, 128, 256, FusionConfig(levels=2, cg_precision="double"))
    got = fuse_views(views, 128, 256, FusionConfig(levels=2, cg_device=device))
    assert not ref.report["levels"][1]["direct"] and ref.report["levels"][1]["iterations"] > 5
    assert "torch" in got.report["solver"]
    for a, b in zip(ref.report["levels"], got.report["levels"]):
        assert abs(a["iterations"] - b["iterations"]) <= 1
        assert b["residual"] <= 1.01 * a["residual"] + 1e-12
    np.testing.assert_allclose(got.distance, ref.distance, rtol=1e-5)
    np.testing.assert_allclose(got.view_scale, ref.view_scale, rtol=1e-5)


def test_torch_cg_equals_the_scipy_cg(fib20):
    """The Jacobi-PCG in torch float64 (on the CPU here) against SciPy's: same iterations, same solution."""
    _torch_vs_scipy(fib20, "cpu")


@pytest.mark.cuda
def test_torch_cg_on_cuda_equals_the_scipy_cg(fib20):
    import torch

    if not torch.cuda.is_available():
        pytest.skip("needs CUDA")
    _torch_vs_scipy(fib20, "cuda")


@pytest.mark.parametrize("tol", [1e-3, 1e-9])
def test_mixed_precision_cg_meets_the_float64_tolerance(fib20, tol):
    """float32 products with a float64 check: the float64 relative residual ends at or below ``tol`` on every level,
    also where float32 alone cannot get there (1e-9 is far below float32's resolution: refinement rounds do it), and the
    solution is the float64 CG's to within what ``tol`` allows."""
    views = make_views(fib20, 64, np.random.default_rng(15), noise=0.02)
    cfg = dict(levels=2, tol=tol, coarse_tol=tol)
    ref = fuse_views(views, 128, 256, FusionConfig(cg_precision="double", **cfg))
    got = fuse_views(views, 128, 256, FusionConfig(**cfg))
    assert "float32" in got.report["solver"] and "float32" not in ref.report["solver"]
    assert not got.report["levels"][1]["direct"]
    for lv in got.report["levels"]:
        assert lv["residual"] <= tol
    np.testing.assert_allclose(got.distance, ref.distance, rtol=max(100 * tol, 1e-6))  # float32 output


def test_data_warm_start_solves_the_same_system_in_fewer_iterations(fib20, box_truth):
    """Starting each level's CG from the observations' mean (the default) rather than the upsampled coarser
    solution: the same float64 tolerance on every level, the same answer to within it, fewer iterations."""
    views = make_views(fib20, 128, np.random.default_rng(8), noise=0.02)
    got = fuse_views(views, 128, 256, FusionConfig(levels=3))
    ref = fuse_views(views, 128, 256, FusionConfig(levels=3, warm_start="coarse"))
    for a, b in zip(got.report["levels"][1:], ref.report["levels"][1:]):
        assert a["residual"] <= 1e-3 and b["residual"] <= 1e-3
    assert sum(got.report["iterations"][1:]) < 0.5 * sum(ref.report["iterations"][1:]), (got.report, ref.report)
    np.testing.assert_allclose(got.distance, ref.distance, rtol=0.01)
    err = [depth_metrics(r.distance, box_truth(128))["abs_rel"] for r in (got, ref)]
    assert err[0] <= 1.05 * err[1], err
    with pytest.raises(ValueError, match="warm_start"):
        FusionConfig(warm_start="zero").check()


def test_torch_cg_refuses_amg():
    with pytest.raises(ValueError, match="Jacobi"):
        FusionConfig(cg_device="cpu", preconditioner="amg").check()
    with pytest.raises(ValueError, match="cg_precision"):
        FusionConfig(cg_precision="half").check()


class TestWarp:
    """The vectorised warp against per-point loops written from the definitions."""

    @staticmethod
    def bilinear_reference(img, x, y, edge):
        h, w = img.shape
        if not (-0.5 <= x < w - 0.5 and -0.5 <= y < h - 0.5):
            return np.nan
        x0, y0 = math.floor(x), math.floor(y)
        fx, fy = x - x0, y - y0
        taps = {
            (i, j): (img[i, j] if 0 <= i < h and 0 <= j < w else np.nan) for i in (y0, y0 + 1) for j in (x0, x0 + 1)
        }
        near = taps[(y0 + (fy >= 0.5), x0 + (fx >= 0.5))]
        num = den = 0.0
        for (i, j), v in taps.items():
            wt = (fx if j > x0 else 1 - fx) * (fy if i > y0 else 1 - fy)
            if np.isfinite(v) and np.isfinite(near) and abs(v - near) <= edge:
                num, den = num + wt * v, den + wt
        return num / den if den > 0 else np.nan

    def test_edge_aware_bilinear_matches_its_reference(self):
        from panorecon.fusion.warp import sample_log_linear

        rng = np.random.default_rng(0)
        img = np.log(rng.uniform(1, 1.3, (7, 9)))
        img[2:4, 3:6] += 1.0  # a depth edge
        img[5, 1] = img[0, 8] = np.nan
        x, y = rng.uniform(-1, 9.5, 400), rng.uniform(-1, 7.5, 400)
        x[:3], y[:3] = [-0.5, 8.49, 3.0], [-0.5, 6.49, 2.5]  # the first and last pixel-centre extents, a tap exactly
        got = sample_log_linear(img, x, y, 0.3)
        ref = np.array([self.bilinear_reference(img, a, b, 0.3) for a, b in zip(x, y)])
        np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
        np.testing.assert_allclose(got[~np.isnan(got)], ref[~np.isnan(ref)], rtol=0, atol=1e-12)

    @pytest.mark.parametrize("k", [1, 2, 3])
    def test_footprint_average_matches_a_per_pixel_loop(self, k):
        from panorecon.fusion.warp import warp_to_erp

        cam = centred_camera(np.array([0.6, -0.5, 0.4]), 24, 80.0)
        rng = np.random.default_rng(k)
        dist = np.exp(rng.normal(0.5, 0.05, (24, 24))).astype(np.float32)
        dist[10:, 15:] *= 3.0  # an edge the bilinear reads must not blend
        view = ViewDepth(cam, dist, "distance", np.ones(dist.shape, bool))
        H, W = 12, 24
        obs = warp_to_erp(view, H, W, sampling="linear", supersample=k, edge_log=0.2)
        fine = erp_directions(H * k, W * k)
        logd = np.log(dist.astype(np.float64))
        near = warp_to_erp(view, H, W)
        centre = dict(zip(near.index, near.log_distance))
        for p, value in zip(obs.index, obs.log_distance):
            r, c = divmod(int(p), W)
            reads = []
            for rays in fine[r * k : (r + 1) * k, c * k : (c + 1) * k].reshape(-1, 3):
                loc = rays @ cam.rotation_c2w
                if loc[2] > 1e-6:
                    x = cam.K[0, 0] * loc[0] / loc[2] + cam.K[0, 2] - 0.5
                    y = cam.K[1, 1] * loc[1] / loc[2] + cam.K[1, 2] - 0.5
                    read = self.bilinear_reference(logd, x, y, 0.2)
                    if abs(read - centre[p]) <= 0.2:
                        reads.append(read)
            assert np.isclose(value, np.mean(reads), rtol=0, atol=1e-9), (p, value, reads)
        assert set(obs.index) <= set(near.index) and len(obs.index) >= len(near.index) - 2

    def test_linear_warp_does_not_blend_across_a_depth_edge(self):
        from panorecon.fusion.warp import warp_to_erp

        cam = centred_camera(np.array([1.0, 0.0, 0.0]), 64, 90.0)
        dist = np.where(np.arange(64)[None, :] < 31, 1.0, 4.0) * np.ones((64, 64))
        obs = warp_to_erp(
            ViewDepth(cam, dist.astype(np.float32), "distance", np.ones((64, 64), bool)),
            64,
            128,
            sampling="linear",
            supersample=3,
        )
        d = np.exp(obs.log_distance)
        assert np.minimum(np.abs(d - 1), np.abs(d - 4)).max() < 1e-9


def test_cached_erp_rays_are_erp_directions():
    from panorecon.fusion.lsq import _erp_rays

    np.testing.assert_allclose(_erp_rays(6), erp_directions(6, 12).reshape(-1, 3), rtol=0, atol=1e-15)
    assert not _erp_rays(6).flags.writeable


class TestDepthEdges:
    """Flying points (more than 50 % off the truth after the median scale, ``metrics.depth.FLYING_REL``) of the
    Fibonacci fusion with a near-perfect teacher on the stress scenes (``scenes/stress.py``): at most 0.05 %."""

    MOST = 5e-4

    @staticmethod
    def flying(case: str, width: int = 256, view_size: int | None = None, **fusion):
        from panorecon.scenes.stress import CASES
        from panorecon.sources import run_source

        cfg = FusionConfig(**fusion) if fusion else None
        _, rep = run_source(CASES[case](width), "fibonacci", "sim:clean", fusion_config=cfg, view_size=view_size)
        return rep

    def held(self, case: str, **kw):
        rep = self.flying(case, **kw)
        assert rep["depth"]["flying"] <= self.MOST and rep["points"]["flying"] <= self.MOST, (case, rep["depth"])
        assert rep["depth"]["abs_rel"] < 0.005
        assert rep["depth"]["pixels"] >= 0.93 * rep["erp"][0] * rep["erp"][1]  # the edge pixels dropped, no more

    def test_cliff_ratio_10_leaves_no_flying_points(self):
        self.held("cliff-10")

    def test_cliff_ratio_1e2_leaves_no_flying_points(self):
        self.held("cliff-1e2")

    def test_cliff_ratio_1e3_leaves_no_flying_points(self):
        self.held("cliff-1e3")

    def test_cliff_ratio_1e4_leaves_no_flying_points(self):
        self.held("cliff-1e4")

    def test_cliff_ratio_1e4_through_the_guided_upsampling_leaves_no_flying_points(self):
        """128 px views resolve 256 rows of a 512-row panorama: the solve's edges reach full size by
        ``upsample.guided_upsample``, which keeps to one side of them."""
        rep = self.flying("cliff-1e4", width=1024, view_size=128)
        assert "upsample" in rep["fusion"]
        assert rep["depth"]["flying"] <= self.MOST and rep["depth"]["abs_rel"] < 0.01

    def test_ramp_4_decades_over_6_degrees_leaves_no_flying_points(self):
        self.held("ramp-4")

    def test_ramp_6_decades_over_10_degrees_leaves_no_flying_points(self):
        self.held("ramp-6")

    def test_horizon_4_decades_leaves_no_flying_points(self):
        self.held("horizon-4")

    def test_seam_jump_leaves_no_flying_points(self):
        self.held("seam-jump")

    @pytest.mark.parametrize("case", ["seam-jump", "cliff-10"])
    def test_a_blurring_teacher_leaves_no_flying_points(self, case):
        """``sim:relative`` blurs each view's depth by 1.5 px, spreading a jump over several view pixels: the flank
        steps of more than half ``edge_jump`` within ``FusionConfig.edge_reach`` pixels of an edge are cut with it
        (the default). Without them (``edge_reach=0``, 512 px) the seam jump flew 0.47 % near the poles, where it
        meets the slope's every distance."""
        from panorecon.fusion import FusionConfig
        from panorecon.scenes.stress import CASES
        from panorecon.sources import run_source

        assert FusionConfig().edge_reach == 3
        _, rep = run_source(CASES[case](512), "fibonacci", "sim:relative")
        assert rep["depth"]["flying"] <= self.MOST and rep["points"]["flying"] <= self.MOST, rep["depth"]
        assert rep["depth"]["pixels"] >= 0.9 * 512 * 256

    def test_a_blurring_teacher_keeps_a_ground_plane_to_the_horizon(self):
        """A ground plane seen to the horizon is no blurred jump: its steps grow to the far end with nothing flat
        beyond, so ``edge_reach`` cuts no more of it than the ``edge_jump`` test alone (a reach without the
        two-sided test cut a beach's far ground: pseudo-label PSNR -1.37 dB on the quick suite)."""
        from panorecon.fusion import FusionConfig
        from panorecon.scenes.stress import CASES
        from panorecon.sources import run_source

        scene = CASES["horizon-4"](512)
        kept = {
            r: run_source(scene, "fibonacci", "sim:relative", fusion_config=FusionConfig(edge_reach=r))[1]["depth"]
            for r in (0, 3)
        }
        assert kept[3]["pixels"] >= kept[0]["pixels"] - 64, (kept[0]["pixels"], kept[3]["pixels"])
        assert kept[3]["flying"] <= self.MOST

    def test_cliff_ratio_1e4_throws_flying_points_without_the_edge_handling(self):
        """What the edge handling removes: blends and wrong-side pixels at the cliff (the measure sees them)."""
        rep = self.flying("cliff-1e4", edge_jump=None)
        assert rep["depth"]["flying"] > 20 * self.MOST and rep["depth"]["abs_rel"] > 1


def test_depth_edge_pixels_flag_both_sides_of_a_step_and_nothing_else():
    from panorecon.fusion.warp import depth_edge_pixels

    jump = math.log(1.5)
    x = np.arange(20.0)[None].repeat(10, 0)
    step = np.where(x < 8, 0.0, 1.0)
    flags = depth_edge_pixels(step, jump)
    assert flags[:, 7:9].all() and not flags[:, :7].any() and not flags[:, 9:].any()
    assert not depth_edge_pixels(0.3 * x, jump).any()  # a slope below jump per pixel: no edge, border included
    assert depth_edge_pixels(0.5 * x, jump).all()  # steeper than the view resolves
    holes = step.copy()
    holes[:, 8] = np.nan  # an invalid pixel is no neighbour: the step now lies between columns 7 and 9
    flags = depth_edge_pixels(holes, jump)
    assert not flags[:, 8].any() and not flags.any()  # 7 and 9 are not 8-neighbours
    assert depth_edge_pixels(step, jump, px=2)[:, 6:10].all()  # dilated


def test_depth_edge_pixels_reach_takes_a_blurred_jumps_flanks_and_leaves_grazing_slopes_alone():
    """A jump a teacher's blur spread over five pixels (steps 0.1, 0.3, 0.5, 0.3, 0.1: only the middle one above
    ln 1.5), flat on both sides: with ``reach`` its steps above half the jump are part of the edge. A grazing
    slope whose steps grow to its far end (log distance -ln(t), as a ground plane towards the horizon, then
    nothing valid) keeps the ``jump`` test with ``reach``, as does a steep slope meeting an edge with nothing flat
    on one side."""
    from panorecon.fusion.warp import depth_edge_pixels

    jump = math.log(1.5)
    blurred = np.cumsum([0.0] * 8 + [0.1, 0.3, 0.5, 0.3, 0.1] + [0.0] * 7)[None].repeat(6, 0)
    assert np.array_equal(np.flatnonzero(depth_edge_pixels(blurred, jump)[0]), [9, 10])
    assert np.array_equal(np.flatnonzero(depth_edge_pixels(blurred, jump, reach=3)[0]), [8, 9, 10, 11])
    assert np.array_equal(np.flatnonzero(depth_edge_pixels(blurred, jump, reach=1)[0]), [9, 10])  # no flat side
    grazing = np.full((6, 24), np.nan)
    grazing[:, :20] = -np.log(np.arange(20.0, 0.0, -1.0))  # steps ln(t / (t - 1)): rising to ln 2 at the end
    assert np.array_equal(depth_edge_pixels(grazing, jump, reach=3), depth_edge_pixels(grazing, jump))
    assert depth_edge_pixels(grazing, jump)[0, 18:20].all()
    slope = 0.3 * np.arange(20.0)[None].repeat(6, 0)
    assert not depth_edge_pixels(slope, jump, reach=3).any()
    slope[:, 15:] += 1.0  # an edge between columns 14 and 15, no flat pixel anywhere: the slope is kept
    assert np.array_equal(np.flatnonzero(depth_edge_pixels(slope, jump, reach=3)[0]), [14, 15])


@settings(max_examples=40, deadline=None)
@given(st.floats(-0.4, 0.4), st.floats(-0.4, 0.4), st.floats(-50, 50), st.floats(0.85, 12), st.integers(1, 18))
def test_depth_edge_pixels_property_gentle_planes_pass_steps_are_flagged(a, b, c, size, col):
    """Property: a log-linear depth whose 8-neighbours differ by at most ln 1.5 has no edge pixel at any offset;
    adding a step that leaves more than ln 1.5 between two columns flags both columns' pixels."""
    from panorecon.fusion.warp import depth_edge_pixels

    jump = math.log(1.5)
    r, k = np.mgrid[0:12, 0:20].astype(float)
    plane = 0.5 * (a * k + b * r) + c  # at most 0.4 between diagonal neighbours
    assert not depth_edge_pixels(plane, jump).any()
    flags = depth_edge_pixels(plane + np.where(k >= col, size, 0.0), jump)
    assert flags[:, col - 1].all() and flags[:, col].all()


@settings(max_examples=8, deadline=None)
@given(st.floats(-4, 6), st.integers(0, 2**31 - 1))
def test_fusion_output_scales_linearly_with_the_depth_scale(log_s, seed):
    """Scale-freeness of the fusion: every view's depth times s gives the fused distance times s (the solve is
    in log distance, its edges in log ratios), the same pixels seen."""
    s = 10.0**log_s
    views = make_views(make_layout("fibonacci", 20), 32, np.random.default_rng(seed), noise=0.01)
    scaled = [ViewDepth(v.camera, (v.depth.astype(np.float64) * s).astype(np.float32), v.kind, v.valid) for v in views]
    a = fuse_views(views, 32, 64, FusionConfig(tol=1e-9))
    b = fuse_views(scaled, 32, 64, FusionConfig(tol=1e-9))
    assert np.array_equal(a.seen, b.seen) and a.seen.mean() > 0.9
    np.testing.assert_allclose(b.distance[a.seen], s * a.distance[a.seen].astype(np.float64), rtol=1e-4)


@settings(max_examples=15, deadline=None)
@given(st.floats(-4, 6), st.floats(0, 5), st.integers(0, 2**31 - 1))
def test_fusion_is_finite_on_random_extreme_depths(log_centre, decades, seed):
    """Property: per-pixel random depths spanning ``decades`` decades around 10^log_centre (every pixel an edge
    at the top of the range) give a finite positive distance wherever a pixel is seen."""
    rng = np.random.default_rng(seed)
    layout = make_layout("fibonacci", 12)
    views = []
    for f in layout.directions:
        cam = centred_camera(f, 24, layout.fov_deg)
        z = 10.0 ** (log_centre + decades * rng.uniform(-0.5, 0.5, (24, 24)))
        views.append(ViewDepth(cam, z.astype(np.float32), "z", np.ones((24, 24), bool)))
    r = fuse_views(views, 16, 32)
    assert np.isfinite(r.distance[r.seen]).all() and (r.distance[r.seen] > 0).all()
    assert np.isnan(r.distance[~r.seen]).all()


def _noisy_disparity_views(layout, noise: float, offset: float, size: int = 96, seed: int = 21):
    """Disparity views of the box room: raw = (alpha_i / z + c_i alpha_i)(1 + noise N(0, 1)) - offset, c_i of
    mean zero -> (views, alphas)."""
    rng = np.random.default_rng(seed)
    alphas = rng.uniform(0.5, 2, len(layout.directions))
    c = rng.uniform(-0.05, 0.05, len(alphas))
    c -= c.mean()
    views = []
    for f, ci, alpha in zip(layout.directions, c, alphas):
        cam = centred_camera(f, size, layout.fov_deg)
        z = box_distance(cam.world_rays()) / cam.z_to_distance_factor()
        raw = (alpha / z + ci * alpha) * (1 + noise * rng.standard_normal(z.shape)) - offset
        views.append(ViewDepth(cam, raw.astype(np.float32), "disparity", np.ones(raw.shape, bool), affine=True))
    return views, alphas


def _random_overlap_equations(rng, noise: float, views: int = 5, pairs: int = 7, rows: int = 60):
    """Rows g_i (a_i r_i + b_i) - g_j (a_j r_j + b_j) = 0 of random overlaps: t in [0.2, 1], g in [0.7, 1], true
    a in [0.5, 2] and b in [-1, 1], raw values with relative noise -> (M [pairs * rows, 2 views], reference view)."""
    a, b = rng.uniform(0.5, 2, views), rng.uniform(-1, 1, views)
    links = [(i, i + 1) for i in range(views - 1)]
    links += [tuple(sorted(rng.choice(views, 2, replace=False))) for _ in range(pairs - len(links))]
    blocks = []
    for i, j in links:
        t = rng.uniform(0.2, 1.0, rows)
        gi, gj = rng.uniform(0.7, 1.0, rows), rng.uniform(0.7, 1.0, rows)
        ri = (t / gi - b[i]) / a[i] * (1 + noise * rng.standard_normal(rows))
        rj = (t / gj - b[j]) / a[j] * (1 + noise * rng.standard_normal(rows))
        row = np.zeros((rows, 2 * views))
        row[:, 2 * i], row[:, 2 * i + 1] = gi * ri, gi
        row[:, 2 * j], row[:, 2 * j + 1] = -gj * rj, -gj
        blocks.append(row)
    return np.concatenate(blocks), int(rng.integers(views))
