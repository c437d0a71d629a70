"""A report's rows from measured counters and images: one row per variant (the dissertation's
Table 8.2 columns, PSNR of Table 8.1), the relative Tables 8.3/8.4, and the run's settings.

Data form: counters (repeat, frames, len(COUNTERS)) float64 per variant; images[key][frame] (H, W,
3) uint8; rows are JSON-ready dicts of floats (None where a figure is missing).
"""
from __future__ import annotations

from dataclasses import asdict

import numpy as np

from ..traversal.settings import RuntimeSettings
from ..traversal.stats import COUNTERS
from .image_error import psnr, rmse_y

SUMMARY_KEYS = ("fps", "frame_ms", "dn", "rarn", "d", "tris", "queries", "stall_ms", "cpu_ms", "gpu_ms", "queries_off")
PSNR_REFERENCES = ("bool", "full")  # the PSNR columns are against these methods' images
MS_PER_S = 1e3


def variant_row(counters: np.ndarray, images: dict, *, key: str, picked: list[int]) -> dict:
    """One variant's row of the report: `counters` (repeat, frames, len(COUNTERS)) -> per frame the
    median over repeats, then the mean over frames of each of SUMMARY_KEYS (and fps; of queries_off,
    the share of frames drawn with the method's queries off, traversal.query_gate); PSNR mean and
    s.d. per channel against each of PSNR_REFERENCES present in `images` (key -> frame -> image), and
    the luminance RMSE against Full, over the `picked` frames (None where the reference is absent)."""
    index = {c: j for j, c in enumerate(COUNTERS)}
    median = np.median(counters, axis=0)  # per frame, over repeats
    row = {c: float(np.mean(median[:, index[c]])) for c in COUNTERS}
    row["fps"] = MS_PER_S / row["frame_ms"] if row["frame_ms"] > 0 else None
    row = {k: row[k] for k in SUMMARY_KEYS} | {"traversed": row["traversed"]}
    for ref in PSNR_REFERENCES:
        values = psnr_against(images, key=key, ref=ref, picked=picked)
        for c, name in enumerate(("y", "cb", "cr")):
            row[f"psnr_{name}_vs_{ref}"] = None if values is None else float(np.mean(values[:, c]))
            row[f"psnr_{name}_vs_{ref}_sd"] = None if values is None else float(np.std(values[:, c]))
    rmse = [rmse_y(images[key][i], images["full"][i]) for i in picked] if "full" in images else None
    row["rmse_y_vs_full"] = None if rmse is None else float(np.mean(rmse))
    return row


def queries_off_by_part(counters: np.ndarray, parts: list[tuple[str, int]]) -> dict:
    """Share of each part's frames with the queries off (per frame the median over repeats): part
    name -> share; `parts` (name, start frame) in order, empty: the whole path as "path"."""
    off = np.median(counters, axis=0)[:, COUNTERS.index("queries_off")]
    parts = list(parts) or [("path", 0)]
    ends = [start for _, start in parts[1:]] + [off.shape[0]]
    return {name: float(np.mean(off[start:end])) if end > start else None for (name, start), end in zip(parts, ends)}


def psnr_against(images: dict, *, key: str, ref: str, picked: list[int]) -> np.ndarray | None:
    """(len(picked), 3) PSNR dB of Y, Cb, Cr of `key`'s images against `ref`'s at the picked frames;
    None when either has no images."""
    if ref not in images or not images[ref] or not images[key]:
        return None
    return np.array([psnr(images[key][i], images[ref][i]) for i in picked])


def relative_tables(methods: dict) -> dict:
    """Tables 8.3/8.4: percent speedup (FPS ratio - 1) and node savings (1 - DN ratio) of Coh(P)
    and Coh(mu) over Bool, Simp and SW of the same bias."""
    out = {}
    for coh, others in (("coh_p", ("bool", "simp_p", "sw_p", "coh_p_alg4")), ("coh_mu", ("bool", "simp_mu", "sw_mu"))):
        if coh not in methods:
            continue
        rows = {}
        for other in others:
            if other in methods:
                a, b = methods[coh], methods[other]
                rows[other] = {"speedup_pct": 100.0 * (a["fps"] / b["fps"] - 1.0),
                               "node_savings_pct": 100.0 * (1.0 - a["dn"] / b["dn"]) if b["dn"] > 0 else None}
        out[coh] = rows
    return out


def settings_json(settings: RuntimeSettings) -> dict:
    """report.json's "settings": every field of the run's RuntimeSettings but the bias (each method
    has its own), k None for inf, so two reports made with different query options tell themselves
    apart."""
    out = {name: value for name, value in asdict(settings).items() if name != "bias"}
    out["k"] = None if np.isinf(settings.k) else settings.k
    return out
