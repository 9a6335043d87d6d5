"""``moge:`` teacher through MoGe's package: version and output kind from the checkpoint config, local-only
loading with one-line errors, each view's FOV handed to ``infer``, batched equal to unbatched, and a tiny
random-weight MoGe-2 (ViT-S/14 backbone, the smallest MoGe builds) end to end through ``points``."""

import json
import warnings

import numpy as np
import pytest
import torch

v2 = pytest.importorskip("moge.model.v2", reason="MoGe's package (dlr-moge) is not installed")

from panorecon.cli import main  # noqa: E402
from panorecon.geometry import centred_camera  # noqa: E402
from panorecon.io import PanoreconInputError  # noqa: E402
from panorecon.scenes import load_scene  # noqa: E402
from panorecon.teachers import get_teacher, list_teachers  # noqa: E402
from panorecon.teachers.moge_teacher import MOGE1, MOGE2_METRIC, moge_output_kind  # noqa: E402


def _stack(last):
    return dict(
        dim_in=[32, 16, 16, 8, 8],
        dim_out=[None, None, None, None, last],
        dim_res_blocks=[32, 16, 16, 8, 8],
        num_res_blocks=[0, 1, 1, 1, 0],
        res_block_in_norm="none",
        res_block_hidden_norm="none",
        resamplers=["conv_transpose"] * 3 + ["bilinear"],
    )


TINY_V2 = dict(
    encoder=dict(backbone="dinov2_vits14", intermediate_layers=[2, 5, 8, 11], dim_out=32),
    neck=dict(_stack(None), dim_in=[34, 2, 2, 2, 2]),
    points_head=_stack(3),
    mask_head=_stack(1),
    scale_head=dict(dims=[384, 32, 1]),
    remap_output="exp",
    num_tokens_range=[16, 36],
)


@pytest.fixture(scope="module")
def moge2(tmp_path_factory):
    folder = tmp_path_factory.mktemp("moge2")
    torch.manual_seed(0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = v2.MoGeModel(**TINY_V2)
    torch.save({"model_config": TINY_V2, "model": model.state_dict()}, folder / "model.pt")
    return folder


def test_version_and_output_from_the_config():
    assert moge_output_kind(TINY_V2) == (2, MOGE2_METRIC) and MOGE2_METRIC.metric
    assert moge_output_kind({k: v for k, v in TINY_V2.items() if k != "scale_head"}) == (2, MOGE1)
    assert moge_output_kind({"encoder": "dinov2_vitl14", "intermediate_layers": 4}) == (1, MOGE1)
    assert MOGE1.alignment == "scale" and MOGE1.kind == "z"
    specs = [s for s, _ in list_teachers()]
    assert "moge:<model.pt, folder or id>" in specs


@pytest.mark.parametrize("spec", ["moge:Ruicheng/moge-2-vitl-normal", "moge:/no/such/model.pt"])
def test_a_checkpoint_not_on_the_machine_is_one_line(spec):
    with pytest.raises(PanoreconInputError) as e:
        get_teacher(spec)
    assert "\n" not in str(e.value) and spec.partition(":")[2] in str(e.value) and "hf download" in str(e.value)


def test_not_a_checkpoint(tmp_path):
    (tmp_path / "model.pt").write_bytes(b"junk")
    with pytest.raises(PanoreconInputError, match="not a MoGe checkpoint"):
        get_teacher(f"moge:{tmp_path}")
    with pytest.raises(PanoreconInputError, match="no model.pt"):
        get_teacher(f"moge:{tmp_path / 'empty'}" if (tmp_path / "empty").mkdir() is None else "")


def test_views_get_their_fov_and_batching_changes_nothing(moge2):
    scene = load_scene("bedroom", 128)
    cams = [centred_camera(np.array(f, float), 28, fov) for f, fov in (([1, 0, 0], 60.0), ([0, 1, 0.3], 90.0))]
    teacher = get_teacher(f"moge:{moge2}?batch=2")
    real, seen = teacher.model.infer, []

    def infer(x, fov_x=None, **kw):
        seen.append(fov_x.tolist())
        return real(x, fov_x=fov_x, **kw)

    teacher.model.infer = infer
    batched = teacher.predict_views(scene, cams)
    teacher.batch = 1
    single = teacher.predict_views(scene, cams)
    assert seen[0] == pytest.approx([60.0, 90.0], rel=1e-6) and len(seen) == 3
    for a, b in zip(batched, single):
        assert a.metric and a.kind == "z" and a.depth.shape == (28, 28)
        np.testing.assert_allclose(np.nan_to_num(a.depth), np.nan_to_num(b.depth), rtol=1e-4, atol=1e-5)
        np.testing.assert_array_equal(a.valid, b.valid)


def test_points_end_to_end(moge2, tmp_path):
    out = tmp_path / "p"
    assert (
        main(
            [
                "points",
                "bedroom",
                "--source",
                "fibonacci",
                "--teacher",
                f"moge:{moge2}",
                "--views",
                "4",
                "--view-size",
                "32",
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
    assert json.loads((out / "r.json").read_text())["teacher"] == f"moge:{moge2}"
