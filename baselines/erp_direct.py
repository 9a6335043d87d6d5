"""``erp-direct``: the teacher run once on the whole ERP image, no split (the single-image baseline)."""

from __future__ import annotations

import time

from panorecon.sources.builtin import cloud_from_distance


def erp_direct(scene, teacher, views=None, fusion_config=None, view_size=None):
    """the teacher run once on the whole ERP image, no split"""
    t = time.perf_counter()
    erp = teacher.predict_erp(scene)
    seconds = {"teacher": time.perf_counter() - t}
    t = time.perf_counter()
    distance = erp.to_distance()
    pc = cloud_from_distance(scene, distance, None)
    seconds["points"] = time.perf_counter() - t
    return pc, seconds, {"views": 1, "distance": distance, "affine_shift_assumed_zero": erp.affine}
