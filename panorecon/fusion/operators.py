"""Sparse difference operators on an H x W ERP grid (flat index r * W + c), wrapping across the seam."""
from __future__ import annotations

import functools

import numpy as np
import scipy.sparse as sp


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
    lap_cols = np.stack([(r * width + (c - 1) % width).ravel(), (r * width + (c + 1) % width).ravel(),
                         ((r - 1) * width + c).ravel(), ((r + 1) * width + c).ravel(), centre], 1)
    indices = np.concatenate([np.stack([hq, hp], 1).ravel(), np.stack([vq, vp], 1).ravel(), lap_cols.ravel(),
                              np.arange(n)]).astype(np.int32)
    data = np.concatenate([np.tile([1.0, -1.0], len(hp) + len(vp)), np.tile([1.0, 1.0, 1.0, 1.0, -4.0], len(centre)),
                           np.ones(n)])
    lengths = np.concatenate([np.full(len(hp) + len(vp), 2), np.full(len(centre), 5), np.ones(n, int)])
    indptr = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    B = sp.csr_matrix((data, indices, indptr), shape=(len(lengths), n))
    row_of_entry = np.repeat(np.arange(len(lengths), dtype=np.int32), lengths)
    return B, row_of_entry
