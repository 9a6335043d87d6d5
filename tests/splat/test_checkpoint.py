"""The trainer's checkpoint: weights_only, input keys, corrupt files set aside (unit level, no training)."""

import logging
import pickle

import numpy as np
import pytest
import torch

from panorecon.geometry import PointCloud
from panorecon.io import PanoreconInputError
from panorecon.splat.checkpoint import checkpoint_inputs, cloud_digest, load_checkpoint, save_checkpoint
from panorecon.splat.model import PARAM_NAMES


class _Scene:
    name, width = "bedroom", 64


def _state(n=5, iteration=10):
    params = {k: torch.nn.Parameter(torch.randn(n, 3)) for k in PARAM_NAMES}
    opt = torch.optim.Adam(list(params.values()), lr=1e-3)
    sum(p.sum() for p in params.values()).backward()
    opt.step()
    return {
        "iteration": iteration,
        "history": [{"iteration": 5, "psnr": 20.0, "gaussians": n}],
        "optimizer": opt.state_dict(),
        "strategy": {"grad_sum": torch.zeros(n), "count": torch.zeros(n)},
        "rng": torch.get_rng_state(),
        "model": {k: p.detach() for k, p in params.items()},
    }


@pytest.fixture
def inputs():
    pc = PointCloud(np.arange(12.0).reshape(4, 3), np.zeros((4, 3)))
    return checkpoint_inputs(_Scene(), pc, "cfg", {"source": "fibonacci", "teacher": "sim:clean", "views": None})


def test_round_trip_with_weights_only(tmp_path, inputs):
    save_checkpoint(tmp_path / "ckpt.pt", inputs, _state())
    state = load_checkpoint(tmp_path / "ckpt.pt", inputs, iters=100)
    assert state["iteration"] == 10 and state["inputs"] == inputs
    assert load_checkpoint(tmp_path / "none.pt", inputs, iters=100) is None


@pytest.mark.parametrize(
    "key, value",
    [
        ("scene", "beach"),
        ("width", 128),
        ("config", "other"),
        ("cloud", "0" * 16),
        ("source", "random"),
        ("teacher", "sim:relative"),
    ],
)
def test_a_checkpoint_for_other_inputs_is_refused_naming_what_differs(tmp_path, inputs, key, value):
    save_checkpoint(tmp_path / "ckpt.pt", {**inputs, key: value}, _state())
    with pytest.raises(PanoreconInputError, match=f"ckpt.pt was written for a different run \\({key}: "):
        load_checkpoint(tmp_path / "ckpt.pt", inputs, iters=100)
    assert (tmp_path / "ckpt.pt").exists()  # refused, left for the user to look at


def test_cloud_digest_sees_any_changed_point():
    a = PointCloud(np.zeros((3, 3)), np.zeros((3, 3)))
    b = PointCloud(np.array([[0, 0, 0], [0, 0, 0], [0, 0, 1e-6]]), np.zeros((3, 3)))
    assert cloud_digest(a) != cloud_digest(b) and cloud_digest(a) == cloud_digest(a.subset(slice(None)))


def _cut(path):
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _junk(path):
    path.write_bytes(b"\0" * 100)


def _foreign(path):
    torch.save({"config": "abc"}, path)


def _nan(path, inputs=None):
    s = _state()
    s["model"]["means"][0, 0] = float("nan")
    save_checkpoint(path, inputs, s)


def _late(path, inputs=None):
    save_checkpoint(path, inputs, _state(iteration=100))


@pytest.mark.parametrize("spoil", [_cut, _junk, _foreign, _nan, _late], ids=["cut", "junk", "not-ours", "nan", "late"])
def test_a_corrupt_checkpoint_is_set_aside_with_a_warning(tmp_path, inputs, caplog, spoil):
    path = tmp_path / "ckpt.pt"
    save_checkpoint(path, inputs, _state())
    spoil(path, inputs) if spoil in (_nan, _late) else spoil(path)
    with caplog.at_level(logging.WARNING, logger="panorecon.train"):
        assert load_checkpoint(path, inputs, iters=100) is None
    assert str(path) in caplog.text and "step 0" in caplog.text
    assert not path.exists() and (tmp_path / "ckpt.pt.bad").exists()


class _Evil:
    def __reduce__(self):
        import os

        return (os.system, ("touch pwned",))


def test_a_checkpoint_with_code_in_it_does_not_run_it(tmp_path, inputs, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with open(tmp_path / "ckpt.pt", "wb") as f:
        pickle.dump({"inputs": inputs, "evil": _Evil()}, f)
    torch.save({"inputs": inputs, "evil": _Evil()}, tmp_path / "ckpt2.pt")
    for name in ("ckpt.pt", "ckpt2.pt"):
        assert load_checkpoint(tmp_path / name, inputs, iters=100) is None
    assert not (tmp_path / "pwned").exists()
