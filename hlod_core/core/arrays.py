"""Small array helpers shared by the core (STYLE: one helper per job).

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
