"""The whole generator on a tiny random Stable-Diffusion-shaped model, on the CPU, in seconds."""
import numpy as np
import pytest
import torch

from panorecon.io import PanoreconInputError
from panorecon.metrics.seam import seam_discontinuity
from panorecon.text2pano import GenerateConfig, PanoramaGenerator, generate_cached

CFG = dict(width=256, steps=4, window=8, stride=4, decode_pad=4)


@pytest.fixture(scope="module")
def generator(tiny_model):
    return PanoramaGenerator.from_pretrained(tiny_model)


def test_generates_a_2_to_1_panorama_deterministically(generator):
    a = generator.generate("bedroom", GenerateConfig(**CFG, seed=1))
    b = generator.generate("bedroom", GenerateConfig(**CFG, seed=1))
    c = generator.generate("bedroom", GenerateConfig(**CFG, seed=2))
    assert a.shape == (128, 256, 3) and a.dtype == np.uint8
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_the_seam_block_couples_the_two_ends(generator, monkeypatch):
    """Perturb the initial noise of the rightmost latent columns only: with the seam block the leftmost columns
    of the result change (the ends are denoised together); without it they cannot."""
    def run(seam, bump):
        real_randn = torch.randn

        def randn(*shape, generator=None, **kw):
            x = real_randn(*shape, generator=generator, **kw)
            x[..., -2:] += bump
            return x

        monkeypatch.setattr(torch, "randn", randn)
        out = generator.denoise("a bedroom", GenerateConfig(**CFG, seam_block=seam))
        monkeypatch.setattr(torch, "randn", real_randn)
        return out

    for seam, coupled in ((True, True), (False, False)):
        left = (run(seam, 0.0) - run(seam, 0.5))[..., :2].abs().max()
        assert (left > 1e-4) == coupled, (seam, float(left))


class SmoothingDenoiser(torch.nn.Module):
    """A stand-in UNet with a known behaviour: it predicts x0 as a 5 x 5 box blur of its input window
    (replicate padding at the window's edges, as a window sees nothing beyond itself), i.e. it makes content
    locally coherent the way a trained denoiser does. A random tiny UNet cannot show a seam: its output keeps
    the i.i.d. initial noise, so every column boundary looks like the wrap."""

    def __init__(self, scheduler, channels=4):
        super().__init__()
        self.scheduler = scheduler
        self.config = type("Config", (), {"in_channels": channels})()

    def forward(self, sample, t, encoder_hidden_states=None):
        a = self.scheduler.alphas_cumprod[int(t)]
        x0 = torch.nn.functional.avg_pool2d(torch.nn.functional.pad(sample, (2, 2, 2, 2), mode="replicate"), 5, 1)
        eps = (sample - a.sqrt() * x0) / (1 - a).sqrt()
        return type("Out", (), {"sample": eps})()


def test_seam_score_with_and_without_the_seam_block(generator):
    """With a coherent denoiser the wrap is as smooth as any column boundary only with the seam block."""
    smooth = PanoramaGenerator(SmoothingDenoiser(generator.scheduler), generator.vae, generator.text_encoder,
                               generator.tokenizer, generator.scheduler)
    scores = {}
    for seam in (True, False):
        lat = smooth.denoise("a bedroom", GenerateConfig(**{**CFG, "steps": 20}, seam_block=seam))
        scores[seam] = seam_discontinuity(lat[0].permute(1, 2, 0).numpy(), band=4)
    print("latent seam score with / without seam block:", scores)
    assert scores[True] < 1.5 and scores[False] > 2 * scores[True]


def test_missing_model_says_where_it_looked_and_what_to_do(tmp_path):
    with pytest.raises(PanoreconInputError, match="no such folder") as e:
        PanoramaGenerator.from_pretrained(tmp_path / "nowhere")
    assert "--model DIR" in str(e.value) and "never downloads" in str(e.value)
    (tmp_path / "empty").mkdir()
    with pytest.raises(PanoreconInputError, match="model_index.json"):
        PanoramaGenerator.from_pretrained(tmp_path / "empty")


def test_generate_cached_reuses_the_file(tiny_model, tmp_path):
    cfg = GenerateConfig(**CFG)
    p1 = generate_cached("beach", str(tiny_model), cfg, tmp_path)
    mtime = p1.stat().st_mtime_ns
    p2 = generate_cached("beach", str(tiny_model), cfg, tmp_path)
    assert p1 == p2 and p2.stat().st_mtime_ns == mtime
    assert generate_cached("beach", str(tiny_model), GenerateConfig(**CFG, seed=5), tmp_path) != p1


def test_a_model_id_not_in_the_local_cache_is_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf"))
    with pytest.raises(PanoreconInputError, match="not found locally"):
        PanoramaGenerator.from_pretrained("someone/not-a-cached-model")


def test_generate_command_writes_the_panorama_and_its_seam_score(tiny_model, tmp_path, capsys):
    from panorecon.cli import main

    out = tmp_path / "pano.png"
    assert main(["generate", "--preset", "beach", "--model", str(tiny_model), "--steps", "2", "--width", "128",
                 "--out", str(out)]) == 0
    assert out.is_file() and "seam score" in capsys.readouterr().out
    assert main(["generate", "--prompt", "x", "--model", str(tmp_path / "none"), "--out", str(tmp_path / "y.png")]) == 2
    assert not (tmp_path / "y.png").exists()
