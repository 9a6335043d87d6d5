import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from panorecon.text2pano.presets import PRESETS, TRIGGER, panorama_prompt
from panorecon.text2pano.windows import coverage, seam_columns, seam_weights, window_starts


@given(st.integers(8, 400), st.integers(1, 64), st.integers(1, 32))
def test_windows_cover_every_column(width, window, stride):
    window = min(window, width)
    stride = min(stride, window)
    starts = window_starts(width, window, stride)
    assert starts[0] == 0 and starts[-1] + window == width
    assert (coverage(width, window, stride) >= 1).all()


def test_a_stride_wider_than_the_window_is_refused():
    with pytest.raises(ValueError, match="uncovered"):
        window_starts(100, 8, 9)


def test_paper_layout_gives_nine_windows():
    # 512 x 2048 image -> 64 x 256 latent; nine patches as in the paper: StitchDiffusion's 128-column views
    # with stride 16, or 64-column windows with stride 24
    assert window_starts(256, 128, 16) == list(range(0, 129, 16))
    assert len(window_starts(256, 64, 24)) == 9


def test_seam_block_straddles_the_wrap_and_its_weight_peaks_there():
    cols = seam_columns(256, 64)
    assert list(cols[:2]) == [224, 225] and list(cols[-2:]) == [30, 31] and len(cols) == 64
    w = seam_weights(256, 64, 16)
    share = w / (w + coverage(256, 64, 16)[cols])
    assert np.argmax(w) in (31, 32) and share.max() > 0.95 and share[0] < 0.05 and share[-1] < 0.05
    # the share falls linearly from the wrap to the block's edges
    np.testing.assert_allclose(np.diff(share[:32]), share[1] - share[0], rtol=1e-9)


def test_presets_are_the_papers_prompts_with_the_trigger():
    assert len(PRESETS) == 8 and PRESETS["beach"] == "Waves on the beach"
    assert panorama_prompt("bedroom") == f"{TRIGGER}, A bedroom"
    assert panorama_prompt("a red barn") == f"{TRIGGER}, a red barn"
    with pytest.raises(ValueError):
        panorama_prompt("  ")
