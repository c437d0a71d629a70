"""CesiumJS's tile selection re-implemented, formula for formula, to explain what Cesium chooses for a
view (tests/cesium_selection.py, benchmarks/cesium_compare.py): its camera and culling volume, the
tileset as it reads it, its SSE and its base traversal at rest (Cesium 1.1xx:
Cesium3DTile.getScreenSpaceError, Cesium3DTilesetBaseTraversal, Cesium3DTilesetTraversal,
OrientedBoundingBox, CullingVolume).

Data form: a `Camera` in the tileset's frame, which is our model space (Blender's Z up, metres; the
viewer page maps it to Cesium's frame with the rigid transform it places the tileset with, which
changes no distance); a `Tileset` as arrays, one row per tile in depth-first order.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hlod_core.model.view import View, look_at, perspective

#: Cesium's CesiumMath.EPSILON7: the smallest eye-to-box distance its SSE divides by.
CESIUM_MIN_DISTANCE_M = 1e-7
#: The near and far planes of the frustum Cesium's Camera makes (1.145: 0.1 and 5e8 m).
CESIUM_NEAR_M, CESIUM_FAR_M = 0.1, 5e8
#: CullingVolume plane masks.
MASK_INSIDE, MASK_OUTSIDE, MASK_INDETERMINATE = 0, 0xFFFFFFFF, 0x7FFFFFFF
OUTSIDE, INTERSECTING, INSIDE = -1, 0, 1



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
                    projection=perspective(math.degrees(self.fovy_rad), w / h, near=self.near_m, far=self.far_m),
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
        top = Path(tileset_json).parent
        uri, parent, children, center, axes, error, depth = [], [], [], [], [], [], []

        def visit(tile: dict, parent_row: int, *, parent_transform: np.ndarray, level: int, folder: str = "") -> int:
            content = (tile.get("content") or {}).get("uri")
            if content is not None and content.endswith(".json"):  # an external tileset: its root in its place,
                path = folder + content  # the same box and error (Cesium always traverses through the referring tile)
                sub = json.loads((top / path).read_text())["root"]
                return visit(sub, parent_row, parent_transform=parent_transform, level=level,
                             folder=path.rpartition("/")[0] + "/" if "/" in path else "")
            local = np.asarray(tile.get("transform", np.eye(4).ravel()), np.float64).reshape(4, 4).T  # column-major
            transform = parent_transform @ local
            box = np.asarray(tile["boundingVolume"]["box"], np.float64)
            row = len(uri)
            uri.append(None if content is None else folder + content)
            parent.append(parent_row)
            children.append([])
            center.append(transform[:3, :3] @ box[:3] + transform[:3, 3])
            axes.append(transform[:3, :3] @ box[3:].reshape(3, 3).T)  # columns: the half axes
            error.append(float(tile["geometricError"]))
            depth.append(level)
            for child in tile.get("children", []):
                children[row].append(visit(child, row, parent_transform=transform, level=level + 1, folder=folder))
            return row

        visit(doc["root"], -1, parent_transform=np.eye(4), level=0)
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


class _Culling:
    """Cesium's visibility tests over one tileset and camera, writing into a CesiumChoice: plane
    masks inherited from the parent, then children bounds."""

    def __init__(self, ts: Tileset, camera: Camera, choice: CesiumChoice):
        self.ts, self.choice = ts, choice
        self.planes = cesium_planes(camera)
        self.plane_test = box_plane_intersections(ts, self.planes)
        self.mask = np.full(ts.tile_count, MASK_INDETERMINATE, np.int64)

    def plane_mask(self, row: int, parent_mask: int) -> int:
        """CullingVolume.computeVisibilityWithPlaneMask."""
        if parent_mask in (MASK_OUTSIDE, MASK_INSIDE):
            return parent_mask
        out = MASK_INSIDE
        for k in range(self.planes.shape[0]):
            flag = 1 << k
            if not parent_mask & flag:
                continue
            if self.plane_test[row, k] == OUTSIDE:
                return MASK_OUTSIDE
            if self.plane_test[row, k] == INTERSECTING:
                out |= flag
        return out

    def update_visibility(self, row: int) -> bool:
        """Cesium3DTile.updateVisibility: the tile's own box."""
        parent = self.ts.parent[row]
        self.mask[row] = self.plane_mask(row, MASK_INDETERMINATE if parent < 0 else int(self.mask[parent]))
        self.choice.box_visible[row] = self.mask[row] != MASK_OUTSIDE
        return bool(self.choice.box_visible[row])

    def update_tile(self, row: int) -> None:
        """Cesium3DTilesetTraversal.updateTileVisibility (REPLACE tiles: no early SSE test)."""
        choice, children = self.choice, self.ts.children[row]
        choice.tested[row] = True
        choice.visible[row] = self.update_visibility(row)
        if choice.visible[row] and children and choice.within_parent[row]:
            # anyChildrenVisible, which stops at the first visible child
            choice.visible[row] = any(self.update_visibility(child) for child in children)


def cesium_select(ts: Tileset, camera: Camera, max_sse_px: float) -> CesiumChoice:
    """Cesium3DTilesetBaseTraversal.selectTiles (REPLACE, skipLevelOfDetail off) at rest, i.e. with
    every tile it asked for loaded (the state `allTilesLoaded` reports): the root is visible and its
    SSE with the tileset's geometricError exceeds tau, else nothing; a tile refines when its own SSE
    exceeds tau and a child is visible (all children are loaded), else it is selected. Visibility:
    the box against the culling volume with the parent's plane mask, then culled when the tile's
    children lie within it and none of theirs is visible."""
    n = ts.tile_count
    distance = box_distances(ts, np.asarray(camera.position, np.float64))
    choice = CesiumChoice(selected=[], distance=distance, sse=sse_px(ts.geometric_error, distance, camera),
                          root_sse=float(sse_px(np.array([ts.tileset_error]), distance[:1], camera)[0]),
                          within_parent=children_within_parent(ts), tested=np.zeros(n, bool),
                          visible=np.zeros(n, bool), box_visible=np.zeros(n, bool), refines=np.zeros(n, bool))
    culling = _Culling(ts, camera, choice)
    culling.update_tile(0)
    if not choice.visible[0] or choice.root_sse <= max_sse_px:
        return choice
    stack = [0]
    while stack:
        row = stack.pop()
        kids = ts.children[row]
        if kids and choice.sse[row] > max_sse_px:  # canTraverse
            for child in kids:
                culling.update_tile(child)
            # sortChildrenByDistanceToCamera: farthest first on the stack, nearest popped first
            stack += [child for child in sorted(kids, key=lambda c: -distance[c]) if choice.visible[child]]
            choice.refines[row] = bool(any(choice.visible[c] for c in kids))
        if not choice.refines[row] and ts.uri[row]:
            choice.selected.append(row)  # selectDesiredTile; no content bounding volume: contentVisibility INSIDE
    return choice
