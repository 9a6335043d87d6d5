"""Which views a fusion can tie together: the overlap graph of the views' valid depth on a coarse ERP grid.

Two views are linked when at least ``min_overlap`` ERP rays of a ``height`` x 2*height grid fall inside both
and have valid depth in both. Views in different connected components share no equation of the fusion: their
relative scale (and, for affine teachers, shift) is not measured but guessed, so such a result is flagged.
A view with fewer than ``min_overlap`` valid rays (one that sees only sky, say) adds nothing to the fusion and
cannot misplace anything: it is listed as empty, not as a group of its own.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
from scipy.sparse.csgraph import connected_components

from ..geometry import ViewDepth, erp_directions
from .warp import project_erp_rays

log = logging.getLogger("panorecon.fusion")


def view_connectivity(views: Sequence[ViewDepth], height: int = 64, min_overlap: int = 16) -> dict:
    """-> {"components": int, "groups": [[view index, ...], ...] largest first, "unconnected_views": views
    outside the largest group, "empty_views": views with fewer than ``min_overlap`` valid rays (in no group),
    "pairs": linked pairs, "min_overlap": min_overlap, "grid_height": height}."""
    V = len(views)
    dirs = erp_directions(height, 2 * height).reshape(-1, 3)
    seen = np.zeros((V, len(dirs)), bool)
    for i, v in enumerate(views):
        idx, rows, cols, _ = project_erp_rays(v.camera, dirs)
        d = v.depth[rows, cols]
        seen[i, idx[v.valid[rows, cols] & np.isfinite(d)]] = True
    active = np.flatnonzero(seen.sum(1) >= min_overlap)
    counts = seen[active].astype(np.int32) @ seen[active].T.astype(np.int32)  # shared valid rays
    linked = counts >= min_overlap
    np.fill_diagonal(linked, False)
    n, label = connected_components(linked, directed=False) if len(active) else (0, active)
    groups = sorted(
        ([int(active[i]) for i in np.flatnonzero(label == c)] for c in range(n)), key=lambda g: (-len(g), g)
    )
    return {
        "components": int(n),
        "groups": groups,
        "unconnected_views": sorted(i for g in groups[1:] for i in g),
        "empty_views": sorted(set(range(V)) - {int(i) for i in active}),
        "pairs": int(np.triu(linked).sum()),
        "min_overlap": min_overlap,
        "grid_height": height,
    }


def connectivity_warning(conn: dict) -> str | None:
    """One line for a result whose views do not all connect, or None."""
    if conn["components"] <= 1:
        return None
    return (
        f"the views do not connect ({conn['components']} groups {conn['groups']} with no overlap of "
        f">= {conn['min_overlap']} valid rays): their relative depth scale is unmeasured, the fused depth "
        "is unreliable; use more views or a wider field of view"
    )


def check_connectivity(views: Sequence[ViewDepth]) -> dict:
    """``view_connectivity`` plus a logged warning (and ``warning`` in the dict) when the views do not connect."""
    conn = view_connectivity(views)
    warning = connectivity_warning(conn)
    if warning:
        conn["warning"] = warning
        log.warning(warning)
    return conn
