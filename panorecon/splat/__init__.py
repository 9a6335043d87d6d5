"""3D Gaussian Splatting: projection and rasterization (a pure-PyTorch reference so far)."""
