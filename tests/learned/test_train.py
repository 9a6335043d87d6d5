"""The learned teacher's training: it learns on a tiny set, a resumed run is the same run, and its config
refuses what it cannot train on."""

import dataclasses

import numpy as np
import pytest
import torch

from panorecon.cli import main
from panorecon.learned import train as T
from panorecon.learned.data import Crops
from panorecon.learned.model import DepthNet


def blocks(n: int, size: int, seed: int) -> Crops:
    """Near rectangles before a far wall, their colour following their disparity (a cue a network can read)."""
    rng = np.random.default_rng(seed)
    depth = np.empty((n, size, size), np.float32)
    for i in range(n):
        depth[i] = rng.uniform(4, 8)
        for _ in range(3):
            (y, x), (h, w) = rng.integers(0, size - 8, 2), rng.integers(6, 16, 2)
            depth[i, y : y + h, x : x + w] = rng.uniform(1, 3)
    shade = (255 * (1 / depth - 1 / 8) / (1 - 1 / 8)).astype(np.uint8)
    rgb = np.stack([shade, 255 - shade, shade // 2], -1)
    return Crops(rgb, depth, np.zeros(n, np.int32), np.full(n, 60, np.float32), ("blocks",), 0.0)


def test_the_loop_learns_a_tiny_set():
    torch.manual_seed(0)
    torch.set_num_threads(1)
    crops = blocks(8, 32, 0)
    model = DepthNet(8)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = [T.train_step(model, opt, crops, *T.batch_indices(0, s, len(crops), 8), 0.5)["loss"] for s in range(100)]
    assert np.mean(losses[-10:]) < 0.25 * np.mean(losses[:5]), (losses[:5], losses[-10:])


TINY = [
    "--families", "bedroom", "--holdout", "library", "mountain", "--train-variants", "1", "--val-variants", "1",
    "--crops-per-scene", "6", "--val-crops-per-scene", "2", "--size", "32", "--erp-width", "64", "--width", "2",
    "--steps", "6", "--batch", "2", "--val-every", "3", "--checkpoint-every", "3", "--no-progress",
]  # fmt: skip


def test_a_resumed_run_is_the_same_run_and_exports(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("PANORECON_CACHE", str(tmp_path / "cache"))
    assert main(["teachers", "train", *TINY, "--out", str(tmp_path / "a")]) == 0
    assert "val seen AbsRel" in capsys.readouterr().out
    real_step, calls = T.train_step, []

    def stop_at_the_fifth(*args):
        calls.append(1)
        if len(calls) == 5:
            raise KeyboardInterrupt
        return real_step(*args)

    monkeypatch.setattr(T, "train_step", stop_at_the_fifth)
    assert main(["teachers", "train", *TINY, "--out", str(tmp_path / "b")]) == 130  # as a Ctrl-C at step 5
    assert torch.load(tmp_path / "b" / "ckpt.pt", weights_only=True)["step"] == 3
    monkeypatch.setattr(T, "train_step", real_step)
    assert main(["teachers", "train", *TINY, "--out", str(tmp_path / "b")]) == 0
    a = torch.load(tmp_path / "a" / "teacher.pt", weights_only=True)
    b = torch.load(tmp_path / "b" / "teacher.pt", weights_only=True)
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    assert (tmp_path / "b" / "teacher.onnx").stat().st_size > 0


@pytest.mark.parametrize(
    "change, needle",
    [
        ({"size": 40}, "size = 40: expected a multiple of 16"),
        ({"fov_min": 100.0}, "fov_min = 100.0: expected at most fov_max"),
        ({"holdout": ("library",)}, "holdout = .*one indoor and one outdoor"),
        ({"holdout": ("bedroom", "beach")}, "bedroom also in families"),
        ({"families": ("bedroom", "nowhere")}, "families = .*expected one of"),
        ({"width": 0}, "width = 0: 0 is out of range"),
        ({"name": "../x"}, "name = '../x': expected a file stem"),
        ({"first_variant": 3}, "first_variant = 3: 3 is out of range"),
    ],
)
def test_config_errors_name_the_value(change, needle):
    with pytest.raises(ValueError, match=needle):
        dataclasses.replace(T.DepthTrainConfig(), **change)


def test_the_command_line_refuses_a_bad_value_with_one_line(tmp_path, capsys):
    assert main(["teachers", "train", "--width", "0", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--width: 0 is out of range" in err[0]
    assert not (tmp_path / "o").exists()
