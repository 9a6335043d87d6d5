"""Checked, atomic file I/O shared by every layer: images, arrays, JSON; and the process's peak memory."""

from .files import (
    PanoreconInputError,
    atomic_write,
    atomic_write_all,
    file_sha256,
    json_text,
    quiet_native_stderr,
    read_image,
    save_npy,
    write_image,
    write_json,
)
from .process import memory_budget_mb, peak_rss_mb, reset_peak_rss, window_peak_rss_mb

__all__ = [
    "atomic_write",
    "atomic_write_all",
    "file_sha256",
    "json_text",
    "quiet_native_stderr",
    "read_image",
    "write_image",
    "save_npy",
    "write_json",
    "PanoreconInputError",
    "memory_budget_mb",
    "peak_rss_mb",
    "reset_peak_rss",
    "window_peak_rss_mb",
]
