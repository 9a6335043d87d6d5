"""The whole generator on a tiny random Stable-Diffusion-shaped model, on the CPU, in seconds."""

import numpy as np
import pytest
import torch

from panorecon.io import PanoreconInputError
from panorecon.metrics.seam import seam_discontinuity
from panorecon.text2pano import GenerateConfig, PanoramaGenerator, generate_cached

CFG = dict(width=256, steps=4, window=8, stride=4, decode_pad=4)


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    """The tiny convs are far slower split over 2 threads on a busy 2-core machine (oneDNN spin-waits)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="module")
def generator(tiny_model):
    return PanoramaGenerator.from_pretrained(tiny_model)


def test_generates_a_2_to_1_panorama_deterministically(generator):
    a = generator.generate("bedroom", GenerateConfig(**CFG, seed=1))
    b = generator.generate("bedroom", GenerateConfig(**CFG, seed=1))
    c = generator.generate("bedroom", GenerateConfig(**CFG, seed=2))
    assert a.shape == (128, 256, 3) and a.dtype == np.uint8
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_the_decoder_is_wrap_consistent(generator):
    """Width-circular decoder convs: decoding a latent rolled by k columns = the image rolled by 8k pixels; the
    central crop of a wrap-padded decode keeps the panorama's size."""
    z = torch.randn(1, 4, 8, 16, generator=torch.Generator().manual_seed(0))
    img = generator.decode(z, decode_pad=0).astype(int)
    rolled = generator.decode(torch.roll(z, 5, -1), decode_pad=0).astype(int)
    assert np.abs(np.roll(img, 5 * generator.vae_factor, axis=1) - rolled).max() <= 1
    assert generator.decode(z, decode_pad=4).shape == img.shape == (64, 128, 3)


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
    smooth = PanoramaGenerator(
        SmoothingDenoiser(generator.scheduler),
        generator.vae,
        generator.text_encoder,
        generator.tokenizer,
        generator.scheduler,
    )
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


def test_a_lora_that_cannot_be_applied_is_one_input_error(generator, tmp_path):
    from safetensors.torch import save_file

    save_file({"not_lora.weight": torch.zeros(2, 2)}, tmp_path / "bad.safetensors")
    for lora in (tmp_path / "missing.safetensors", tmp_path / "bad.safetensors"):
        with pytest.raises(PanoreconInputError, match="--lora"):
            generator.load_lora(lora)


def test_bad_settings_are_input_errors():
    with pytest.raises(PanoreconInputError, match="stride"):
        GenerateConfig(window=8, stride=9).check()
    with pytest.raises(PanoreconInputError, match="multiple of 16"):
        GenerateConfig(width=1000).check()


def test_generate_cached_reuses_the_file(tiny_model, tmp_path):
    cfg = GenerateConfig(**CFG)
    p1 = generate_cached("beach", str(tiny_model), cfg, tmp_path)
    mtime = p1.stat().st_mtime_ns
    p2 = generate_cached("beach", str(tiny_model), cfg, tmp_path)
    assert p1 == p2 and p2.stat().st_mtime_ns == mtime
    assert generate_cached("beach", str(tiny_model), GenerateConfig(**CFG, seed=5), tmp_path) != p1
    assert generate_cached("a bedroom", str(tiny_model), cfg, tmp_path) != p1


def test_a_model_id_not_in_the_local_cache_is_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf"))
    with pytest.raises(PanoreconInputError, match="not found locally"):
        PanoramaGenerator.from_pretrained("someone/not-a-cached-model")


def test_generate_command_writes_the_panorama_and_its_seam_score(tiny_model, tmp_path, capsys):
    from panorecon.cli import main

    out = tmp_path / "pano.png"
    assert (
        main(
            [
                "generate",
                "--preset",
                "beach",
                "--model",
                str(tiny_model),
                "--steps",
                "2",
                "--width",
                "128",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert out.is_file() and "seam score" in capsys.readouterr().out
    assert main(["generate", "--prompt", "x", "--model", str(tmp_path / "none"), "--out", str(tmp_path / "y.png")]) == 2
    assert not (tmp_path / "y.png").exists()


def test_a_prompt_scene_is_generated_once_and_runs_through_a_point_source(tiny_model, tmp_path, monkeypatch):
    from panorecon.pipeline import Row, StageCache, run_points
    from panorecon.pipeline.stages import load_row_scene

    cache = StageCache(tmp_path)
    with pytest.raises(PanoreconInputError, match="PANORECON_TEXT2PANO_MODEL"):
        load_row_scene("prompt:beach", 64, cache)
    monkeypatch.setenv("PANORECON_TEXT2PANO_MODEL", str(tiny_model))
    monkeypatch.setenv("PANORECON_TEXT2PANO_STEPS", "2")
    scene = load_row_scene("prompt:beach", 64, cache)
    assert scene.rgb.shape == (32, 64, 3) and not scene.has_ground_truth
    assert len(list((tmp_path / "text2pano").glob("*.png"))) == 1
    record = run_points(cache, Row("prompt:beach", 64, "random", None))
    assert record["points"] > 0 and record["report"]["depth"].startswith("n/a")
    assert len(list((tmp_path / "text2pano").glob("*.png"))) == 1  # generated once
