"""Multi-view depth -> one panoramic ray-distance map: the §2.4 log-depth least squares, and the
MoGe-style reference merge it is measured against."""
from .lsq import FusionConfig, FusionResult, fuse_views, pyramid_heights
from .moge import moge_merge

__all__ = ["FusionConfig", "FusionResult", "fuse_views", "moge_merge", "pyramid_heights"]
