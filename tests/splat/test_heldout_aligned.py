"""Held-out views of another panorama captured at another exposure and white balance: the aligned score
recovers the score against an unchanged capture, the raw one does not; the reprojection oracle is the training
panorama's colour at the true 3D points. Fixture: one synthetic room (bedroom) rendered from two positions and
written as two Stanford2D3D panoramas, the second once as rendered and once with a per-channel gain and offset."""

import json

import cv2
import numpy as np
import pytest

from panorecon.geometry import erp_directions, sample_erp
from panorecon.io import write_image
from panorecon.metrics.aligned import apply_color_affine, fit_color_affine, masked_psnr
from panorecon.scenes import load_scene
from panorecon.scenes.datasets import heldout_panoramas
from panorecon.splat.evaluate import _aligned_scores
from panorecon.splat.labels import make_panorama_heldout_views

OFFSET = np.array([0.5, 0.3, 0.0])  # metres: the second panorama's centre
GAIN = np.array([0.7, 0.85, 0.6])  # the second capture's exposure and white balance: rgb -> GAIN rgb + BIAS
BIAS = np.array([0.12, 0.05, 0.10])  # (at most 0.82 for white: nothing clips)
RES, VIEWS, SEED = 64, 4, 1


def _write_space(root, world, change: bool):
    origin = np.array([4.0, -2.0, 1.0])
    for i, off in enumerate((np.zeros(3), OFFSET)):
        r = world.render_erp(128, off)
        rgb = r.rgb
        if change and i == 1:
            rgb = np.round((GAIN * (rgb / 255.0) + BIAS) * 255).astype(np.uint8)
        xyz = origin + off + r.distance[..., None] * erp_directions(128, 256)
        base, pano = root / "area_1" / "pano", f"camera_{i:032x}_room_1_{i}_frame_equirectangular_domain"
        write_image(base / "rgb" / f"{pano}_rgb.png", rgb)
        (base / "depth").mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(base / "depth" / f"{pano}_depth.png"), np.round(r.distance * 512).astype(np.uint16))
        (base / "pose").mkdir(parents=True, exist_ok=True)
        (base / "pose" / f"{pano}_pose.json").write_text(json.dumps({"camera_location": (origin + off).tolist()}))
        from ..scenes.conftest import write_exr_xyz

        write_exr_xyz(base / "global_xyz" / f"{pano}_global_xyz.exr", xyz)
    return load_scene(f"stanford2d3d:{root}/area_1/camera_{0:032x}_room_1_0")


@pytest.fixture(scope="module")
def spaces(tmp_path_factory):
    """(world, the held-out views of the unchanged space, those of the changed one, the training ERP rgb):
    the same cameras and masks (same seed and depth), the second panorama's colours changed or not."""
    world = load_scene("bedroom", 256).world
    same = _write_space(tmp_path_factory.mktemp("same"), world, False)
    changed = _write_space(tmp_path_factory.mktemp("changed"), world, True)
    views = [make_panorama_heldout_views(s, heldout_panoramas(s), VIEWS, RES, 60.0, SEED) for s in (same, changed)]
    return world, views[0], views[1], same.rgb


def _reconstruction(world, view):
    """A stand-in for trained Gaussians: the true view of the unchanged world, blurred (float32 in [0, 1])."""
    return cv2.GaussianBlur(world.render_view(view.camera).rgb.astype(np.float32) / 255.0, (5, 5), 1.0)


def _scores(world, views):
    kept = [(v, _reconstruction(world, v)) for v in views]
    return _aligned_scores(kept, "n/a: LPIPS left out of this test", None), kept


def _carried(img, v):
    """PSNR (dB) of ``img`` aligned onto the UNCHANGED view ``v``, its error carried into the changed capture's
    contrast (x GAIN per channel): what the aligned score of the changed capture must read, since the affine
    fit onto GAIN x + BIAS is GAIN x (the fit onto x) + BIAS."""
    m = v.mask
    aligned = apply_color_affine(img, fit_color_affine(img[m], v.rgb[m]))
    return -10 * np.log10(np.mean((GAIN * (aligned[m] - v.rgb[m])) ** 2))


def test_fixture_is_the_same_views_with_the_colour_change(spaces):
    _, same, changed, _ = spaces
    for a, b in zip(same, changed):
        np.testing.assert_array_equal(a.mask, b.mask)
        assert a.mask.sum() > 1000
        np.testing.assert_allclose(b.rgb[a.mask], GAIN * a.rgb[a.mask] + BIAS, atol=1.5 / 255)


def test_aligned_score_recovers_the_unchanged_score_raw_does_not(spaces):
    world, same, changed, _ = spaces
    s_same, kept_same = _scores(world, same)
    s_changed, kept_changed = _scores(world, changed)
    raw_same = np.mean([masked_psnr(img, v.rgb, v.mask) for v, img in kept_same])
    raw_changed = np.mean([masked_psnr(img, v.rgb, v.mask) for v, img in kept_changed])
    expected = np.mean([_carried(img, v) for v, img in kept_same])
    assert raw_changed < raw_same - 5  # the exposure change alone costs the raw score over 5 dB
    # tolerance 0.3 dB: the changed panorama is stored in 8 bits (a rounding error of 0.5/255 at most)
    assert abs(s_changed["aligned_psnr"] - expected) < 0.3
    assert s_changed["aligned_psnr_views"] == VIEWS
    # on the unchanged capture the alignment changes little: the reconstruction's own error remains
    assert raw_same <= s_same["aligned_psnr"] < raw_same + 1
    assert abs(s_changed["aligned_ssim"] - s_same["aligned_ssim"]) < 0.02
    assert s_changed["aligned_lpips"] == "n/a: LPIPS left out of this test"


def test_oracle_is_the_training_panoramas_colour_at_the_true_points(spaces):
    world, same, changed, train_rgb = spaces
    for v in same:
        m = v.mask
        truth = world.render_view(v.camera)
        x = OFFSET + v.camera.world_rays()[m] * truth.distance[m][:, None]  # the true 3D points
        expected = sample_erp(train_rgb, (x / np.linalg.norm(x, axis=1, keepdims=True))[None], "linear")[0] / 255.0
        assert np.isnan(v.oracle[~m]).all()
        assert np.median(np.abs(v.oracle[m] - expected)) < 1.5 / 255
        assert masked_psnr(v.oracle, v.rgb, m) == pytest.approx(
            -10 * np.log10(np.mean((expected - v.rgb[m]) ** 2)), abs=0.5
        )
    s_same, _ = _scores(world, same)
    s_changed, _ = _scores(world, changed)
    # the unchanged capture's oracle: the same surface seen from two places, up to resampling
    assert s_same["oracle_psnr"] > 30 and s_same["oracle_psnr"] <= s_same["oracle_aligned_psnr"]
    # the changed one's: raw, it carries the exposure change; aligned, the unchanged value in the changed contrast
    assert s_changed["oracle_psnr"] < s_same["oracle_psnr"] - 5
    expected = np.mean([_carried(v.oracle, v) for v in same])
    assert abs(s_changed["oracle_aligned_psnr"] - expected) < 0.3


def test_refused_alignment_reads_na_with_its_reason(spaces):
    world, same, _, _ = spaces
    flat = [(v, np.full((RES, RES, 3), 0.5, np.float32)) for v in same]  # a render of one flat colour
    s = _aligned_scores(flat, "n/a: LPIPS left out of this test", None)
    assert "rank-deficient" in s["aligned_psnr"] and s["aligned_psnr_views"] == 0
    assert s["aligned_ssim"] == s["aligned_psnr"] and isinstance(s["oracle_psnr"], float)


def _line(name: str, h: dict) -> str:
    return (
        f"{name}: raw {h['psnr']:.2f} dB, aligned {h['aligned_psnr']:.2f} dB (SSIM {h['aligned_ssim']:.3f}), "
        f"oracle {h['oracle_psnr']:.2f} dB, oracle aligned {h['oracle_aligned_psnr']:.2f} dB"
    )


def main(iters: int = 300) -> None:
    """The fixture's held-out numbers (raw, colour-aligned, oracle) on the unchanged and the changed second
    panorama: first for the blurred true views (``_reconstruction``, no training), then for Gaussians trained
    ``iters`` steps on the first panorama (its true cloud as the initialisation).
    ``python -m tests.splat.test_heldout_aligned`` from the repository root."""
    import tempfile
    from pathlib import Path

    from panorecon.splat.trainer import TrainConfig, train

    world = load_scene("bedroom", 256).world
    with tempfile.TemporaryDirectory() as tmp:
        scenes = {n: _write_space(Path(tmp) / n, world, c) for n, c in (("unchanged", False), ("changed", True))}
        for name, scene in scenes.items():
            views = make_panorama_heldout_views(scene, heldout_panoramas(scene), VIEWS, RES, 60.0, SEED)
            s, kept = _scores(world, views)
            raw = float(np.mean([masked_psnr(img, v.rgb, v.mask) for v, img in kept]))
            print(_line(f"blurred true views, {name}", {**s, "psnr": raw}), flush=True)
        for name, scene in scenes.items():
            cfg = TrainConfig(iters=iters, labels=60, res=RES, heldout=VIEWS, seed=SEED, history_every=0)
            h = train(scene, scene.point_cloud(), cfg, Path(tmp) / f"run_{name}", progress=False)["held-out"]
            print(_line(f"Gaussians after {iters} steps, {name}", h), f"({h['views']} views)", flush=True)


if __name__ == "__main__":
    main()
