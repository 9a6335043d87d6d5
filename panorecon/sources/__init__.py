"""Point sources: every initialization is a named source returning the same ``PointCloud`` and a report."""

from .registry import SourceSpec, get_source, list_sources, register_source
from .run import EmptyCloudError, check_source, cloud_scale, run_source, uses_seed

__all__ = [
    "EmptyCloudError",
    "SourceSpec",
    "check_source",
    "cloud_scale",
    "get_source",
    "list_sources",
    "register_source",
    "run_source",
    "uses_seed",
]
