"""per_frame.npz, the per-frame medians an evaluation keeps beside its report.json so that its
figures can be drawn again: "keys" (V,) report keys, "counters" (C,) counter names (traversal
COUNTERS), "median" (V, frames, C) float32 medians over repeats; and, from evaluations that count
them, "cost_columns" (draw_cost.COLUMNS) and "cost_median" (V, frames, 2) float64, each frame's draws
and texture bytes (`load_costs`). Written atomically, read without pickle.
"""
from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from ..core.atomic import atomic_file
from ..core.errors import InputError
from ..traversal.stats import COUNTERS, LATER_COUNTERS
from .draw_cost import COLUMNS

PER_FRAME_FILE = "per_frame.npz"


def save_per_frame(target: Path, medians: dict, *, costs: dict | None = None) -> None:
    """per_frame.npz (module docstring) of `medians`: report key -> (frames, len(COUNTERS)); `costs`:
    report key -> (frames, len(draw_cost.COLUMNS)), every key of `medians`."""
    keys = list(medians)
    extra = {}
    if costs is not None:
        extra = {"cost_columns": np.array(COLUMNS, dtype=str), "cost_median": np.array([costs[k] for k in keys])}
    with atomic_file(target) as f:
        np.savez_compressed(f, keys=np.array(keys, dtype=str), counters=np.array(COUNTERS, dtype=str),
                            median=np.array([medians[k] for k in keys], dtype=np.float32), **extra)


def load_costs(source: Path) -> dict:
    """report key -> {column of draw_cost.COLUMNS: (frames,) float64} from per_frame.npz; empty when
    the file has none (an evaluation made before they were counted)."""
    with np.load(source, allow_pickle=False) as data:
        if "cost_median" not in data.files:
            return {}
        keys, columns, median = data["keys"].tolist(), data["cost_columns"].tolist(), data["cost_median"]
    return {str(k): {c: median[i][:, columns.index(c)].astype(np.float64) for c in COLUMNS} for i, k in enumerate(keys)}


def load_per_frame(source: Path, *, frames: int | None = None) -> dict:
    """report key -> (frames, len(COUNTERS)) float64 medians from per_frame.npz, in COUNTERS order
    whatever order the file lists its counters in. Raises InputError naming the file when it is not
    one (or holds another number of frames than `frames`, the report's)."""
    try:
        with np.load(source, allow_pickle=False) as data:
            keys, counters, median = data["keys"], data["counters"], data["median"]
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise InputError(f"{source}: not an evaluation's per-frame file ({exc})") from None
    names = counters.tolist()
    missing = [c for c in COUNTERS if c not in names and c not in LATER_COUNTERS]
    if median.ndim != 3 or median.shape[0] != len(keys) or median.shape[2] != len(counters) or missing:
        raise InputError(f"{source}: not an evaluation's per-frame file (median {median.shape}, "
                         f"{len(keys)} keys, counters missing: {', '.join(missing) or 'none'})")
    if frames is not None and median.shape[1] != frames:
        raise InputError(f"{source}: {median.shape[1]} frames, its report.json {frames}")
    out = {}
    for i, k in enumerate(keys):
        columns = [median[i][:, names.index(c)] if c in names else np.full(median.shape[1], LATER_COUNTERS[c])
                   for c in COUNTERS]
        out[str(k)] = np.stack(columns, axis=1).astype(np.float64)
    return out
