"""Checked, atomic file I/O shared by every layer: images, arrays, JSON."""
from .files import atomic_write, read_image, write_image, save_npy, write_json, PanoreconInputError

__all__ = ["atomic_write", "read_image", "write_image", "save_npy", "write_json", "PanoreconInputError"]
