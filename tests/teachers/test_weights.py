"""The learned teachers shipped in panorecon/teachers/weights: each ONNX file computes what its training's
state dict computes in torch (they cannot drift apart), it is read by the plain ``onnx:`` teacher, and
``teachers list`` names it."""

import json

import numpy as np
import pytest
import torch

from panorecon.learned.model import DepthNet, parameter_count
from panorecon.learned.train import to_input
from panorecon.teachers import get_teacher, list_teachers, shipped_models

MODELS = shipped_models()


def test_two_learned_teachers_are_shipped_and_listed():
    assert len(MODELS) >= 2
    listed = dict(list_teachers())
    for path in MODELS:
        (spec,) = [s for s in listed if s.startswith("onnx:") and s.endswith(path.name)]
        assert "learned" in listed[spec] and "unreadable" not in listed[spec]


@pytest.mark.parametrize("path", MODELS, ids=[p.stem for p in MODELS])
def test_the_onnx_file_equals_its_state_dict(path):
    record = json.loads(path.with_suffix(".train.json").read_text())
    torch.manual_seed(0)
    model = DepthNet(record["config"]["width"])
    model.load_state_dict(torch.load(path.with_suffix(".pt"), weights_only=True))
    model.eval()
    assert parameter_count(model) == record["parameters"]
    size = record["config"]["size"]
    rng = np.random.default_rng(0)
    v, u = np.mgrid[0:size, 0:size] / size
    smooth = np.stack([255 * u, 255 * v, 128 + 100 * np.sin(9 * u * v)], -1)
    for rgb in (rng.integers(0, 256, (size, size, 3)), smooth):
        rgb = rgb.astype(np.uint8)
        teacher = get_teacher(f"onnx:{path}")  # the user's path: preprocessing from <model>.json, onnxruntime
        got = teacher.run(rgb)
        with torch.no_grad():
            want = model(to_input(rgb[None]))[0, 0].numpy()
        assert got.shape == want.shape and np.isfinite(got).all()
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-4 * float(np.abs(want).max()))
    assert teacher.config["output"] == "disparity" and teacher.config["mode"] == "affine"
