"""Metrics against the truth: depth (AbsRel, RMSE, δ1, the flying share, and their solid-angle-weighted ERP
versions), points (accuracy, completeness, Chamfer, F-score), LPIPS (AlexNet v0.1 with converted weights,
``lpips_weights``), the panorama seam score, WS-PSNR and WS-SSIM for ERP images (``panorama``) and scores after a
per-view colour alignment (``aligned``); the trainer's PSNR and SSIM live with its losses and are checked against
scikit-image."""

from .depth import depth_metrics, edge_depth_metrics, point_flying_share, ws_depth_metrics
from .points import point_metrics

__all__ = ["depth_metrics", "edge_depth_metrics", "point_flying_share", "point_metrics", "ws_depth_metrics"]
