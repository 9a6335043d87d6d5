"""Depth and point-cloud metrics against the truth."""
from .depth import depth_metrics
from .points import point_metrics

__all__ = ["depth_metrics", "point_metrics"]
