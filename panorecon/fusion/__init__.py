"""Multi-view depth -> one panoramic ray-distance map: the §2.4 log-depth least squares. (MoGe's own merge,
the peer method it is measured against, is the ``moge-merge`` plug-in in the top-level ``baselines`` package.)"""

from .lsq import FusionConfig, FusionOptions, FusionResult, fuse_views, pyramid_heights

__all__ = ["FusionConfig", "FusionOptions", "FusionResult", "fuse_views", "pyramid_heights"]
