"""panorecon: text or 360° panorama -> 3D Gaussian Splatting scene, with honest initialization ablations."""

__version__ = "0.1.0"
