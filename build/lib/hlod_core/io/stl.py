"""STL files, read here rather than by pymeshlab, whose STL reader loops without end on some
truncated or zero-filled files (docs/how-it-works.md#why-obj-and-stl-files-are-checked-before-pymeshlab-reads-them).

Data form: a file in; positions (v,3) float32 and faces (f,3) int64 out, corners at bit-identical
positions welded into one vertex; InputError naming the file (and the line, for text) at fault.
Binary STL: an 80-byte header, a uint32 triangle count, 50 bytes per triangle, so exactly
84 + 50 n bytes. ASCII STL: solid / facet ... outer loop / 3 x vertex / endloop / endfacet / endsolid.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from .text_numbers import parse_numbers

#: Binary STL: an 80-byte header, a little-endian uint32 triangle count, 50 bytes per triangle.
STL_HEADER_BYTES = 80
STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])


def read_stl(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Binary STL when the size is 84 + 50 n for the n its header gives; otherwise ASCII text
    (solid / facet ... outer loop / 3 x vertex / endloop / endfacet / endsolid). Coordinates are
    float32, as the format defines them; corners at bit-identical positions become one vertex."""
    data = path.read_bytes()
    size = len(data)
    claimed = int.from_bytes(data[STL_HEADER_BYTES:STL_HEADER_BYTES + 4], "little") if size >= 84 else None
    binary_size = None if claimed is None else STL_HEADER_BYTES + 4 + STL_RECORD.itemsize * claimed
    if size == binary_size:
        records = np.frombuffer(data, STL_RECORD, count=claimed, offset=STL_HEADER_BYTES + 4)
        corners = records["corners"].reshape(-1, 3)
    elif re.match(rb"\s*solid(\s|$)", data[:1024]) and _is_text(data):
        corners = _ascii_stl_corners(path, data)
    else:
        binary = "" if claimed is None else f"; a binary STL whose header gives {claimed} triangles has {binary_size}"
        raise InputError(f"{path}: not an STL file ({size} bytes{binary}; an ASCII STL is text starting with 'solid')")
    if corners.shape[0] == 0:
        raise InputError(f"{path}: the mesh has no triangles")
    corners = corners.astype(np.float32) + np.float32(0.0)  # -0.0 -> 0.0, so both weld
    keys = np.ascontiguousarray(corners).view(np.dtype((np.void, 12))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")  # vertices in the order the file first uses them
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return corners[first[order]], rank[inverse.reshape(-1)].reshape(-1, 3)


def _is_text(data: bytes) -> bool:
    """No control bytes other than tab, CR, LF (binary STL floats nearly always hold some)."""
    byte = np.frombuffer(data, np.uint8)
    return not np.any((byte < 32) & (byte != 9) & (byte != 10) & (byte != 13))


_STL_VERTEX = re.compile(rb"(?m)^[ \t]*vertex[ \t]+(\S+[ \t]+\S+[ \t]+\S+)[ \t]*\r?$")
_STL_VERTEX_FAST = re.compile(rb"vertex[ \t]+(\S+[ \t]+\S+[ \t]+\S+)[ \t]*(?:\r?\n|$)")


def _ascii_stl_corners(path: Path, data: bytes) -> np.ndarray:
    """(3f, 3) float64 corners of an ASCII STL; InputError naming the line of the first fault."""
    end = data.rfind(b"endsolid")
    if end < 0 or data[data.rfind(b"\n", 0, end) + 1:end].strip():
        raise InputError(f"{path}: ASCII STL without 'endsolid' (truncated?)")
    coords = _STL_VERTEX_FAST.findall(data)  # literal-first patterns: fast; checked against counts
    facets = data.count(b"facet") - 2 * data.count(b"endfacet")  # 'endfacet' holds 'facet'
    if not (len(coords) == data.count(b"vertex") == 3 * facets and facets == data.count(b"endfacet")):
        coords = _check_stl_lines(path, data)  # line by line, naming the first fault
    values = parse_numbers(b" ".join(coords), np.float64, 3 * len(coords))
    if values is None:
        for m in _STL_VERTEX.finditer(data):
            try:
                [float(x) for x in m.group(1).split()]
            except ValueError:
                line = data.count(b"\n", 0, m.start()) + 1
                raise InputError(f"{path}: line {line}: vertex coordinates are not numbers") from None
    return values.reshape(-1, 3)


def _check_stl_lines(path: Path, data: bytes) -> list:
    """The vertex coordinates of an ASCII STL, read line by line; InputError naming the line of
    the first vertex without three coordinates or facet without three vertices."""
    def line_of(pos: int) -> int:
        return data.count(b"\n", 0, pos) + 1

    coords = _STL_VERTEX.findall(data)
    vertex_lines = re.compile(rb"(?m)^[ \t]*vertex\b")
    if len(coords) != len(vertex_lines.findall(data)):
        bad = next(m for m in vertex_lines.finditer(data) if not _STL_VERTEX.match(data, m.start()))
        raise InputError(f"{path}: line {line_of(bad.start())}: a vertex needs three coordinates")
    facet_lines, end_lines = re.compile(rb"(?m)^[ \t]*facet\b"), re.compile(rb"(?m)^[ \t]*endfacet\b")
    facet_at = [m.start() for m in facet_lines.finditer(data)]
    if len(coords) != 3 * len(facet_at) or len(facet_at) != len(end_lines.findall(data)):
        vertex_at = [m.start() for m in vertex_lines.finditer(data)]
        per_facet = np.bincount(np.searchsorted(facet_at, vertex_at, side="right") - 1,
                                minlength=len(facet_at))[:len(facet_at)] if facet_at else np.zeros(0, np.int64)
        wrong = np.flatnonzero(per_facet != 3)
        where = f"line {line_of(facet_at[wrong[0]])}: a facet with {per_facet[wrong[0]]} vertices" if wrong.size \
            else "facet and endfacet lines do not pair up"
        raise InputError(f"{path}: {where} (an STL facet is one triangle)")
    return coords
