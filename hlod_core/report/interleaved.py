"""The timed run of the evaluation and of the tuning: variants of the traversal over one camera path
on one renderer, interleaved frame by frame (each keeps its own traversal state; the order rotates
every frame and runs backwards on odd repeats), so a drift in the machine's speed (on a shared VM,
tens of percent over minutes) hits them alike and timings compare as ratios within the run.

Data form: per_frame[key] is a (repeat, frames, len(COUNTERS)) float64 array of FrameStats counters
(traversal.COUNTERS order) per variant key; images[key][frame] an (H, W, 3) uint8 read-back of the
first repeat at the PSNR frames, taken outside the timed frame; costs[key] a (repeat, frames,
len(draw_cost.COLUMNS)) float64 array of each frame's draws and texture bytes, counted from the drawn
nodes outside the timed frame (`draw_cost`).
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from ..model.camera_path import CameraPath
from ..model.hierarchy import Hlod
from ..render.renderer import Renderer
from ..traversal.methods import make
from ..traversal.settings import RuntimeSettings
from ..traversal.stats import COUNTERS
from .draw_cost import COLUMNS, DrawCost

log = logging.getLogger(__name__)

PROGRESS_STEPS = 10  # log lines per repeat


@dataclass(frozen=True)
class Variant:
    """One timed configuration: a report key (a method key, or "coh_p tau=2" in a sweep)."""

    key: str
    method: str
    settings: RuntimeSettings
    sweep_value: object = None


def psnr_frame_indices(frames: int, count: int, seed: int) -> list[int]:
    """The seeded PSNR frames: `count` distinct frame indices of a `frames`-frame path (all of them
    when count >= frames), ascending."""
    rng = np.random.default_rng(seed)
    return sorted(rng.choice(frames, size=min(count, frames), replace=False).tolist())


def run_interleaved(hlod: Hlod, renderer: Renderer, path: CameraPath, *, size: tuple[int, int], runs: list[Variant],
                    repeat: int, picked: list[int], started: float, label: str = "",
                    draw_cost: DrawCost | None = None, costs: dict | None = None,
                    notes: dict | None = None) -> tuple[dict, dict]:
    """One timed pass of `runs` over the path, `repeat` times, interleaved (module docstring).
    Returns (per_frame, images) of the module docstring, images at the `picked` frames. `started`
    (a perf_counter time) dates the progress lines, `label` prefixes them. With `draw_cost`, the
    dict `costs` gets costs[key] of the module docstring; `notes`, where given, gets key -> why the
    variant's queries were last off (FrameStats.queries_note) in the first repeat."""
    frames = len(path)
    picked_set = set(picked)
    per_frame = {v.key: np.zeros((repeat, frames, len(COUNTERS))) for v in runs}
    images: dict[str, dict[int, np.ndarray]] = {v.key: {} for v in runs}
    if draw_cost is not None:
        costs.update({v.key: np.zeros((repeat, frames, len(COLUMNS))) for v in runs})
    for rep in range(repeat):
        traversals = [(v, make(v.method, hlod, renderer, settings=v.settings)) for v in runs]
        for i in range(frames):
            view = path.view(i, size)
            turn = traversals[i % len(traversals):] + traversals[:i % len(traversals)]
            for v, traversal in (turn if rep % 2 == 0 else turn[::-1]):
                stats = traversal.frame(view)
                per_frame[v.key][rep, i] = [getattr(stats, c) for c in COUNTERS]
                if draw_cost is not None:
                    costs[v.key][rep, i] = draw_cost.frame(stats.drawn)
                if notes is not None and rep == 0 and stats.queries_note:
                    notes[v.key] = stats.queries_note
                if rep == 0 and i in picked_set:
                    images[v.key][i] = renderer.read_pixels()
            if (i + 1) % max(frames // PROGRESS_STEPS, 1) == 0 or i + 1 == frames:
                log.info("%srepeat %d/%d: frame %d/%d (%.0f s)", label, rep + 1, repeat, i + 1, frames,
                         time.perf_counter() - started)
    return per_frame, images
