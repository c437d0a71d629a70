"""Small array helpers shared by the core, one helper per job.

Data form: numpy arrays; index arrays are rows into a vertex array of the same part.
"""
from __future__ import annotations

import numpy as np


def concat_indexed(parts) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate (vertices (v_i, ...), indices (f_i, k)) parts into one vertex array and one index
    array whose rows refer to the concatenated vertices (each part's indices offset by the vertices
    before it). Index dtype: int64. At least one part."""
    parts = list(parts)
    counts = np.array([v.shape[0] for v, _ in parts], np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
    vertices = np.concatenate([v for v, _ in parts])
    indices = np.concatenate([np.asarray(f, np.int64) + o for (_, f), o in zip(parts, offsets)])
    return vertices, indices


def segment_ranges(offsets: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Concatenation of arange(o, o + c) for each pair (o, c), vectorised: (sum(counts),) int64."""
    counts = np.asarray(counts, np.int64)
    starts = np.repeat(np.asarray(offsets, np.int64) - (np.cumsum(counts) - counts), counts)
    return np.arange(int(counts.sum()), dtype=np.int64) + starts


def distinct_corners(faces: np.ndarray) -> np.ndarray:
    """(f,) bool: the triangles of faces (f,3) whose three vertex ids differ; the others collapse
    (a weld merged two of their corners) and are dropped."""
    return (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])


#: `compact` marks used vertices in a mask over the span of ids the faces use while that span is
#: at most this many times the faces' corners (a leaf's vertices mostly come from one object);
#: a longer span is sorted instead.
COMPACT_SPAN_FACTOR = 16


def compact(positions: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Keep only the vertices the faces use, in ascending id order. positions (v, ...), faces
    (f,3) int rows into them. Returns (positions of the used vertices, faces (f,3) int32 local to
    them, used (u,) the kept vertex ids)."""
    flat = np.asarray(faces).reshape(-1)
    if flat.size == 0:
        return np.asarray(positions[:0]), np.zeros((0, 3), np.int32), np.zeros(0, np.int64)
    lo = int(flat.min())
    span = int(flat.max()) - lo + 1
    if span > COMPACT_SPAN_FACTOR * flat.shape[0]:
        used, local = np.unique(flat, return_inverse=True)
    else:
        mask = np.zeros(span, bool)
        shifted = flat - lo
        mask[shifted] = True
        used = np.flatnonzero(mask) + lo
        local = (np.cumsum(mask, dtype=np.int32) - 1)[shifted]
    return np.asarray(positions[used]), local.reshape(-1, 3).astype(np.int32), used
