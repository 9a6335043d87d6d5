"""Metrics against the truth: depth (AbsRel, RMSE, δ1), points (accuracy, completeness, Chamfer, F-score), LPIPS
(AlexNet v0.1 with converted weights, ``lpips_weights``) and the panorama seam score; PSNR and SSIM live with the
trainer's losses and are checked against scikit-image."""

from .depth import depth_metrics, edge_depth_metrics
from .points import point_metrics

__all__ = ["depth_metrics", "edge_depth_metrics", "point_metrics"]
