"""The shared pipeline: cached stages (scene -> points -> train) that ``panorecon ablate`` runs row by row."""

from .cache import StageCache, code_digest, stage_key
from .stages import Row, run_points, run_train, teacher_depth_fn

__all__ = ["StageCache", "code_digest", "stage_key", "Row", "run_points", "run_train", "teacher_depth_fn"]
