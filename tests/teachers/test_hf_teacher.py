"""``hf:`` teacher: the output-kind table, local-only loading and its one-line errors, the processor round trip
(a known depth at the processor's resolution comes back exactly at the view's pixels, square and non-square,
batched equal to unbatched) and tiny random-weight Depth Anything (relative, metric) and DPT models built from
their configs, end to end through ``points`` and ``train``."""

import json
import os
import types

import numpy as np
import pytest
import torch

transformers = pytest.importorskip("transformers")
from transformers import (  # noqa: E402 (after the importorskip)
    AutoModelForDepthEstimation,
    DepthAnythingConfig,
    DepthProConfig,
    Dinov2Config,  # noqa: E402
    DPTConfig,
    DPTImageProcessor,
    ZoeDepthConfig,
)
from transformers.modeling_outputs import DepthEstimatorOutput  # noqa: E402

from panorecon.cli import main  # noqa: E402
from panorecon.geometry import centred_camera  # noqa: E402
from panorecon.io import PanoreconInputError  # noqa: E402
from panorecon.scenes import load_scene  # noqa: E402
from panorecon.teachers import get_teacher, list_teachers  # noqa: E402
from panorecon.teachers.base import sky_of_view  # noqa: E402
from panorecon.teachers.hf_teacher import OUTPUT_KINDS, output_kind  # noqa: E402


def _dinov2():
    return Dinov2Config(
        hidden_size=16,
        num_hidden_layers=4,
        num_attention_heads=2,
        intermediate_size=32,
        patch_size=14,
        image_size=56,
        out_features=["stage1", "stage2", "stage3", "stage4"],
        reshape_hidden_states=False,
    )


def _depth_anything(kind: str):
    return DepthAnythingConfig(
        backbone_config=_dinov2(),
        reassemble_hidden_size=16,
        patch_size=14,
        neck_hidden_sizes=[8, 8, 8, 8],
        fusion_hidden_size=8,
        head_hidden_size=8,
        depth_estimation_type=kind,
        max_depth=10,
    )


def _dpt():
    return DPTConfig(
        hidden_size=16,
        num_hidden_layers=4,
        num_attention_heads=2,
        intermediate_size=32,
        image_size=64,
        patch_size=16,
        neck_hidden_sizes=[8, 8, 8, 8],
        fusion_hidden_size=8,
        backbone_out_indices=[0, 1, 2, 3],
        reassemble_factors=[4, 2, 1, 0.5],
    )


# Depth Anything's processor keeps the aspect ratio with sides a multiple of 14; DPT-Large's resizes to a square
PROCESSORS = {
    "da": dict(size={"height": 56, "width": 56}, keep_aspect_ratio=True, ensure_multiple_of=14),
    "dpt": dict(size={"height": 64, "width": 64}, keep_aspect_ratio=False),
}


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """Tiny random-weight models saved with save_pretrained, as a user's downloaded folder would be."""
    root = tmp_path_factory.mktemp("hf")
    torch.manual_seed(0)
    out = {}
    for name, cfg, proc in (
        ("da-relative", _depth_anything("relative"), "da"),
        ("da-metric", _depth_anything("metric"), "da"),
        ("dpt", _dpt(), "dpt"),
    ):
        AutoModelForDepthEstimation.from_config(cfg).save_pretrained(root / name)
        DPTImageProcessor(**PROCESSORS[proc]).save_pretrained(root / name)
        out[name] = root / name
    return out


def _zoedepth():
    from transformers import BeitConfig

    backbone = BeitConfig(
        hidden_size=16,
        num_hidden_layers=4,
        num_attention_heads=2,
        intermediate_size=32,
        image_size=64,
        patch_size=16,
        out_features=["stage1", "stage2", "stage3", "stage4"],
        reshape_hidden_states=False,
        use_relative_position_bias=True,
    )
    return ZoeDepthConfig(
        backbone_config=backbone,
        neck_hidden_sizes=[8, 8, 8, 8],
        fusion_hidden_size=8,
        bottleneck_features=8,
        num_attractors=[4, 4, 4, 4],
        bin_embedding_dim=8,
        num_relative_features=8,
        patch_size=16,
        reassemble_hidden_size=16,
        bin_configurations=[{"n_bins": 8, "min_depth": 0.001, "max_depth": 10.0, "name": "nyu"}],
    )


def test_zoedepth_runs_where_torchvision_is_else_one_line(tmp_path):
    """transformers' ZoeDepth post-processing (its padding removal) calls torchvision; without it: one line."""
    from transformers import ZoeDepthImageProcessor

    AutoModelForDepthEstimation.from_config(_zoedepth()).save_pretrained(tmp_path / "zoe")
    ZoeDepthImageProcessor(
        size={"height": 64, "width": 64}, keep_aspect_ratio=True, ensure_multiple_of=16
    ).save_pretrained(tmp_path / "zoe")
    try:
        import torchvision  # noqa: F401
    except ImportError:
        with pytest.raises(PanoreconInputError, match="needs torchvision") as e:
            get_teacher(f"hf:{tmp_path / 'zoe'}")
        assert "\n" not in str(e.value)
        return
    teacher = get_teacher(f"hf:{tmp_path / 'zoe'}")
    views = teacher.predict_views(load_scene("bedroom", 128), [centred_camera(np.array([1.0, 0, 0]), 40, 70.0)])
    assert views[0].metric and views[0].depth.shape == (40, 40)


def test_output_kinds_come_from_the_config():
    assert output_kind(_depth_anything("relative")) == OUTPUT_KINDS[("depth_anything", "relative")]
    assert output_kind(_depth_anything("relative")).affine and output_kind(_dpt()).kind == "disparity"
    metric = output_kind(_depth_anything("metric"))
    assert metric.metric and metric.kind == "z" and metric.alignment == "none"
    assert output_kind(ZoeDepthConfig()).metric and output_kind(DepthProConfig()).takes_fov
    with pytest.raises(PanoreconInputError, match="not in panorecon's table"):
        output_kind(types.SimpleNamespace(model_type="segformer"))
    listed = "\n".join(f"{a} {b}" for a, b in list_teachers())
    assert "hf:" in listed and "depth_anything (metric)" in listed and "scale and shift in inverse depth" in listed


@pytest.mark.parametrize("spec", ["hf:no-such-org/no-such-model", "hf:/no/such/folder"])
def test_a_model_not_on_the_machine_is_one_line(spec):
    with pytest.raises(PanoreconInputError) as e:
        get_teacher(spec)
    msg = str(e.value)
    assert "\n" not in msg and spec in msg and "hf download" in msg


def test_a_model_id_in_the_hub_cache_loads_offline(models, tmp_path):
    """A model id resolves from the Hugging Face cache layout (refs/main -> snapshots/<commit>) with
    HF_HUB_OFFLINE=1 in a fresh process (huggingface_hub reads its cache and offline settings at import)."""
    import shutil
    import subprocess
    import sys

    repo = tmp_path / "hf_home" / "hub" / "models--tiny-org--tiny-dpt"
    commit = "0123456789abcdef0123456789abcdef01234567"
    shutil.copytree(models["dpt"], repo / "snapshots" / commit)
    (repo / "refs").mkdir()
    (repo / "refs" / "main").write_text(commit)
    code = (
        "from panorecon.teachers import get_teacher, teacher_fingerprint; t = get_teacher('hf:tiny-org/tiny-dpt'); "
        "print(t.output.kind, teacher_fingerprint('hf:tiny-org/tiny-dpt'))"
    )
    env = {**os.environ, "HF_HOME": str(tmp_path / "hf_home"), "HF_HUB_OFFLINE": "1"}
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    kind, fingerprint = run.stdout.split()[-2:]
    assert kind == "disparity" and fingerprint.startswith("hf:tiny-org/tiny-dpt#")


def test_cli_missing_model_exits_2_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "out"
    rc = main(
        [
            "points",
            "bedroom",
            "--source",
            "fibonacci",
            "--teacher",
            "hf:no-such-org/no-such-model",
            "--width",
            "128",
            "--out",
            str(out / "c.ply"),
        ]
    )
    assert rc == 2 and not out.exists()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no-such-org/no-such-model" in err[0]


@pytest.mark.parametrize("bad", ["?batch=0", "?batch=x", "?colour=1", "?device=tpu"])
def test_bad_options(models, bad):
    with pytest.raises(PanoreconInputError):
        get_teacher(f"hf:{models['dpt']}{bad}")


def _known_depth(pixel_values: torch.Tensor) -> DepthEstimatorOutput:
    """A depth known at the processor's resolution: 1 + 0.5 u + 2 v (u, v pixel centres in [0, 1] across the
    processed image) plus each image's mean input value (so batching mix-ups show)."""
    B, _, H, W = pixel_values.shape
    v = (torch.arange(H, dtype=torch.float32) + 0.5) / H
    u = (torch.arange(W, dtype=torch.float32) + 0.5) / W
    field = 1 + 0.5 * u[None, :] + 2 * v[:, None]
    return DepthEstimatorOutput(predicted_depth=field[None] + pixel_values.float().mean((1, 2, 3))[:, None, None])


@pytest.mark.parametrize("name", ["da-relative", "dpt"])
@pytest.mark.parametrize("hw", [(48, 48), (40, 72), (90, 36)], ids=["square", "wide", "tall"])
def test_known_depth_comes_back_at_the_view_pixels(models, name, hw):
    teacher = get_teacher(f"hf:{models[name]}?batch=2")
    seen = []
    teacher.model = lambda pixel_values: seen.append(pixel_values.shape) or _known_depth(pixel_values)
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 256, (*hw, 3), dtype=np.uint8) for _ in range(3)]
    outs = teacher.run(images)
    h, w = hw
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(w) + 0.5) / w
    want = 1 + 0.5 * u[None, :] + 2 * v[:, None]
    H, W = seen[0][2:]
    assert (H == W) == (name == "dpt" or h == w)  # Depth Anything's processor keeps the aspect ratio
    by, bx = int(np.ceil(2 * h / H)) + 1, int(np.ceil(2 * w / W)) + 1  # bicubic taps reach past the border here
    # torch's bicubic (a = -0.75) bends a ramp by up to ~0.06 processed pixels: allow a quarter pixel of the
    # steeper ramp; half a pixel (an align-corners slip), a flip, a crop or a padding offset is far outside
    tol = 0.25 * max(2 / H, 0.5 / W)
    for img, out in zip(images, outs):
        assert out.shape == hw and out.dtype == np.float32
        offset = float(teacher.processor(images=[img], return_tensors="pt")["pixel_values"].mean())
        np.testing.assert_allclose(out[by:-by, bx:-bx], (want + offset)[by:-by, bx:-bx], atol=tol, rtol=0)
    assert [s[0] for s in seen] == [2, 1]
    one = get_teacher(f"hf:{models[name]}?batch=1")
    one.model = _known_depth
    for a, b in zip(outs, one.run(images)):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)


def test_views_carry_the_table_kind_and_the_sky(models):
    scene = load_scene("city-plaza", 128)
    cams = [centred_camera(np.array(f, float), 40, 80.0) for f in ([1, 0, 0.8], [0, 1, 0], [0, 0, 1])]
    rel = get_teacher(f"hf:{models['da-relative']}").predict_views(scene, cams)
    met = get_teacher(f"hf:{models['da-metric']}").predict_views(scene, cams)
    assert all(v.kind == "disparity" and v.affine and not v.metric for v in rel)
    assert all(v.kind == "z" and v.metric and not v.affine for v in met)
    skies = [sky_of_view(scene, c) for c in cams]
    assert skies[2].mean() > 0.5  # looking straight up in an open plaza
    for v, sky in zip(rel + met, skies + skies):
        assert not (v.valid & sky).any() and np.isfinite(v.depth).all()


def test_depth_pro_gets_the_view_fov(models, monkeypatch):
    """A Depth Pro teacher hands each view's horizontal FOV to the processor in place of the network's estimate."""
    teacher = get_teacher(f"hf:{models['dpt']}")
    teacher.output = OUTPUT_KINDS[("depth_pro", None)]
    got = []
    teacher.model = _known_depth
    real = teacher.processor.post_process_depth_estimation

    def post(outputs, **kw):
        got.append(outputs.field_of_view.tolist())
        return real(outputs, **kw)

    monkeypatch.setattr(teacher.processor, "post_process_depth_estimation", post)
    scene = load_scene("bedroom", 128)
    teacher.predict_views(scene, [centred_camera(np.array([1.0, 0, 0]), 32, fov) for fov in (60.0, 90.0)])
    np.testing.assert_allclose(sorted(sum(got, [])), [60.0, 90.0], rtol=1e-5)


def test_points_and_train_end_to_end(models, tmp_path):
    for name in ("da-relative", "da-metric", "dpt"):
        out = tmp_path / name
        assert (
            main(
                [
                    "points",
                    "bedroom",
                    "--source",
                    "fibonacci",
                    "--teacher",
                    f"hf:{models[name]}",
                    "--views",
                    "6",
                    "--width",
                    "128",
                    "--out",
                    str(out / "c.ply"),
                    "--report",
                    str(out / "r.json"),
                ]
            )
            == 0
        )
        report = json.loads((out / "r.json").read_text())
        assert report["teacher"] == f"hf:{models[name]}" and (out / "c.ply").stat().st_size > 1000
    out = tmp_path / "train"
    assert (
        main(
            [
                "train",
                "bedroom",
                "--source",
                "fibonacci",
                "--teacher",
                f"hf:{models['da-relative']}",
                "--views",
                "6",
                "--width",
                "128",
                "--iters",
                "20",
                "--res",
                "32",
                "--labels",
                "6",
                "--no-progress",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    m = json.loads((out / "metrics.json").read_text())
    assert np.isfinite(m["pseudo-label"]["psnr"]) and (out / "point_cloud.ply").is_file()


def test_erp_direct_keeps_the_kind_and_drops_metric_without_a_focal(models):
    scene = load_scene("bedroom", 128)
    teacher = get_teacher(f"hf:{models['da-metric']}")
    erp = teacher.predict_erp(scene)
    assert erp.depth.shape == scene.rgb.shape[:2] and erp.kind == "distance" and erp.metric
    teacher.output = OUTPUT_KINDS[("depth_pro", None)]  # takes a focal the ERP does not have
    assert not teacher.predict_erp(scene).metric
    rel = get_teacher(f"hf:{models['da-relative']}").predict_erp(scene)
    assert rel.kind == "disparity" and rel.affine and not (rel.valid & scene.sky).any()


def test_a_folder_of_a_non_depth_model_is_one_line_naming_it(tmp_path):
    from transformers import SegformerConfig

    SegformerConfig().save_pretrained(tmp_path / "seg")  # config.json is what decides
    with pytest.raises(PanoreconInputError) as e:
        get_teacher(f"hf:{tmp_path / 'seg'}")
    msg = str(e.value)
    assert "\n" not in msg and f"hf:{tmp_path / 'seg'}" in msg and "'segformer'" in msg
