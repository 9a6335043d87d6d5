"""Point sources: every initialization is a named source returning the same ``PointCloud`` and a report."""

from .registry import SourceSpec, get_source, list_sources, register_source
from .run import check_source, cloud_scale, run_source, uses_seed

__all__ = [
    "SourceSpec",
    "check_source",
    "cloud_scale",
    "get_source",
    "list_sources",
    "register_source",
    "run_source",
    "uses_seed",
]
