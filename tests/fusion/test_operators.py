"""The matrix-free normal operator against the assembled sparse matrix it replaces (the slow reference)."""

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from panorecon.fusion.operators import StencilNormalOperator, stacked_operator, transpose_apply


def assembled(H, W, wx, wy, wl, d):
    B, row_of_entry = stacked_operator(H, W)
    w = np.concatenate([wx, wy, wl, d])
    Bw = sp.csr_matrix((B.data * np.sqrt(w)[row_of_entry], B.indices, B.indptr), shape=B.shape)
    return (Bw.T @ Bw).tocsr(), B


def random_weights(H, W, rng, spread=1.0):
    f = lambda n: 10 ** rng.uniform(-spread, spread, n) * (rng.random(n) > 0.1)  # noqa: E731  (some zero weights)
    return f(H * W), f((H - 1) * W), f(max(H - 2, 0) * W), f(H * W)


@settings(max_examples=25, deadline=None)
@given(st.integers(2, 9), st.integers(3, 12), st.integers(0, 10_000), st.sampled_from([1.0, 6.0]))
def test_matvec_and_diagonal_equal_the_assembled_matrix(H, W, seed, spread):
    """Includes 2-row grids (no Laplacian rows), 3-column grids (every pixel next to the seam) and weights
    spanning 1e-6..1e6 (stiff regularization)."""
    rng = np.random.default_rng(seed)
    wx, wy, wl, d = random_weights(H, W, rng, spread)
    A, _ = assembled(H, W, wx, wy, wl, d)
    op = StencilNormalOperator(H, W, wx, wy, wl, d)
    x = rng.normal(size=H * W)
    np.testing.assert_allclose(op @ x, A @ x, rtol=1e-10, atol=1e-10 * np.abs(A).max())
    np.testing.assert_allclose(op.diagonal(), A.diagonal(), rtol=1e-12, atol=1e-12 * np.abs(A).max())


def test_transpose_apply_is_b_transpose():
    H, W = 6, 10
    rng = np.random.default_rng(0)
    tx, ty, tl = rng.normal(size=H * W), rng.normal(size=(H - 1) * W), rng.normal(size=(H - 2) * W)
    _, B = assembled(H, W, *random_weights(H, W, rng))
    want = B.T @ np.concatenate([tx, ty, tl, np.zeros(H * W)])
    np.testing.assert_allclose(transpose_apply(H, W, tx, ty, tl).ravel(), want, atol=1e-12)


def test_the_seam_couples_first_and_last_columns():
    H, W = 4, 8
    op = StencilNormalOperator(H, W, np.ones(H * W), np.zeros((H - 1) * W), np.zeros((H - 2) * W), np.zeros(H * W))
    x = np.zeros(H * W)
    x[0] = 1.0  # row 0, column 0: its left neighbour is column W-1
    y = (op @ x).reshape(H, W)
    assert y[0, W - 1] == pytest.approx(-1.0) and y[0, 1] == pytest.approx(-1.0) and y[0, 0] == pytest.approx(2.0)


@settings(max_examples=25, deadline=None)
@given(st.integers(2, 9), st.integers(3, 12), st.integers(0, 10_000), st.sampled_from([1.0, 6.0]))
def test_torch_operator_equals_the_numpy_one(H, W, seed, spread):
    """The torch CG's operator (float64, CPU here; the same code runs on CUDA) against the NumPy one."""
    import torch

    from panorecon.fusion.operators import TorchStencilOperator

    rng = np.random.default_rng(seed)
    op = StencilNormalOperator(H, W, *random_weights(H, W, rng, spread))
    x = rng.normal(size=H * W)
    got = (TorchStencilOperator(op, "cpu") @ torch.from_numpy(x)).numpy()
    np.testing.assert_allclose(got, op @ x, rtol=1e-12, atol=1e-12 * np.abs(op @ x).max())


def test_float32_operator_equals_the_float64_one():
    rng = np.random.default_rng(4)
    H, W = 9, 14
    op = StencilNormalOperator(
        H, W, rng.random(H * W), rng.random((H - 1) * W), rng.random((H - 2) * W), rng.random(H * W)
    )
    x = rng.standard_normal(H * W)
    y32 = op.astype(np.float32) @ x.astype(np.float32)
    assert y32.dtype == np.float32
    np.testing.assert_allclose(y32, op @ x, rtol=1e-5, atol=1e-5)
