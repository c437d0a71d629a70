"""The tiles CesiumJS chooses for a view against the nodes our VFC traversal draws for the same
camera and the same screen-space-error threshold (issue 17).

    PYTHONPATH=. .venv/bin/python -m benchmarks.cesium_compare [--scale 0.25] [--target-tris 1000]
        [--size 800x600] [--tau 16 4] [--json OUT.json]

bakes the default city (procedural.default_scene at `--scale`), exports it as 3D Tiles, serves it with
hlod_core.export.viewer, opens the viewer page in Chromium (Playwright, /usr/bin/chromium, WebGL through
SwiftShader), and for each camera of `CAMERAS` and each threshold prints |ours|, |Cesium's|, the
intersection, the Jaccard index, Cesium's choice as predicted by `cesium_select` (a re-implementation
of Cesium's rule, must equal what Cesium chose) and, for every tile in one set only, the term that
decides it.

Data form: a baked `Hlod` and its export's tileset.json (one tile per node with triangles, content
uri "tiles/<node>.glb", box = the node's subtree box, geometricError = the node's error); a
`Camera` in the tileset's frame, which is our model space (Blender's Z up, metres; the page maps it
to Cesium's frame with the rigid transform it places the tileset with, which changes no distance).

Both rules compute `SSE = geometricError * H / (d * 2 tan(fovy / 2))` and refine while SSE > tau
(we stop at SSE <= tau: the same comparison). They differ in (Cesium 1.1xx,
Cesium3DTile.getScreenSpaceError, Cesium3DTilesetBaseTraversal, Cesium3DTilesetTraversal):
- **distance** (`DISTANCE`): ours is to the node's bounding sphere, d = |e - c| - r (DESIGN §5.1),
  Cesium's to the tile's box (OrientedBoundingBox.distanceSquaredTo, 0 inside, clamped to 1e-7).
  The sphere contains the box's geometry but reaches closer to the eye than the box, so our SSE is
  the larger one and we refine some tiles Cesium keeps: ours is the finer (deeper) set.
- **culling with children bounds** (`CHILDREN_BOUNDS`, Cesium's `cullWithChildrenBounds`, default
  on): a tile whose children all lie within it (Cesium3DTileOptimizations.checkChildrenWithinParent,
  strictly, along the axis from its centre to each child's) counts as invisible when none of its
  children's boxes meets the frustum. We test only the node's own box.
- **a refinement needs a visible child** (`NO_VISIBLE_CHILD`): Cesium keeps a tile whose SSE is
  above tau when no child is visible (updateAndPushChildren: `anyChildrenVisible`); our VFC descends
  and draws nothing there.
- **the root** (`ROOT_ERROR`): Cesium draws nothing unless the root, with the tileset's own
  geometricError (our root box diagonal), is above tau; our VFC always draws at least the root.
- **frustum** (`FRUSTUM`): both test a box plane by plane (conservative, same planes); Cesium counts
  a box touching a plane from outside (distance = -radius) as outside, we as inside.
- H is the drawing buffer's height divided by Cesium's pixelRatio (1 at resolutionScale 1 with
  useBrowserRecommendedResolution) for Cesium, the viewport height for us: the same here. Cesium
  waits for all children to load before refining (REPLACE, skipLevelOfDetail off); once
  `allTilesLoaded` every one it needs is loaded, so that changes nothing at rest.
"""
from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hlod_core.traversal import boxes, metrics
from hlod_core.export import tiles3d
from hlod_core.model.hierarchy import Hlod
from hlod_core.traversal.methods import make
from hlod_core.traversal.settings import RuntimeSettings
from hlod_core.model.view import View, look_at, perspective

#: Cesium's CesiumMath.EPSILON7: the smallest eye-to-box distance its SSE divides by.
CESIUM_MIN_DISTANCE_M = 1e-7
#: The near and far planes of the frustum Cesium's Camera makes (1.145: 0.1 and 5e8 m).
CESIUM_NEAR_M, CESIUM_FAR_M = 0.1, 5e8
#: CullingVolume plane masks.
MASK_INSIDE, MASK_OUTSIDE, MASK_INDETERMINATE = 0, 0xFFFFFFFF, 0x7FFFFFFF
OUTSIDE, INTERSECTING, INSIDE = -1, 0, 1
#: An SSE or a plane distance this close (relative) to its threshold is a tie the two programs
#: may round either way (Cesium works in its own frame, a rigid transform of ours).
TIE_RELATIVE = 1e-9

#: Terms that decide a tile chosen by one side only (the module docstring explains each).
DISTANCE = "distance: sphere (ours) vs box (Cesium)"
EYE_IN_SPHERE = "eye inside the node's sphere: ours refines whatever its error, Cesium divides it by the box distance"
CHILDREN_BOUNDS = "Cesium culls a tile none of whose children is in the frustum (cullWithChildrenBounds)"
NO_VISIBLE_CHILD = "Cesium keeps a tile above tau when no child is in the frustum"
ROOT_ERROR = "root: Cesium draws nothing while the tileset geometricError is within tau"
FRUSTUM = "frustum test at a plane (touching boxes)"
TERMS = (DISTANCE, EYE_IN_SPHERE, CHILDREN_BOUNDS, NO_VISIBLE_CHILD, ROOT_ERROR, FRUSTUM)


@dataclass(frozen=True)
class Camera:
    """A perspective camera in the tileset's frame (our model space, Z up, metres).

    position, direction, up: (3,) float64 (direction and up orthonormal, as Cesium keeps them);
    fovy_rad: vertical field of view; near_m, far_m: Cesium's frustum planes;
    buffer_px: (width, height) of the drawing buffer; pixel_ratio: Cesium's scene.pixelRatio
    (SSE is computed for buffer height / pixel_ratio pixels)."""

    position: tuple
    direction: tuple
    up: tuple
    fovy_rad: float
    buffer_px: tuple = (800, 600)
    near_m: float = CESIUM_NEAR_M
    far_m: float = CESIUM_FAR_M
    pixel_ratio: float = 1.0

    @classmethod
    def looking_at(cls, eye, target, up=(0.0, 0.0, 1.0), *, fovy_deg: float = 60.0, **kw) -> "Camera":
        eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
        direction = (target - eye) / np.linalg.norm(target - eye)
        right = np.cross(direction, up)
        right /= np.linalg.norm(right)
        return cls(position=tuple(eye), direction=tuple(direction), up=tuple(np.cross(right, direction)),
                   fovy_rad=math.radians(fovy_deg), **kw)

    @property
    def height_px(self) -> float:
        return self.buffer_px[1] / self.pixel_ratio

    def view(self) -> View:
        """Our View of the same camera: look-at, perspective with the same fovy, aspect, near, far,
        viewport = the drawing buffer over the pixel ratio (SSE uses its height)."""
        eye = np.asarray(self.position, np.float64)
        w, h = self.buffer_px
        return View(eye=eye, view=look_at(eye, eye + np.asarray(self.direction), self.up),
                    projection=perspective(math.degrees(self.fovy_rad), w / h, self.near_m, self.far_m),
                    width=int(round(w / self.pixel_ratio)), height=int(round(h / self.pixel_ratio)))

    def to_page(self) -> dict:
        """The argument of window.hlodViewer.setCamera."""
        return {"position": list(self.position), "direction": list(self.direction), "up": list(self.up),
                "fovyRadians": self.fovy_rad}


# --- the tileset as Cesium reads it -------------------------------------------------------------

@dataclass
class Tileset:
    """tileset.json as arrays, in the tileset's frame (transforms applied), tiles in depth-first
    order (root 0): uri (content uri or None), node (our node id from the uri, -1 without content),
    parent (n,) int, children: lists of rows, center (n,3), half_axes (n,3,3) with the box's half
    axes as columns, geometric_error (n,), depth (n,); tileset_error: the tileset's geometricError."""

    uri: list
    node: np.ndarray
    parent: np.ndarray
    children: list
    center: np.ndarray
    half_axes: np.ndarray
    geometric_error: np.ndarray
    depth: np.ndarray
    tileset_error: float
    row_of_uri: dict = field(default_factory=dict)

    @classmethod
    def read(cls, tileset_json: Path) -> "Tileset":
        doc = json.loads(Path(tileset_json).read_text())
        uri, parent, children, center, axes, error, depth = [], [], [], [], [], [], []

        def visit(tile: dict, parent_row: int, parent_transform: np.ndarray, level: int) -> int:
            local = np.asarray(tile.get("transform", np.eye(4).ravel()), np.float64).reshape(4, 4).T  # column-major
            transform = parent_transform @ local
            box = np.asarray(tile["boundingVolume"]["box"], np.float64)
            row = len(uri)
            uri.append((tile.get("content") or {}).get("uri"))
            parent.append(parent_row)
            children.append([])
            center.append(transform[:3, :3] @ box[:3] + transform[:3, 3])
            axes.append(transform[:3, :3] @ box[3:].reshape(3, 3).T)  # columns: the half axes
            error.append(float(tile["geometricError"]))
            depth.append(level)
            for child in tile.get("children", []):
                children[row].append(visit(child, row, transform, level + 1))
            return row

        visit(doc["root"], -1, np.eye(4), 0)
        node = np.array([int(Path(u).stem) if u else -1 for u in uri], np.int64)
        return cls(uri=uri, node=node, parent=np.asarray(parent), children=children, center=np.asarray(center),
                   half_axes=np.asarray(axes), geometric_error=np.asarray(error), depth=np.asarray(depth),
                   tileset_error=float(doc["geometricError"]),
                   row_of_uri={u: i for i, u in enumerate(uri) if u})

    @property
    def tile_count(self) -> int:
        return len(self.uri)


def children_within_parent(ts: Tileset) -> np.ndarray:
    """(n,) bool: Cesium3DTileOptimizations.checkChildrenWithinParent, formula for formula: for each
    child, the parent's and the child's boxes projected on the unit axis from the parent's centre to
    the child's (sum over the half-axis matrix entries of |entry * axis component|); the optimisation
    holds only if proj_parent > proj_child + |axis| for every child (a shared centre gives NaN,
    which never fails the test). Leaves keep True (Cesium's value; unused without children)."""
    out = np.ones(ts.tile_count, bool)
    for row, kids in enumerate(ts.children):
        for child in kids:
            axis = ts.center[child] - ts.center[row]
            length = np.linalg.norm(axis)
            with np.errstate(invalid="ignore", divide="ignore"):
                axis = axis / length
            # halfAxes[3 * column + r] * axis[r]: column-major entries times the axis component of their row
            proj_parent = np.sum(np.abs(ts.half_axes[row] * axis[:, None]))
            proj_child = np.sum(np.abs(ts.half_axes[child] * axis[:, None]))
            if proj_parent <= proj_child + length:
                out[row] = False
                break
    return out


# --- Cesium's camera, culling volume and SSE ----------------------------------------------------

def cesium_planes(camera: Camera) -> np.ndarray:
    """(6,4) planes (normal, w), inside where n.x + w >= 0, built as Cesium's
    PerspectiveOffCenterFrustum.computeCullingVolume does: left, right, bottom, top through the eye,
    near, far."""
    position, direction, up = (np.asarray(v, np.float64) for v in (camera.position, camera.direction, camera.up))
    right = np.cross(direction, up)
    w, h = camera.buffer_px
    top = camera.near_m * math.tan(0.5 * camera.fovy_rad)
    r = (w / h) * top
    near_center = position + direction * camera.near_m
    far_center = position + direction * camera.far_m

    def unit(v):
        return v / np.linalg.norm(v)

    def through_eye(normal):
        return np.append(normal, -normal @ position)

    left_plane = through_eye(unit(np.cross(unit(near_center - right * r - position), up)))
    right_plane = through_eye(unit(np.cross(up, unit(near_center + right * r - position))))
    bottom_plane = through_eye(unit(np.cross(right, unit(near_center - up * top - position))))
    top_plane = through_eye(unit(np.cross(unit(near_center + up * top - position), right)))
    near_plane = np.append(direction, -direction @ near_center)
    far_plane = np.append(-direction, direction @ far_center)
    return np.array([left_plane, right_plane, bottom_plane, top_plane, near_plane, far_plane])


def box_plane_intersections(ts: Tileset, planes: np.ndarray) -> np.ndarray:
    """(n,6) OrientedBoundingBox.intersectPlane per tile and plane: OUTSIDE when the centre's
    signed distance <= -r, INSIDE when >= r, else INTERSECTING; r = sum_k |n . half_axis_k|."""
    radius = np.abs(np.einsum("pi,nik->npk", planes[:, :3], ts.half_axes)).sum(axis=2)
    distance = ts.center @ planes[:, :3].T + planes[:, 3]
    return np.where(distance <= -radius, OUTSIDE, np.where(distance >= radius, INSIDE, INTERSECTING))


def box_distances(ts: Tileset, eye: np.ndarray) -> np.ndarray:
    """(n,) OrientedBoundingBox.distanceSquaredTo's square root: eye to box, 0 inside."""
    offset = eye - ts.center
    half = np.linalg.norm(ts.half_axes, axis=1)  # (n,3) half lengths of the axes (columns)
    along = np.einsum("ni,nik->nk", offset, ts.half_axes) / half
    outside = np.maximum(np.abs(along) - half, 0.0)
    return np.sqrt(np.sum(outside * outside, axis=1))


def sse_px(error: np.ndarray, distance: np.ndarray, camera: Camera) -> np.ndarray:
    """Cesium3DTile.getScreenSpaceError (perspective, no dynamic SSE): error * H / (d * 2 tan(fovy/2))
    / pixelRatio, d clamped to CESIUM_MIN_DISTANCE_M, 0 where the error is 0."""
    buffer_height = camera.buffer_px[1]
    denominator = 2.0 * math.tan(0.5 * camera.fovy_rad)
    out = error * buffer_height / (np.maximum(distance, CESIUM_MIN_DISTANCE_M) * denominator) / camera.pixel_ratio
    return np.where(error == 0.0, 0.0, out)


@dataclass
class CesiumChoice:
    """What `cesium_select` decided: selected rows (in traversal order), and per tile (n,) the
    box distance, SSE, the children-bounds flag, and whether the traversal tested the tile's
    visibility (`tested`) and found it visible (`visible`) or refined it (`refines`)."""

    selected: list
    distance: np.ndarray
    sse: np.ndarray
    root_sse: float
    within_parent: np.ndarray
    tested: np.ndarray
    visible: np.ndarray
    box_visible: np.ndarray
    refines: np.ndarray


def cesium_select(ts: Tileset, camera: Camera, max_sse_px: float) -> CesiumChoice:
    """Cesium3DTilesetBaseTraversal.selectTiles (REPLACE, skipLevelOfDetail off) at rest, i.e. with
    every tile it asked for loaded (the state `allTilesLoaded` reports): the root is visible and its
    SSE with the tileset's geometricError exceeds tau, else nothing; a tile refines when its own SSE
    exceeds tau and a child is visible (all children are loaded), else it is selected. Visibility:
    the box against the culling volume with the parent's plane mask, then culled when the tile's
    children lie within it and none of theirs is visible."""
    n = ts.tile_count
    planes = cesium_planes(camera)
    plane_test = box_plane_intersections(ts, planes)
    within = children_within_parent(ts)
    distance = box_distances(ts, np.asarray(camera.position, np.float64))
    sse = sse_px(ts.geometric_error, distance, camera)
    root_sse = float(sse_px(np.array([ts.tileset_error]), distance[:1], camera)[0])
    mask = np.full(n, MASK_INDETERMINATE, np.int64)
    tested, visible, box_visible, refines = (np.zeros(n, bool) for _ in range(4))

    def plane_mask(row: int, parent_mask: int) -> int:
        """CullingVolume.computeVisibilityWithPlaneMask."""
        if parent_mask in (MASK_OUTSIDE, MASK_INSIDE):
            return parent_mask
        out = MASK_INSIDE
        for k in range(planes.shape[0]):
            flag = 1 << k
            if not parent_mask & flag:
                continue
            if plane_test[row, k] == OUTSIDE:
                return MASK_OUTSIDE
            if plane_test[row, k] == INTERSECTING:
                out |= flag
        return out

    def update_visibility(row: int) -> bool:
        """Cesium3DTile.updateVisibility: the tile's own box."""
        parent = ts.parent[row]
        mask[row] = plane_mask(row, MASK_INDETERMINATE if parent < 0 else int(mask[parent]))
        box_visible[row] = mask[row] != MASK_OUTSIDE
        return bool(box_visible[row])

    def update_tile(row: int) -> None:
        """Cesium3DTilesetTraversal.updateTileVisibility (REPLACE tiles: no early SSE test)."""
        tested[row] = True
        visible[row] = update_visibility(row)
        if visible[row] and ts.children[row] and within[row]:
            # anyChildrenVisible, which stops at the first visible child
            visible[row] = any(update_visibility(child) for child in ts.children[row])

    selected: list = []
    update_tile(0)
    if not visible[0] or root_sse <= max_sse_px:
        return CesiumChoice(selected, distance, sse, root_sse, within, tested, visible, box_visible, refines)
    stack = [0]
    while stack:
        row = stack.pop()
        if ts.children[row] and sse[row] > max_sse_px:  # canTraverse
            kids = ts.children[row]
            for child in kids:
                update_tile(child)
            # sortChildrenByDistanceToCamera: farthest first on the stack, nearest popped first
            for child in sorted(kids, key=lambda c: -distance[c]):
                if visible[child]:
                    stack.append(child)
            refines[row] = bool(any(visible[c] for c in kids))
        if not refines[row] and ts.uri[row]:
            selected.append(row)  # selectDesiredTile; no content bounding volume: contentVisibility INSIDE
    return CesiumChoice(selected, distance, sse, root_sse, within, tested, visible, box_visible, refines)


# --- our side -----------------------------------------------------------------------------------

class SelectionOnly:
    """A traversal.NodeRenderer that draws nothing. VFC asks its renderer for nothing but draws (no
    queries), so the nodes it draws are decided without GL; the tests check that the GL renderer
    gives VFC the same nodes."""

    def __init__(self, hlod: Hlod):
        from hlod_core.model.hierarchy import query_box_pad

        self.query_box_pad = query_box_pad(hlod.box_min, hlod.box_max)

    def begin_frame(self, view: View) -> None:
        pass

    def end_frame(self) -> float:
        return 0.0

    def draw_node(self, node: int, ratio_p: float) -> None:
        pass

    def issue_query(self, node: int, *, with_alpha: bool):
        raise AssertionError("VFC issues no occlusion queries")

    def available(self, query) -> bool:
        raise AssertionError("VFC issues no occlusion queries")

    def result(self, query):
        raise AssertionError("VFC issues no occlusion queries")


def vfc_nodes(hlod: Hlod, camera: Camera, tau_px: float, renderer=None) -> list[int]:
    """The nodes our VFC traversal draws for `camera` at threshold `tau_px` (traversal.VFC, one frame),
    in draw order; `renderer` defaults to SelectionOnly."""
    traversal = make("vfc", hlod, renderer or SelectionOnly(hlod), settings=RuntimeSettings(tau=tau_px))
    return list(traversal.frame(camera.view()).drawn)


def tile_uri(node: int) -> str:
    """The content uri tiles3d.export gives node `node`'s tile."""
    return f"{tiles3d.TILE_FOLDER}/{node}.glb"


def node_of_row(ts: Tileset, hlod: Hlod) -> np.ndarray:
    """(n,) our node id of each tile, by walking both trees together (tiles3d.tileset keeps the
    children's order and leaves out only subtrees without triangles); checked against the uris."""
    subtree_tris = hlod.tri_count.astype(np.int64).copy()
    for node in np.argsort(-hlod.depth, kind="stable").tolist():  # deepest first: sums flow up
        if hlod.parent[node] >= 0:
            subtree_tris[hlod.parent[node]] += subtree_tris[node]
    out = np.full(ts.tile_count, -1, np.int64)
    out[0] = 0
    for row in range(ts.tile_count):  # depth-first rows: a parent's row comes before its children's
        first, count = int(hlod.child_offset[out[row]]), int(hlod.child_count[out[row]])
        kept = [c for c in range(first, first + count) if subtree_tris[c] > 0] if count else []
        if len(kept) != len(ts.children[row]):
            raise ValueError(f"tile {ts.uri[row]}: {len(ts.children[row])} children, node {out[row]} has {len(kept)}")
        out[ts.children[row]] = kept
    has_uri = ts.node >= 0
    if not np.array_equal(out[has_uri], ts.node[has_uri]):
        raise ValueError("tileset.json does not belong to this HLOD: the tile uris name other nodes")
    return out


# --- the comparison -----------------------------------------------------------------------------

@dataclass
class Difference:
    """A tile one side chose and the other did not: `side` "ours" or "cesium" (who chose it), the
    deciding term (one of TERMS, or "unexplained"), `tie` when the deciding values sit within
    TIE_RELATIVE of each other, and a line with the figures."""

    uri: str
    side: str
    term: str
    tie: bool
    detail: str
    at: str = ""  # the tile where the two rules decide differently


def explain(ts: Tileset, hlod: Hlod, camera: Camera, tau_px: float, ours: set, cesium: set,
            choice: CesiumChoice) -> list[Difference]:
    """For every tile in one set only, the first node on its path from the root where our VFC and
    Cesium's rule decide differently (enter: in the frustum / visible; refine), and the term that
    makes them differ there."""
    view = camera.view()
    nodes = node_of_row(ts, hlod)
    in_frustum = boxes.boxes_in_frustum(view, hlod.box_min, hlod.box_max)
    sphere_d = metrics.sphere_distance(view, hlod.sphere_center, hlod.sphere_radius)
    our_sse = metrics.sse(view, hlod.error, center=hlod.sphere_center, radius=hlod.sphere_radius, is_leaf=hlod.is_leaf)
    out = []
    for uri in sorted(ours ^ cesium, key=lambda u: (ts.depth[ts.row_of_uri[u]], u)):
        row = ts.row_of_uri[uri]
        path = [row]
        while ts.parent[path[-1]] >= 0:
            path.append(int(ts.parent[path[-1]]))
        term, tie, detail, at = "unexplained", False, "no decision differs on the path", uri
        for a in reversed(path):
            at = ts.uri[a]
            node = int(nodes[a])
            where = f"{ts.uri[a]} (depth {ts.depth[a]})"
            ours_enter = bool(in_frustum[node])
            cesium_enter = bool(choice.visible[a]) and (a != 0 or choice.root_sse > tau_px)
            if ours_enter != cesium_enter:
                if a == 0 and choice.visible[0]:
                    term, tie = ROOT_ERROR, _tie(choice.root_sse, tau_px)
                    detail = (f"root SSE with the tileset error {ts.tileset_error:.4g} m: "
                              f"{choice.root_sse:.4g} px <= tau {tau_px:g}")
                elif ours_enter and choice.box_visible[a] and not choice.visible[a]:
                    term = CHILDREN_BOUNDS
                    detail = f"{where}: its box meets the frustum, none of its {len(ts.children[a])} children's does"
                else:
                    term = FRUSTUM
                    detail = f"{where}: in our frustum {ours_enter}, Cesium's box test {bool(choice.box_visible[a])}"
                break
            if not ours_enter:
                break
            ours_refine = not hlod.is_leaf[node] and our_sse[node] > tau_px
            cesium_refine = bool(choice.refines[a])
            if ours_refine != cesium_refine:
                figures = (f"{where}: ours {our_sse[node]:.4g} px (sphere distance {sphere_d[node]:.4g} m), "
                           f"Cesium {choice.sse[a]:.4g} px (box distance {choice.distance[a]:.4g} m), "
                           f"tau {tau_px:g}, error {ts.geometric_error[a]:.4g} m")
                if (our_sse[node] > tau_px) != (choice.sse[a] > tau_px):
                    term = EYE_IN_SPHERE if sphere_d[node] <= 0 else DISTANCE
                    tie = _tie(our_sse[node], tau_px) or _tie(choice.sse[a], tau_px)
                elif choice.sse[a] > tau_px and not any(choice.visible[c] for c in ts.children[a]):
                    term = NO_VISIBLE_CHILD
                detail = figures
                break
        out.append(Difference(uri=uri, side="ours" if uri in ours else "cesium", term=term, tie=tie, detail=detail,
                              at=at))
    return out


def _tie(value: float, threshold: float) -> bool:
    return bool(abs(value - threshold) <= TIE_RELATIVE * max(abs(threshold), 1.0))


def jaccard(a: set, b: set) -> float:
    """|a & b| / |a | b|; 1 for two empty sets."""
    union = a | b
    return len(a & b) / len(union) if union else 1.0


def compare(ts: Tileset, hlod: Hlod, camera: Camera, tau_px: float, cesium_uris: set | None = None, *,
            renderer=None) -> dict:
    """One row of the table: ours (VFC), Cesium's rule as predicted here, and Cesium's choice if
    given (else the prediction stands in for it), with the differences explained."""
    ours = {tile_uri(n) for n in vfc_nodes(hlod, camera, tau_px, renderer)}
    choice = cesium_select(ts, camera, tau_px)
    predicted = {ts.uri[r] for r in choice.selected}
    cesium = predicted if cesium_uris is None else set(cesium_uris)
    differences = explain(ts, hlod, camera, tau_px, ours, cesium, choice)
    return {"tau_px": tau_px, "ours": len(ours), "cesium": len(cesium), "both": len(ours & cesium),
            "jaccard": jaccard(ours, cesium), "predicted": len(predicted),
            "prediction_exact": predicted == cesium, "prediction_misses": sorted(predicted ^ cesium),
            "ours_only": sorted(ours - cesium), "cesium_only": sorted(cesium - ours),
            "ours_depth": _depths(ts, ours), "cesium_depth": _depths(ts, cesium),
            "differences": differences}


def _depths(ts: Tileset, uris: set) -> str:
    """'d0:n0 d1:n1 ...' of the tiles' depths."""
    depths = np.bincount([ts.depth[ts.row_of_uri[u]] for u in uris], minlength=1) if uris else np.zeros(1, int)
    return " ".join(f"{d}:{c}" for d, c in enumerate(depths.tolist()) if c)


# --- Cesium in the browser (window.hlodViewer of hlod_core/export/viewer_page) -------------------------

#: Frames a selection must stay the same, with all tiles loaded, before it is read as Cesium's choice.
STABLE_FRAMES = 3
_NEXT_FRAME_JS = "() => new Promise(done => requestAnimationFrame(() => requestAnimationFrame(done)))"
_STATE_JS = """() => ({loaded: window.hlodViewer.allTilesLoaded === true,
    tiles: window.hlodViewer.selectedTiles().map(t => t.uri),
    size: window.hlodViewer.frameSize(), camera: window.hlodViewer.camera(),
    devicePixelRatio: window.devicePixelRatio})"""


def cesium_choose(page, camera: Camera, tau_px: float, *, timeout_s: float = 120.0) -> tuple[set, Camera]:
    """Set `camera` and the maximum SSE on the viewer page (a Playwright page showing it), wait until
    every tile is loaded and the selection has stayed the same for STABLE_FRAMES frames, and return
    (Cesium's selected uris, the camera as the page reports it: position, direction, up, fovy, the
    drawing buffer, and near, far, pixel ratio where the page gives them)."""
    page.evaluate("([c, tau]) => { window.hlodViewer.setMaximumScreenSpaceError(tau); window.hlodViewer.setCamera(c); }",
                  [camera.to_page(), tau_px])
    deadline = time.monotonic() + timeout_s
    previous, stable = None, 0
    while stable < STABLE_FRAMES:
        if time.monotonic() > deadline:
            raise TimeoutError(f"Cesium did not settle within {timeout_s:g} s (tau {tau_px:g} px, camera {camera.to_page()})")
        page.evaluate(_NEXT_FRAME_JS)
        state = page.evaluate(_STATE_JS)
        tiles = sorted(state["tiles"])
        stable = stable + 1 if state["loaded"] and tiles == previous else 0
        previous = tiles
    seen = state["camera"]
    # the page's camera: Cesium keeps direction and up orthonormal; fovy is its frustum's
    read = Camera(position=tuple(seen["position"]), direction=tuple(seen["direction"]), up=tuple(seen["up"]),
                  fovy_rad=float(seen["fovyRadians"]), buffer_px=tuple(int(v) for v in state["size"]),
                  near_m=float(seen.get("near", CESIUM_NEAR_M)), far_m=float(seen.get("far", CESIUM_FAR_M)),
                  pixel_ratio=float(seen.get("pixelRatio", 1.0)))
    return set(previous), read


# --- the benchmark ------------------------------------------------------------------------------

def scene_setups() -> dict:
    """name -> (mesh factory, target_tris, {camera name: Camera factory(buffer_px)}): the terrain
    (procedural.low_scene at scale 0.1, 200 m across, hills to 16 m: flat wide tiles whose spheres
    reach far closer to the eye than their boxes) and the default city at scale 0.25 (2 x 2
    towers on a 40 m ground). Cameras: beyond (so far that the tileset's geometricError is under
    16 px), far, middle, close-up and inside the root box."""
    from hlod_core.io import procedural

    def cams(spec):
        return {name: (lambda size, e=eye, t=target: Camera.looking_at(e, t, buffer_px=size)) for name, (eye, target) in spec.items()}

    return {
        "terrain": (lambda: procedural.low_scene(seed=1, scale=0.1), 500, cams({
            "beyond": ([0.0, -9500.0, 3500.0], [0.0, 0.0, 0.0]), "far": ([0.0, -300.0, 120.0], [0.0, 0.0, 0.0]),
            "middle": ([60.0, -120.0, 40.0], [0.0, 0.0, 0.0]), "close": ([10.0, -30.0, 20.0], [15.0, 0.0, 5.0]),
            "inside": ([-60.0, -60.0, 14.0], [40.0, 40.0, 4.0])})),
        "city": (lambda: procedural.default_scene(seed=1, scale=0.25), 500, cams({
            "beyond": ([10.0, -2800.0, 1000.0], [10.0, 10.0, 15.0]), "far": ([10.0, -160.0, 70.0], [10.0, 10.0, 15.0]),
            "middle": ([45.0, -45.0, 35.0], [10.0, 10.0, 12.0]), "close": ([-1.0, -12.0, 4.0], [0.0, 0.0, 6.0]),
            "inside": ([10.0, -5.0, 1.7], [10.0, 25.0, 4.0])})),
    }


def bake_and_export(scene: str, out_dir: Path) -> tuple[Hlod, Tileset]:
    from hlod_core.bake.pipeline import BakeSettings, bake

    factory, target_tris, _ = scene_setups()[scene]
    hlod = bake(factory(), BakeSettings(jobs=1, target_tris=target_tris))
    tiles3d.export(hlod, out_dir)
    return hlod, Tileset.read(out_dir / "tileset.json")


class Browser:
    """Chromium from the system packages driven by Playwright (WebGL through SwiftShader), one page
    on `url` with window.hlodViewer ready; console errors collected. A context manager."""

    ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]

    def __init__(self, url: str, *, size: tuple[int, int] = (800, 600), executable: str = "/usr/bin/chromium"):
        self.url, self.size, self.executable = url, size, executable
        self.console_errors: list[str] = []

    def __enter__(self):
        from playwright.sync_api import sync_playwright

        self._playwright = sync_playwright().start()
        try:
            self._browser = self._playwright.chromium.launch(executable_path=self.executable, args=self.ARGS)
            self.page = self._browser.new_page(viewport={"width": self.size[0], "height": self.size[1]})
            self.page.on("console", lambda m: self.console_errors.append(m.text) if m.type == "error" else None)
            self.page.on("pageerror", lambda e: self.console_errors.append(str(e)))
            self.page.goto(self.url)
            self.page.wait_for_function("() => window.hlodViewer && window.hlodViewer.ready === true", timeout=120_000)
        except BaseException:
            self._playwright.stop()
            raise
        return self

    def __exit__(self, *exc):
        try:
            self._browser.close()
        finally:
            self._playwright.stop()


def run(scene: str, taus: list[float], *, size: tuple[int, int] = (800, 600), folder: Path) -> list[dict]:
    """Bake and export `scene`, serve it, and compare every camera at every threshold."""
    from hlod_core.export.viewer import serve

    hlod, ts = bake_and_export(scene, folder / "tiles")
    rows = []
    with serve(folder / "tiles") as server:
        server.start()
        with Browser(server.url, size=size) as browser:
            for name, make_camera in scene_setups()[scene][2].items():
                for tau in taus:
                    uris, seen = cesium_choose(browser.page, make_camera(size), tau)
                    row = compare(ts, hlod, seen, tau, uris)
                    row.update(scene=scene, camera=name)
                    rows.append(row)
    return rows


def summary_lines(row: dict) -> list[str]:
    """The terms of a row's differences, grouped by the tile where the rules part, one example each."""
    groups: dict = {}
    for d in row["differences"]:
        groups.setdefault((d.term, d.at), []).append(d)
    out = []
    for (term, at), ds in groups.items():
        ours = sum(d.side == "ours" for d in ds)
        out.append(f"    {term} at {at}: {ours} ours only, {len(ds) - ours} Cesium only{' (tie)' if any(d.tie for d in ds) else ''}; "
                   f"{ds[0].detail}")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", nargs="+", default=["terrain", "city"], choices=sorted(scene_setups()))
    parser.add_argument("--tau", nargs="+", type=float, default=[16.0, 2.0], help="maximum SSE, pixels")
    parser.add_argument("--size", default="800x600")
    parser.add_argument("--json", help="write the rows here")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for scene in args.scene:
            rows += run(scene, args.tau, size=size, folder=Path(tmp) / scene)
    print("| scene | camera | tau px | ours | Cesium | both | Jaccard | predicted = Cesium | ours by depth | Cesium by depth |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['scene']} | {r['camera']} | {r['tau_px']:g} | {r['ours']} | {r['cesium']} | {r['both']} | "
              f"{r['jaccard']:.2f} | {'yes' if r['prediction_exact'] else 'NO ' + str(r['prediction_misses'])} | "
              f"{r['ours_depth']} | {r['cesium_depth']} |")
    for r in rows:
        if r["differences"]:
            print(f"{r['scene']} {r['camera']} tau {r['tau_px']:g}:")
            print("\n".join(summary_lines(r)))
    if args.json:
        Path(args.json).write_text(json.dumps([{k: v for k, v in r.items() if k != "differences"} | {
            "differences": [d.__dict__ for d in r["differences"]]} for r in rows], indent=1))


if __name__ == "__main__":
    main()
