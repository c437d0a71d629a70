"""Run one traversal method over a camera path and average its counters (the `run` command).

Data form: in, a camera path and a method name; out, a dict of per-frame means, one float per
name in traversal.COUNTERS and QUERY_COUNTERS, plus "frames".
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..core.png import write_png
from ..io.textures import load_images
from ..model.camera_path import CameraPath
from ..model.hierarchy import Hlod
from ..render.renderer import Renderer
from ..traversal.methods import make
from ..traversal.settings import RuntimeSettings
from ..traversal.stats import COUNTERS, FrameStats, QUERY_COUNTERS


def run_path(hlod: Hlod, method: str, settings: RuntimeSettings, *, path: CameraPath, size: tuple[int, int],
             renderer: Renderer | None = None, save_frames: str | os.PathLike | None = None) -> dict:
    """Per-frame means of every counter, plus "frames". Uses `renderer` or a standalone one (with the
    HLOD's texture images, io.textures.load_images); `save_frames`: a folder for every frame as PNG."""
    own = renderer is None
    renderer = renderer or Renderer.create_standalone(hlod, size, images=load_images(hlod))
    try:
        traversal = make(method, hlod, renderer, settings=settings)
        stats: list[FrameStats] = []
        for i in range(len(path)):
            stats.append(traversal.frame(path.view(i, size)))
            if save_frames is not None:
                write_png(Path(save_frames) / f"{method}_{i:05d}.png", renderer.read_pixels())
    finally:
        if own:
            renderer.release()
    out = {name: float(np.mean([getattr(s, name) for s in stats])) for name in COUNTERS + QUERY_COUNTERS}
    out["frames"] = len(stats)
    return out
