"""The renderer's cost model: what a query and a node draw cost, fitted from timed samples, and the
skip test "is drawing this node cheaper than asking about it" (CHC++'s skipped queries for cheap
visible nodes: Mattausch, Bittner, Wimmer, "CHC++: Coherent Hierarchical Culling Revisited",
Eurographics 2008).

Data form: a sample is (count, size, seconds): `count` queries (or draw calls) of `size` pixels
(or triangles) in all, timed together. A linear model seconds = count * fixed + size * per_unit is
fitted by least squares over the samples (`fit_linear`), one for queries (per query, per box
pixel) and one for draws (per draw call, per triangle); `CostModel` holds both, with each fit's
relative residual. `BoxAreas` estimates the pixels boxes cover on screen, vectorised over boxes
(the projected areas of their three face directions), from view-independent terms found once for
a node table; `NodeCosts` holds the skip test's terms and `draw_is_cheaper` is the skip test of a
frame's few candidate nodes. No GL here: the renderer times the samples (its `cost_model`).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..model.view import View

#: A coefficient the least-squares fit makes negative or zero (noise on a cost too small to
#: measure) is clamped to this many seconds, so every cost stays positive.
MIN_COST_S = 1e-12


@dataclass(frozen=True)
class LinearCost:
    """seconds = count * fixed_s + units * per_unit_s; residual: the fit's RMS error relative to the
    samples' mean time (0 = exact)."""

    fixed_s: float
    per_unit_s: float
    residual: float

    def seconds(self, count, units):
        """Vectorised over arrays of counts and units."""
        return np.asarray(count, np.float64) * self.fixed_s + np.asarray(units, np.float64) * self.per_unit_s


def fit_linear(count, units, seconds) -> LinearCost:
    """Least squares over samples (count, units, seconds) (arrays of one length >= 2), without an
    intercept: a batch of zero calls costs nothing. A negative coefficient is clamped to
    MIN_COST_S and the other refitted alone."""
    a = np.c_[np.asarray(count, np.float64), np.asarray(units, np.float64)]
    y = np.asarray(seconds, np.float64)
    if a.shape[0] < 2:
        raise ValueError(f"a linear cost needs at least 2 samples, got {a.shape[0]}")
    coef = np.linalg.lstsq(a, y, rcond=None)[0]
    for bad in range(2):
        if not coef[bad] > MIN_COST_S:
            other = 1 - bad
            coef[bad] = MIN_COST_S
            rest = y - a[:, bad] * MIN_COST_S
            coef[other] = max(MIN_COST_S, float(a[:, other] @ rest / max(a[:, other] @ a[:, other], MIN_COST_S)))
    rms = float(np.sqrt(np.mean((a @ coef - y) ** 2)))
    return LinearCost(fixed_s=float(coef[0]), per_unit_s=float(coef[1]),
                      residual=rms / max(float(np.mean(y)), MIN_COST_S))


@dataclass(frozen=True)
class CostModel:
    """Fitted costs of one renderer: `query` (per query, per box pixel rasterised) and `draw` (per
    draw call, per triangle). `clock`: what was timed ("gpu": GL_TIME_ELAPSED, "wall": seconds
    between two glFinish, for a host whose own timer queries may be running)."""

    query: LinearCost
    draw: LinearCost
    clock: str

    def query_seconds(self, box_pixels):
        return self.query.seconds(1, box_pixels)

    def draw_seconds(self, triangles):
        return self.draw.seconds(1, triangles)

    def describe(self) -> str:
        return (f"query {self.query.fixed_s * 1e6:.2f} us + {self.query.per_unit_s * 1e9:.3f} ns/px "
                f"(residual {self.query.residual:.0%}); draw {self.draw.fixed_s * 1e6:.2f} us + "
                f"{self.draw.per_unit_s * 1e9:.3f} ns/triangle (residual {self.draw.residual:.0%}); {self.clock} clock")


@dataclass(frozen=True, eq=False)
class BoxAreas:
    """The pixels boxes cover on screen, estimated as a parallel projection along the line of sight
    to each box's centre: the sum over the three axes of the face area perpendicular to it times
    |cos| of its angle to that line, scaled by (pixels per unit at the centre's distance)^2, at most
    the viewport. Within a factor of about 2 of the exact silhouette (alpha_estimators.alpha_projected)
    for boxes in front of the eye; unlike the equal-volume cube, it keeps flat boxes' areas. Holds the
    per-box terms that do not depend on the view, found once for a node table's query boxes: the
    three face areas and the centres, (n,3) float64 each, model units."""

    faces: np.ndarray
    centre: np.ndarray

    @classmethod
    def of(cls, box_min: np.ndarray, box_max: np.ndarray) -> "BoxAreas":
        """From (n,3) bounds, model units."""
        lo, hi = np.array(box_min, np.float64), np.array(box_max, np.float64)
        ext = hi - lo
        faces = np.stack([ext[:, 1] * ext[:, 2], ext[:, 0] * ext[:, 2], ext[:, 0] * ext[:, 1]], axis=1)
        return cls(faces=faces, centre=0.5 * (lo + hi))

    def pixels_outside(self, view: View, nodes: np.ndarray | None = None) -> np.ndarray:
        """(m,) estimated pixels of the boxes `nodes` (all when None), boxes known not to hold the
        eye (the traversal's queryable boxes: a box holding it would get its area, not the viewport)."""
        pick = (lambda a: a) if nodes is None else (lambda a: a[nodes])
        faces = pick(self.faces)
        screen = float(view.width * view.height)
        unit_px = view.pixels_per_unit_x * view.pixels_per_unit_y
        if view.orthographic:
            forward = -view.view[2, :3]
            return np.minimum(np.abs(faces @ forward) * unit_px, screen)
        to_box = pick(self.centre) - view.eye
        d2 = np.einsum("ij,ij->i", to_box, to_box)
        with np.errstate(divide="ignore", invalid="ignore"):
            area = np.einsum("ij,ij->i", faces, np.abs(to_box)) / (d2 * np.sqrt(d2)) * unit_px
        return np.fmin(area, screen)  # inf and NaN (the eye at the centre) -> the viewport


#: Nodes up to which `draw_is_cheaper` tests them in plain Python, one by one (above: numpy): on
#: small fronts a numpy call costs more than the arithmetic (the measured crossover:
#: docs/performance.md#the-skip-tests-start-and-small-fronts).
PYTHON_TEST_NODES = 64


@dataclass(frozen=True, eq=False)
class NodeCosts:
    """The skip test's view-independent terms of a node table: tri_count (n,) as a list and `tris`
    (n,) float64, triangles per node; `boxes`, the query boxes' BoxAreas, and `faces`, `centres`,
    its (n,3) terms as lists for the Python path (all None where the box pixels come per frame)."""

    tri_count: list
    tris: np.ndarray
    boxes: BoxAreas | None
    faces: list | None
    centres: list | None

    @classmethod
    def of(cls, tri_count, box_min: np.ndarray | None = None, box_max: np.ndarray | None = None) -> "NodeCosts":
        """From (n,) triangle counts and, optionally, the (n,3) query boxes (model units)."""
        boxes = None if box_min is None else BoxAreas.of(box_min, box_max)
        return cls(tri_count=np.asarray(tri_count).tolist(), tris=np.asarray(tri_count, np.float64), boxes=boxes,
                   faces=None if boxes is None else boxes.faces.tolist(),
                   centres=None if boxes is None else boxes.centre.tolist())


def draw_is_cheaper(view: View, model: CostModel, nodes: Sequence[int], *, costs: NodeCosts, rate: float,
                    pixels: np.ndarray | None = None, python_nodes: int = PYTHON_TEST_NODES) -> memoryview:
    """The skip test (CHC++'s skipped queries): for each of `nodes`, whose query boxes do not hold
    the eye, is drawing its triangles, times `rate` (the traversal's change rate, or 1), cheaper
    than rasterising its query box? Box pixels from `pixels` ((n,) per-node estimate, e.g. the
    projected alpha) where given, else `BoxAreas.pixels_outside` of costs.boxes. Out: an (n,) mask
    as a memoryview (0/1 bytes, or bool), true where cheaper; false for nodes not asked about.
    Up to `python_nodes` nodes in plain Python, one by one, more with numpy: the same decisions."""
    count = len(costs.tri_count)
    if len(nodes) <= python_nodes:
        cheaper = _one_node_test(view, model, costs=costs, pixels=pixels)
        out = bytearray(count)
        for node in nodes:
            if cheaper(node, rate):
                out[node] = 1
        return memoryview(out)
    nodes = np.array(nodes, np.int64)
    box_pixels = pixels[nodes] if pixels is not None else costs.boxes.pixels_outside(view, nodes)
    mask = np.zeros(count, bool)
    mask[nodes] = model.draw_seconds(costs.tris[nodes]) * rate < model.query_seconds(box_pixels)
    return memoryview(mask)


def _one_node_test(view: View, model: CostModel, *, costs: NodeCosts,
                   pixels: np.ndarray | None) -> Callable[[int, float], bool]:
    """cheaper(node, rate): `draw_is_cheaper` for one node in Python scalars, the same operations
    as `LinearCost.seconds` and `BoxAreas.pixels_outside`."""
    screen = float(view.width * view.height)
    unit_px = view.pixels_per_unit_x * view.pixels_per_unit_y
    draw_unit, draw_fixed = model.draw.per_unit_s, model.draw.fixed_s
    query_unit, query_fixed = model.query.per_unit_s, model.query.fixed_s
    tri_count, faces, centres = costs.tri_count, costs.faces, costs.centres
    if pixels is not None:
        box_pixels = pixels.__getitem__
    elif view.orthographic:
        fx, fy, fz = (-view.view[2, :3]).tolist()

        def box_pixels(node: int) -> float:
            a, b, c = faces[node]
            return min(abs(a * fx + b * fy + c * fz) * unit_px, screen)
    else:
        ex, ey, ez = view.eye.tolist()

        def box_pixels(node: int) -> float:
            a, b, c = faces[node]
            x, y, z = centres[node]
            dx, dy, dz = x - ex, y - ey, z - ez
            d2 = dx * dx + dy * dy + dz * dz
            if not d2 > 0:  # the eye at the centre: numpy's inf or NaN, clipped to the viewport
                return screen
            return min((a * abs(dx) + b * abs(dy) + c * abs(dz)) / (d2 * math.sqrt(d2)) * unit_px, screen)

    def cheaper(node: int, rate: float) -> bool:
        return (tri_count[node] * draw_unit + draw_fixed) * rate < box_pixels(node) * query_unit + query_fixed
    return cheaper
