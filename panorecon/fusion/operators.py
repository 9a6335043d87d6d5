"""Sparse difference operators on an H x W ERP grid (flat index r * W + c), wrapping across the seam."""

from __future__ import annotations

import functools

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


def horizontal_pairs(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """(p, q) flat indices of every horizontal neighbour pair, q right of p, wrapping at the seam: [H*W] each."""
    p = np.arange(height * width)
    q = (p // width) * width + (p % width + 1) % width
    return p, q


def vertical_pairs(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """(p, q) flat indices of every vertical neighbour pair, q below p: [(H-1)*W] each."""
    p = np.arange((height - 1) * width)
    return p, p + width


def difference_matrix(p: np.ndarray, q: np.ndarray, n: int) -> sp.csr_matrix:
    """Rows x_q - x_p, [len(p), n]."""
    m = len(p)
    rows = np.repeat(np.arange(m), 2)
    cols = np.stack([q, p], 1).ravel()
    vals = np.tile([1.0, -1.0], m)
    return sp.csr_matrix((vals, (rows, cols)), shape=(m, n))


@functools.lru_cache(maxsize=8)
def laplacian_matrix(height: int, width: int) -> sp.csr_matrix:
    """5-point Laplacian rows x_left + x_right + x_up + x_down - 4 x_p for interior rows (1..H-2), [(H-2)*W, H*W]."""
    r, c = np.meshgrid(np.arange(1, height - 1), np.arange(width), indexing="ij")
    p = (r * width + c).ravel()
    nbrs = [r * width + (c - 1) % width, r * width + (c + 1) % width, (r - 1) * width + c, (r + 1) * width + c]
    m = len(p)
    rows = np.repeat(np.arange(m), 5)
    cols = np.stack([p] + [n.ravel() for n in nbrs], 1).ravel()
    vals = np.tile([-4.0, 1.0, 1.0, 1.0, 1.0], m)
    return sp.csr_matrix((vals, (rows, cols)), shape=(m, height * width))


def laplacian_centres(height: int, width: int) -> np.ndarray:
    """Flat indices of the pixels ``laplacian_matrix`` rows are centred on, [(H-2)*W]."""
    return np.arange(width, (height - 1) * width)


@functools.lru_cache(maxsize=2)
def stacked_operator(height: int, width: int):
    """B = [D_horizontal; D_vertical; Laplacian; Identity] (CSR, rows in that order: H*W, (H-1)*W, (H-2)*W,
    H*W) and the row of every stored entry ([nnz] int32), cached per size. For row weights r,
    (diag(r) B)^T (diag(r) B) is then one sparse product: no COO assembly, no matrix sums.
    Built directly from its fixed row lengths (2, 2, 5, 1 entries) rather than by stacking matrices."""
    n = height * width
    hp, hq = horizontal_pairs(height, width)
    vp, vq = vertical_pairs(height, width)
    r, c = np.meshgrid(np.arange(1, height - 1), np.arange(width), indexing="ij")
    centre = (r * width + c).ravel()
    lap_cols = np.stack(
        [
            (r * width + (c - 1) % width).ravel(),
            (r * width + (c + 1) % width).ravel(),
            ((r - 1) * width + c).ravel(),
            ((r + 1) * width + c).ravel(),
            centre,
        ],
        1,
    )
    indices = np.concatenate(
        [np.stack([hq, hp], 1).ravel(), np.stack([vq, vp], 1).ravel(), lap_cols.ravel(), np.arange(n)]
    ).astype(np.int32)
    data = np.concatenate(
        [np.tile([1.0, -1.0], len(hp) + len(vp)), np.tile([1.0, 1.0, 1.0, 1.0, -4.0], len(centre)), np.ones(n)]
    )
    lengths = np.concatenate([np.full(len(hp) + len(vp), 2), np.full(len(centre), 5), np.ones(n, int)])
    indptr = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    B = sp.csr_matrix((data, indices, indptr), shape=(len(lengths), n))
    row_of_entry = np.repeat(np.arange(len(lengths), dtype=np.int32), lengths)
    return B, row_of_entry


class StencilNormalOperator(spla.LinearOperator):
    """A = Dx^T diag(wx) Dx + Dy^T diag(wy) Dy + Lap^T diag(wl) Lap + diag(d), applied on the H x W grid with
    array shifts instead of a stored matrix (the same operator as ``(R B)^T (R B)`` for ``stacked_operator``).

    wx [H*W]: weight of the pair (p, right of p, wrapping); wy [(H-1)*W]: pair (p, below p); wl [(H-2)*W]:
    Laplacian row centred on interior pixel p (rows 1..H-2); d [H*W]: diagonal (data) weights. ``dtype``: float64
    (default) or float32 (half the memory traffic per product: the inner solve of a mixed-precision CG).
    Needs width >= 3 (narrower, a pixel's left and right neighbours coincide).
    """

    def __init__(self, height: int, width: int, wx, wy, wl, d, dtype=np.float64):
        if width < 3 or height < 2:
            raise ValueError(f"StencilNormalOperator on a {height} x {width} grid: expected height >= 2, width >= 3")
        super().__init__(np.dtype(dtype), (height * width, height * width))
        self.height, self.width = height, width
        self.wx = np.asarray(wx, dtype).reshape(height, width)
        self.wy = np.asarray(wy, dtype).reshape(height - 1, width)
        self.wl = np.asarray(wl, dtype).reshape(max(height - 2, 0), width)
        self.d = np.asarray(d, dtype).reshape(height, width)

    def astype(self, dtype) -> StencilNormalOperator:
        """The same operator with its weights (and products) in ``dtype``."""
        return StencilNormalOperator(self.height, self.width, self.wx, self.wy, self.wl, self.d, dtype)

    def _matvec(self, x):
        X = np.asarray(x, self.dtype).reshape(self.height, self.width)
        right = np.roll(X, -1, axis=1)
        tx = self.wx * (right - X)
        ty = self.wy * (X[1:] - X[:-1])
        tl = self.wl * (right[1:-1] + np.roll(X, 1, axis=1)[1:-1] + X[:-2] + X[2:] - 4 * X[1:-1])
        return transpose_apply(self.height, self.width, tx, ty, tl).ravel() + (self.d * X).ravel()

    def _rmatvec(self, x):
        return self._matvec(x)  # symmetric

    def diagonal(self) -> np.ndarray:
        diag = self.wx + np.roll(self.wx, 1, axis=1) + self.d
        diag[:-1] += self.wy
        diag[1:] += self.wy
        diag[1:-1] += 16 * self.wl + np.roll(self.wl, 1, axis=1) + np.roll(self.wl, -1, axis=1)
        diag[:-2] += self.wl
        diag[2:] += self.wl
        return diag.ravel()


def transpose_apply(height: int, width: int, tx, ty, tl) -> np.ndarray:
    """Dx^T tx + Dy^T ty + Lap^T tl as an [H, W] array, for per-row values tx [H, W] (horizontal pairs),
    ty [H-1, W] (vertical pairs) and tl [H-2, W] (Laplacian rows centred on rows 1..H-2); float32 when all three
    are float32, else float64."""
    dtype = np.result_type(tx, ty, tl, np.float32)
    tx = np.asarray(tx, dtype).reshape(height, width)
    ty = np.asarray(ty, dtype).reshape(height - 1, width)
    tl = np.asarray(tl, dtype).reshape(max(height - 2, 0), width)
    out = np.roll(tx, 1, axis=1) - tx  # +t at q = right of p, -t at p
    out[1:] += ty
    out[:-1] -= ty
    out[1:-1] += np.roll(tl, 1, axis=1) + np.roll(tl, -1, axis=1) - 4 * tl
    out[:-2] += tl
    out[2:] += tl
    return out


class TorchStencilOperator:
    """``StencilNormalOperator`` in torch (float64) on any device: the same array shifts, for the torch CG."""

    def __init__(self, op: StencilNormalOperator, device):
        import torch

        self.height, self.width = op.height, op.width
        t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float64, device=device)  # noqa: E731
        self.wx, self.wy, self.wl, self.d = t(op.wx), t(op.wy), t(op.wl), t(op.d)

    def __matmul__(self, x):
        """A x for x [H*W] float64 -> [H*W]."""
        import torch

        X = x.reshape(self.height, self.width)
        right = torch.roll(X, -1, dims=1)
        tx = self.wx * (right - X)
        ty = self.wy * (X[1:] - X[:-1])
        tl = self.wl * (right[1:-1] + torch.roll(X, 1, dims=1)[1:-1] + X[:-2] + X[2:] - 4 * X[1:-1])
        # the transpose of [Dx; Dy; Lap] applied to (tx, ty, tl), as ``transpose_apply``
        out = torch.roll(tx, 1, dims=1) - tx
        out = out + torch.nn.functional.pad(ty, (0, 0, 1, 0)) - torch.nn.functional.pad(ty, (0, 0, 0, 1))
        if len(tl):
            lap_t = torch.zeros_like(X)
            lap_t[1:-1] += -4 * tl + torch.roll(tl, 1, dims=1) + torch.roll(tl, -1, dims=1)
            lap_t[:-2] += tl
            lap_t[2:] += tl
            out = out + lap_t
        return (out + self.d * X).reshape(-1)
