"""3D Gaussian Splatting (paper §2.3, §2.5): the rasterizer with its backends (``rasterize/``: the pure-PyTorch
reference, the C++ ``cpu`` kernels, gsplat on CUDA), the Gaussian model and its 3DGS PLY, losses, pseudo-labels and
held-out views, the initial cloud and sky environment, densify/prune strategies (3DGS and the adaptive pruning),
checkpoints and the trainer."""
