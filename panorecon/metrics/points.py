"""Point-cloud metrics against a true cloud, with SciPy KD-trees (exact nearest neighbours).

accuracy: mean distance from each predicted point to its nearest true point (metres);
completeness: mean distance from each true point to its nearest predicted point;
chamfer: (accuracy + completeness) / 2; fscore: harmonic mean of precision (share of predicted points
within ``threshold`` of the truth) and recall (share of true points within ``threshold`` of the prediction).
Clouds larger than ``max_points`` are subsampled uniformly at random with a fixed seed first.
"""

from __future__ import annotations

import numpy as np


def nearest_distances(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Distance from every point of src [N, 3] to its nearest point of dst [M, 3] (metres), [N] float64."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(np.asarray(dst, np.float64)).query(np.asarray(src, np.float64), k=1, workers=-1)
    return d


def _subsample(xyz: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    return xyz if len(xyz) <= n else xyz[rng.choice(len(xyz), n, replace=False)]


def point_metrics(
    pred: np.ndarray, truth: np.ndarray, threshold: float = 0.05, max_points: int = 200_000, seed: int = 0
) -> dict:
    """pred [N, 3], truth [M, 3] in metres -> count, accuracy, completeness, chamfer, fscore, threshold."""
    if len(pred) == 0 or len(truth) == 0:
        raise ValueError(f"point_metrics: empty cloud (prediction {len(pred)} points, truth {len(truth)} points)")
    rng = np.random.default_rng(seed)
    p, t = _subsample(pred, max_points, rng), _subsample(truth, max_points, rng)
    d_pt = nearest_distances(p, t)
    d_tp = nearest_distances(t, p)
    precision, recall = float(np.mean(d_pt < threshold)), float(np.mean(d_tp < threshold))
    f = 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)
    acc, comp = float(d_pt.mean()), float(d_tp.mean())
    return {
        "count": int(len(pred)),
        "accuracy": acc,
        "completeness": comp,
        "chamfer": 0.5 * (acc + comp),
        "fscore": f,
        "threshold": threshold,
        "subsampled_to": int(min(len(pred), max_points)),
    }
