"""The report's modulation showcase (dissertation Figs. 8.1-8.3): Bool, Coh(P) and Coh(mu) at one
frame of the path, shaded, in modulation colours from the user's view, and their drawn front in
modulation colours from a bird's-eye view.

Data form: in, the evaluation's variants and per-frame counters ((repeat, frames, len(COUNTERS))
float64 per report key); out, PNG files in the report folder and a dict {"frame", "eye_px" (the
eye projected into the bird's-eye image, pixels), "images": {key: {"shaded", "modulation",
"birdseye": file name, "dn"}}, "default_colour"}.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.colour import modulation_colour
from ..core.png import write_png
from ..model.camera_path import CameraPath
from ..model.hierarchy import Hlod
from ..model.view import View, look_at, orthographic
from ..render.renderer import DEFAULT_COLOUR, Renderer
from ..traversal.methods import make
from ..traversal.stats import COUNTERS

SHOWN_KEYS = ("bool", "coh_p", "coh_mu")
# bird's-eye framing, relative to the root box: the picture's height over the box's extent, the
# eye's lift above the box top and the near plane (fractions of the picture height and of the far
# distance), the far distance in box depths plus a margin (fraction of the picture height)
_BIRD_FRAME_MARGIN = 1.05
_BIRD_MIN_EXTENT = 1e-9  # model units: a flat or empty root box still gets a picture
_BIRD_EYE_LIFT = 1e-3
_BIRD_FAR_DEPTHS = 3.0
_BIRD_FAR_MARGIN = 1e-2
_BIRD_NEAR_OF_FAR = 1e-3


def bird_view(hlod: Hlod, size: tuple[int, int], up_axis: int = 2) -> View:
    """Orthographic view straight down the up axis onto the root box, all of it in the picture."""
    lo, hi = hlod.box_min[0], hlod.box_max[0]
    centre = 0.5 * (lo + hi)
    a, b = [ax for ax in range(3) if ax != up_axis]
    w, h = size
    extent_a, extent_b = hi[a] - lo[a], hi[b] - lo[b]
    height = _BIRD_FRAME_MARGIN * max(extent_b, extent_a * h / w, _BIRD_MIN_EXTENT)
    depth = hi[up_axis] - lo[up_axis]
    eye = centre.copy()
    eye[up_axis] = hi[up_axis] + depth + _BIRD_EYE_LIFT * height
    up = np.zeros(3)
    up[b] = 1.0
    far = _BIRD_FAR_DEPTHS * depth + _BIRD_FAR_MARGIN * height
    return View(eye=eye, view=look_at(eye, centre, up),
                projection=orthographic(height, w / h, near=_BIRD_NEAR_OF_FAR * far, far=far), width=w, height=h)


def draw_nodes(renderer: Renderer, view: View, *, nodes, colours) -> np.ndarray:
    """One untimed frame of `nodes` (n,) in `colours` (n, 3) linear RGB; its (H, W, 3) uint8 image."""
    renderer.begin_frame(view, time_gpu=False)
    for node, colour in zip(nodes, colours):
        renderer.draw_node_coloured(int(node), colour)
    renderer.end_frame()
    return renderer.read_pixels()


def modulation_frames(hlod: Hlod, renderer: Renderer, *, path: CameraPath, size: tuple[int, int], runs: list,
                      per_frame: dict, out_dir: Path) -> dict | None:
    """At the frame where Coh(P) saves the most nodes over Bool (else the middle frame), the
    images of Bool, Coh(P) and Coh(mu): shaded, modulation-coloured from the user's view, and the
    drawn front modulation-coloured from a bird's-eye view. Untimed reruns of the path up to it.
    `runs`: the evaluation's variants (`.key`, `.method`, `.settings`)."""
    by_key = {v.key: v for v in runs}
    shown = [k for k in SHOWN_KEYS if k in by_key]
    if not shown:
        return None
    dn = COUNTERS.index("dn")
    frame = len(path) // 2
    if "bool" in by_key and "coh_p" in by_key:
        saving = np.median(per_frame["bool"][:, :, dn], 0) - np.median(per_frame["coh_p"][:, :, dn], 0)
        frame = int(np.argmax(saving))
    bird = bird_view(hlod, size)
    eye_px = _project(bird, path.view(frame, size).eye)
    files = {}
    for key in shown:
        v = by_key[key]
        traversal = make(v.method, hlod, renderer, settings=v.settings)
        for i in range(frame + 1):
            stats = traversal.frame(path.view(i, size))
        shaded = renderer.read_pixels()
        colours = modulation_colour(traversal.modulation(stats.drawn))
        user = draw_nodes(renderer, path.view(frame, size), nodes=stats.drawn, colours=colours)
        above = draw_nodes(renderer, bird, nodes=stats.drawn, colours=colours)
        files[key] = {}
        for name, image in (("shaded", shaded), ("modulation", user), ("birdseye", above)):
            files[key][name] = write_png(out_dir / f"{key}_{name}.png", image).name
        files[key]["dn"] = stats.dn
    return {"frame": frame, "eye_px": eye_px, "images": files, "default_colour": list(DEFAULT_COLOUR)}


def _project(view: View, point) -> list[float]:
    """[x, y] pixels of a world point in `view`, top row 0."""
    clip = view.projection @ view.view @ np.append(point, 1.0)
    ndc = clip[:2] / clip[3]
    return [float((ndc[0] + 1) / 2 * view.width), float((1 - ndc[1]) / 2 * view.height)]
