"""PLY files on plyfile: one ``vertex`` element of scalar properties, written streamed and atomically, read
memory-mapped and checked. ``geometry.PointCloud`` keeps its points here, ``splat/ply.py`` the 3DGS layout."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement, PlyElementParseError, PlyHeaderParseError, PlyListProperty, PlyProperty

from .files import PanoreconInputError, atomic_write

PLY_CHUNK = 1 << 20  # vertices per write: write_ply's extra memory is one chunk of rows, whatever the cloud's size


def write_ply(path: str | os.PathLike, columns: Sequence[tuple[str, np.ndarray]], comments: Sequence[str] = ()) -> None:
    """Write ``columns`` ((name, [N] array) in file order; float32, int32 or uint8 as stored) as the ``vertex``
    element of a binary little-endian PLY, atomically. plyfile writes the header; the rows are interleaved
    ``PLY_CHUNK`` at a time, so no full copy of the table is made."""
    if not columns:
        raise ValueError("write_ply: no columns")
    n = len(columns[0][1])
    for name, values in columns:
        if np.ndim(values) != 1 or len(values) != n:
            raise ValueError(f"write_ply: column {name!r} has shape {np.shape(values)}; expected ({n},)")
    element = PlyElement("vertex", [PlyProperty(name, np.dtype(v.dtype).str[1:]) for name, v in columns], n)
    header = PlyData([element], byte_order="<", comments=list(comments)).header + "\n"
    row = element.dtype("<")
    with atomic_write(path) as tmp, open(tmp, "wb") as f:
        f.write(header.encode("ascii"))
        for i in range(0, n, PLY_CHUNK):
            data = np.empty(min(PLY_CHUNK, n - i), dtype=row)
            for name, values in columns:
                data[name] = values[i : i + len(data)]
            f.write(data.tobytes())


def read_ply(path: str | os.PathLike, what: str = "point cloud") -> dict[str, np.ndarray]:
    """The ``vertex`` element of a PLY (any plyfile reads: binary of either byte order or ASCII; other elements,
    such as faces, are read and dropped) -> name -> [N] array of each scalar property, in file order, in native
    byte order and the file's type (copies: binary data is memory-mapped while read, never held twice).

    Checked: the file exists, its header parses, it has N > 0 vertices with x, y, z, every row is there, and a
    binary file without list properties ends where its header says. A bad file raises ``PanoreconInputError``
    naming it (``what``: what the file is, for the message)."""
    path = Path(path)
    if not path.is_file():
        raise PanoreconInputError(f"{what} {path}: no such file")
    try:
        ply = PlyData.read(str(path), mmap="c")
    except PlyHeaderParseError as e:
        raise PanoreconInputError(
            f"{what} {path}: not a PLY file ({e}; expected a 'ply' header ending in end_header)"
        ) from None
    except PlyElementParseError as e:
        if e.message != "early end-of-file":
            raise PanoreconInputError(f"{what} {path}: corrupt PLY data ({e})") from None
        with open(path, "rb") as f:
            rows = "data lines" if b"\nformat ascii" in f.read(4096) else "complete rows"
        raise PanoreconInputError(
            f"{what} {path}: truncated: {e.row} {rows} for the {e.element.count} {e.element.name} rows its header "
            "announces (cut-off or corrupt file)"
        ) from None
    except (ValueError, OSError, UnicodeDecodeError) as e:
        raise PanoreconInputError(f"{what} {path}: not a readable PLY file ({e})") from None
    if "vertex" not in ply or ply["vertex"].count <= 0:
        raise PanoreconInputError(
            f"{what} {path}: the PLY header has no vertices; expected 'element vertex N' with N > 0"
        )
    vertex = ply["vertex"]
    names = [p.name for p in vertex.properties if not isinstance(p, PlyListProperty)]
    missing = [k for k in ("x", "y", "z") if k not in names]
    if missing:
        raise PanoreconInputError(
            f"{what} {path}: its vertices have no x, y, z properties (missing: {', '.join(missing)})"
        )
    last = ply.elements[-1].data
    if isinstance(last, np.memmap):  # binary, every element of fixed-size rows: the file's size is known
        expected, actual = last.offset + last.nbytes, path.stat().st_size
        if actual != expected:
            raise PanoreconInputError(
                f"{what} {path}: {actual} bytes, expected {expected} for the {vertex.count} vertices its header "
                "announces (data after the last row: corrupt file)"
            )
    return {name: np.array(vertex[name], dtype=vertex[name].dtype.newbyteorder("=")) for name in names}
