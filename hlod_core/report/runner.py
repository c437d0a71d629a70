"""Run one traversal method over a camera path and average its counters (the `run` command).

Data form: in, a camera path and a method name; out, a dict of per-frame means, one float per
name in traversal.COUNTERS and QUERY_COUNTERS, plus "frames"; under a GPU budget also the means of
STREAM_COUNTERS and the streaming summary (`streaming_summary`), and with compare_unlimited the
frames' luminance PSNR against the same method without a budget.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from ..core.png import write_png
from ..io.textures import load_images
from ..model.camera_path import CameraPath
from ..model.hierarchy import Hlod
from ..render.renderer import Renderer
from ..render.residency import StreamingSettings
from ..traversal.methods import make
from ..traversal.settings import RuntimeSettings
from ..traversal.stats import COUNTERS, QUERY_COUNTERS, STREAM_COUNTERS, FrameStats
from .image_error import psnr

MS_PER_S = 1e3
#: Frames left out of the comparison with an unlimited budget: the first ones load the view's nodes.
COMPARE_AFTER_FRAMES = 10


def run_path(hlod: Hlod, method: str, settings: RuntimeSettings, *, path: CameraPath, size: tuple[int, int],
             renderer: Renderer | None = None, save_frames: str | os.PathLike | None = None,
             streaming: StreamingSettings | None = None, compare_unlimited: bool = False,
             started_s: float | None = None) -> dict:
    """Per-frame means of every counter, plus "frames". Uses `renderer` or a standalone one (with the
    HLOD's texture images, textures.load_images) under `streaming`'s GPU budget. compare_unlimited:
    the path is first drawn without a budget, and each frame's PSNR-Y against that frame is
    summarised. started_s: time.perf_counter() when the file was opened, so `first_frame_ms` counts
    the opening too (else it counts from the renderer's creation)."""
    reference = _unlimited_frames(hlod, method, settings, path, size) if compare_unlimited else None
    own = renderer is None
    started = time.perf_counter() if started_s is None else started_s
    renderer = renderer or Renderer.create_standalone(hlod, size, images=load_images(hlod), streaming=streaming)
    psnr_y: list[float] = []
    try:
        traversal = make(method, hlod, renderer, settings=settings)
        stats: list[FrameStats] = []
        for i in range(len(path)):
            stats.append(traversal.frame(path.view(i, size)))
            if i == 0:
                first_frame_ms = (time.perf_counter() - started) * MS_PER_S
            if save_frames is not None or reference is not None:
                pixels = renderer.read_pixels()
                if save_frames is not None:
                    write_png(Path(save_frames) / f"{method}_{i:05d}.png", pixels)
                if reference is not None:
                    psnr_y.append(float(psnr(pixels, reference[i])[0]))
        summary = streaming_summary(renderer, stats, first_frame_ms=first_frame_ms)
    finally:
        if own:
            renderer.release()
    out = {name: float(np.mean([getattr(s, name) for s in stats])) for name in COUNTERS + QUERY_COUNTERS}
    if renderer.residency is not None:
        out.update({name: float(np.mean([getattr(s, name) for s in stats])) for name in STREAM_COUNTERS})
    out["frames"] = len(stats)
    out.update(summary)
    if reference is not None:
        later = psnr_y[COMPARE_AFTER_FRAMES:]
        out["psnr_y_vs_unlimited_median"] = float(np.median(later)) if later else None
        out["psnr_y_vs_unlimited_min"] = float(np.min(later)) if later else None
        out["compared_frames"] = len(later)
        out["frame_ms_unlimited_median"] = reference.frame_ms_median
    return out


def streaming_summary(renderer: Renderer, stats: list[FrameStats], *, first_frame_ms: float) -> dict:
    """The GPU budget's summary of a run, node geometry and textures counted together:
    gpu_budget_bytes (0: unlimited), gpu_resident_bytes_peak, uploaded_bytes (the start's uploads
    included), ancestor_substitutions (over all frames), upload_ms_max (the most a frame spent on
    evictions and uploads) and first_frame_ms."""
    residency = renderer.residency
    if residency is None:
        whole = renderer.gpu_bytes
        return {"gpu_budget_bytes": 0, "gpu_resident_bytes_peak": whole, "uploaded_bytes": whole,
                "ancestor_substitutions": 0, "upload_ms_max": 0.0, "first_frame_ms": first_frame_ms}
    return {"gpu_budget_bytes": residency.settings.budget_bytes,
            "gpu_resident_bytes_peak": residency.resident_bytes_peak,
            "uploaded_bytes": residency.uploaded_bytes,
            "ancestor_substitutions": int(sum(s.substitutions for s in stats)),
            "upload_ms_max": float(max((s.upload_ms for s in stats), default=0.0)),
            "first_frame_ms": first_frame_ms}


class _Frames(list):
    """The frames of an unlimited run, (H, W, 3) uint8 each, and its median frame time."""

    frame_ms_median = 0.0


def _unlimited_frames(hlod: Hlod, method: str, settings: RuntimeSettings, path: CameraPath,
                      size: tuple[int, int]) -> _Frames:
    renderer = Renderer.create_standalone(hlod, size, images=load_images(hlod))
    frames, times = _Frames(), []
    try:
        traversal = make(method, hlod, renderer, settings=settings)
        for i in range(len(path)):
            times.append(traversal.frame(path.view(i, size)).frame_ms)
            frames.append(renderer.read_pixels())
    finally:
        renderer.release()
    frames.frame_ms_median = float(np.median(times))
    return frames
