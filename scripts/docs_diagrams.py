"""The two pictures that open docs/how-it-works.md, drawn from a real bake and a real frame:

    .venv/bin/python scripts/docs_diagrams.py [--out docs/images]

- `how_bake.png`: the default procedural city (`hlod_core.io.procedural.default_scene`, scale 1, the scene run.sh bakes)
  baked with the default settings: its octree leaves seen from above (each holds at most
  target_tris input triangles), the triangles and nodes per depth (the leaves are the input; each
  inner node is its children's LODs merged and decimated to target_tris), and each node's stored
  error against its depth (never smaller than a child's).
- `how_traversal.png`: one frame of Coh(P) on that bake, from a street-level camera (eye 1.7 m, the
  tests' street walk), seen from above: the nodes drawn in their modulation colour (the overlay's
  ramp over 1 - P), the nodes a query found hidden, and the steps of the loop beside it.

Both need OpenGL only for the frame (EGL; Mesa llvmpipe without a GPU) and matplotlib.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

#: The city's scale (1: the default scene of run.sh, about 217k triangles).
CITY_SCALE = 1.0
#: The street camera of the tests' street walk: eye 1.7 m above the street between the first two
#: columns of buildings, looking along it.
EYE, TARGET, UP = (10.0, -5.0, 1.7), (10.0, 25.0, 4.0), (0.0, 0.0, 1.0)
FRAME_SIZE = (640, 480)
#: Frames drawn from the same camera before the one shown (Coh's predictions settle on the view).
SETTLE_FRAMES = 4
GREY, INK = "#b9b9b9", "#303030"


def bake_city():
    """(mesh, Hlod) of the city at CITY_SCALE, default bake settings (jobs 2)."""
    from hlod_core.bake.pipeline import bake
    from hlod_core.bake.settings import BakeSettings
    from hlod_core.io import procedural

    mesh = procedural.default_scene(seed=1, scale=CITY_SCALE)
    return mesh, bake(mesh, BakeSettings(jobs=2))


class RecordingRenderer:
    """A real renderer with every draw and query result noted: drawn[node] = P, seen[node] = q."""

    def __init__(self, renderer):
        self._renderer = renderer
        self.drawn: dict[int, float] = {}
        self.seen: dict[int, int] = {}

    def __getattr__(self, name):
        return getattr(self._renderer, name)

    def begin_frame(self, view, **kwargs) -> None:
        self.drawn.clear()
        self.seen.clear()
        self._renderer.begin_frame(view, **kwargs)

    def draw_node(self, node: int, ratio_p: float = 1.0) -> None:
        self.drawn[int(node)] = float(ratio_p)
        self._renderer.draw_node(node, ratio_p)

    def result(self, query):
        q, alpha, stall = self._renderer.result(query)
        for node in (query.members or (query.node,)):
            self.seen[int(node)] = int(q)
        return q, alpha, stall


def street_frame(hlod) -> tuple[RecordingRenderer, object]:
    """The recorded last frame of Coh(P) from the street camera: (recorder, FrameStats)."""
    from hlod_core.model.camera_path import CameraPath
    from hlod_core.render.renderer import Renderer
    from hlod_core.traversal.methods import make
    from hlod_core.traversal.settings import RuntimeSettings

    path = CameraPath(frames=np.array([[EYE, TARGET, UP]], float), near=0.05, far=400.0, fovy_deg=60.0)
    renderer = Renderer.create_standalone(hlod, FRAME_SIZE)
    try:
        recorder = RecordingRenderer(renderer)
        traversal = make("coh", hlod, recorder, settings=RuntimeSettings(multiquery="off", skip_queries="off"))
        for _ in range(SETTLE_FRAMES):
            stats = traversal.frame(path.view(0, FRAME_SIZE))
        return recorder, stats
    finally:
        renderer.release()


def _boxes(ax, hlod, nodes, **style) -> None:
    from matplotlib.patches import Rectangle

    for node in nodes:
        lo, hi = hlod.box_min[node], hlod.box_max[node]
        ax.add_patch(Rectangle((lo[0], lo[1]), hi[0] - lo[0], hi[1] - lo[1], **style))


def _top_view(ax, mesh, hlod, title: str) -> None:
    """The input's triangles from above (their centroids, grey) on equal axes."""
    centroids = mesh.positions[mesh.faces].mean(axis=1)
    ax.scatter(centroids[:, 0], centroids[:, 1], s=0.05, c=GREY, linewidths=0, rasterized=True)
    lo, hi = hlod.box_min[0], hlod.box_max[0]
    pad = 0.03 * float(np.max(hi[:2] - lo[:2]))
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=10, loc="left")
    ax.set_xticks([])
    ax.set_yticks([])


def draw_bake(out_dir: Path, mesh, hlod) -> Path:
    """how_bake.png (module docstring)."""
    import matplotlib.pyplot as plt

    leaves = np.flatnonzero(hlod.is_leaf)
    depth = np.asarray(hlod.depth)
    levels = np.arange(int(depth.max()) + 1)
    tris = np.array([int(np.asarray(hlod.tri_count)[depth == d].sum()) for d in levels])
    nodes = np.array([int((depth == d).sum()) for d in levels])
    target = int(hlod.meta.get("target_tris", 2000))
    fig, (cells, counts, errors) = plt.subplots(1, 3, figsize=(13.0, 4.3), dpi=130,
                                                gridspec_kw={"width_ratios": [1.1, 1.0, 1.0]})
    _top_view(cells, mesh, hlod, f"1. Octree: {leaves.size} leaves of at most {target:,} input triangles")
    _boxes(cells, hlod, leaves, fill=False, edgecolor="#4772b3", linewidth=0.6)
    cells.text(0.01, -0.06, f"{hlod.meta.get('input_tris', mesh.faces.shape[0]):,} triangles seen from above",
               transform=cells.transAxes, fontsize=8, color=INK)

    counts.barh(levels, tris, color="#4772b3")
    counts.set_xscale("log")
    counts.invert_yaxis()
    for d in levels:
        counts.text(tris[d] * 1.1, d, f"{nodes[d]} node{'' if nodes[d] == 1 else 's'}, {tris[d]:,} triangles",
                    va="center", fontsize=8, color=INK)
    counts.set_xlim(max(1, tris.min() / 3), tris.max() * 30)
    counts.set_yticks(levels)
    counts.set_ylabel("depth (0: the root)")
    counts.set_xlabel("triangles at this depth (log)")
    counts.set_title("2. Bottom up: children's LODs merged,\ndecimated to target_tris (pymeshlab)", fontsize=10,
                     loc="left")

    inner = ~np.asarray(hlod.is_leaf)
    error = np.asarray(hlod.error, np.float64)
    jitter = np.random.default_rng(1).uniform(-0.15, 0.15, depth.size)
    errors.scatter(error[inner], depth[inner] + jitter[inner], s=6, c="#c0392b", linewidths=0)
    errors.set_xscale("log")
    errors.invert_yaxis()
    errors.set_yticks(levels)
    errors.set_xlabel("stored error (model units, log): Hausdorff distance\nto the input triangles below the node")
    errors.set_title("3. An error per node, never smaller than a child's\n(leaves are the input: error 0)",
                     fontsize=10, loc="left")
    fig.tight_layout()
    path = out_dir / "how_bake.png"
    fig.savefig(path)
    plt.close(fig)
    return path


def draw_traversal(out_dir: Path, mesh, hlod, recorder, stats) -> Path:
    """how_traversal.png (module docstring)."""
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyBboxPatch, Polygon

    from hlod_core.core.colour import modulation_colour, srgb_from_linear

    fig, (top, steps) = plt.subplots(1, 2, figsize=(13.0, 5.2), dpi=130, gridspec_kw={"width_ratios": [1.2, 1.0]})
    _top_view(top, mesh, hlod, f"One frame of Coh(P) from the street: {stats.dn} nodes drawn, "
                               f"{stats.queries} queries")
    hidden = [n for n, q in recorder.seen.items() if q == 0 and n not in recorder.drawn]
    _boxes(top, hlod, hidden, fill=False, edgecolor="#c0392b", linewidth=1.0, linestyle="--")
    for node, p in recorder.drawn.items():
        colour = srgb_from_linear(modulation_colour(np.array([1.0 - p])))[0]
        _boxes(top, hlod, [node], facecolor=(*colour, 0.55), edgecolor=INK, linewidth=0.4)
    eye, target = np.array(EYE[:2]), np.array(TARGET[:2])
    ahead = (target - eye) / np.linalg.norm(target - eye)
    side = np.array([-ahead[1], ahead[0]])
    reach = 2.0 * float(np.max(hlod.box_max[0][:2] - hlod.box_min[0][:2]))  # clipped by the axes
    half = np.tan(np.radians(30.0)) * FRAME_SIZE[0] / FRAME_SIZE[1]  # the horizontal half-angle's tangent
    top.add_patch(Polygon([eye, eye + reach * (ahead + half * side), eye + reach * (ahead - half * side)],
                          closed=True, fill=False, edgecolor=INK, linewidth=0.8))
    top.plot(*eye, marker="o", color=INK, markersize=4)
    top.text(0.01, -0.06, "filled: drawn, in the overlay's colour (blue: fully visible, red: coarsened by "
                          "occlusion); dashed red: a query found it hidden", transform=top.transAxes, fontsize=8,
             color=INK)

    steps.set_axis_off()
    steps.set_xlim(0, 1)
    steps.set_ylim(0, 1)
    boxes = [
        (0.90, "Front to back: pop the nearest node of the priority queue"),
        (0.73, "Outside the view frustum? Skip it and its subtree"),
        (0.56, "Occlusion query on its box: q visible pixels,\nvisibility mu = q / alpha (alpha: the box unoccluded)"),
        (0.37, "SSE = error x pixels per unit / distance;\nSSE x P_{s,t}(mu) <= tau ?"),
        (0.16, "yes: draw the node, stop here\nno: push its children"),
    ]
    for y, text in boxes:
        steps.add_patch(FancyBboxPatch((0.05, y - 0.06), 0.9, 0.12, boxstyle="round,pad=0.01",
                                       facecolor="#eef2f8", edgecolor="#4772b3"))
        steps.text(0.5, y, text, ha="center", va="center", fontsize=9, color=INK)
    for (y0, _), (y1, _) in zip(boxes[:-1], boxes[1:]):
        steps.annotate("", xy=(0.5, y1 + 0.065), xytext=(0.5, y0 - 0.065),
                       arrowprops={"arrowstyle": "->", "color": INK})
    steps.text(0.05, 0.02, "Queries are issued as the loop goes and read when they are back, using last frame's\n"
                           "visibility meanwhile (coherent hierarchical culling), so the frame never waits on them.",
               fontsize=8, color=INK)
    steps.set_title("The loop (VMSSE: the error scaled by how visible a node is)", fontsize=10, loc="left")
    fig.tight_layout()
    path = out_dir / "how_traversal.png"
    fig.savefig(path)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images")
    args = parser.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    args.out.mkdir(parents=True, exist_ok=True)
    mesh, hlod = bake_city()
    recorder, stats = street_frame(hlod)
    for path in (draw_bake(args.out, mesh, hlod), draw_traversal(args.out, mesh, hlod, recorder, stats)):
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
