"""The HLOD node table: structure of arrays, one row per node, root = row 0.

Implements the data model of docs/how-it-works.md#the-node-table (after the octree HLODs of J. P.
Charalambos, "HLOD Refinement Driven by Hardware Occlusion Queries", dissertation, 2007, section
3.3: one discrete LOD of about `target_tris` triangles per node, a model-space error per node,
nested bounding volumes; docs/how-it-works.md#papers).

Nodes are numbered breadth first, so the children of a node are contiguous:
`child_offset[i] .. child_offset[i] + child_count[i] - 1` (`child_offset = -1` for a leaf).

Geometry lives in one shared buffer: `positions` are float32 *relative to* `origin` (float64), so
a model placed 1e6 units away keeps its precision; `indices` are global rows into `positions`, and
node i draws triangles `tri_offset[i] .. tri_offset[i] + tri_count[i] - 1` (one ranged draw).
Bounds are float64 in world (model) units.

Appearance (appearance.py), only when the scene has it: per vertex `uvs` (v,2) float32
and `colors` (v,4) float32 linear RGBA, per triangle `tri_material` (t,) uint16 rows of
`materials`. Within a node, triangles are sorted by material, so a node draws as one ranged draw
per (node, material) (`draw_parts`).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from ..core.arrays import segment_ranges

#: Largest magnitude of any coordinate, bound or error (model units) the product accepts, in files
#: and camera paths: squares and products of such numbers stay far inside float64, and differences
#: of them inside float32 (the renderer's origin-relative query boxes).
MAX_COORDINATE = 1e30

#: Query boxes (docs/how-it-works.md#query-boxes) are enlarged by this fraction of the root box diagonal; the cube side
#: of docs/how-it-works.md#alpha-three-ways is computed on the enlarged box so that flat boxes keep a non-zero cube.
QUERY_BOX_PAD_FRACTION = 1e-3

# name -> (dtype, trailing shape); the leading dimension is the node count.
NODE_ARRAYS: dict[str, tuple[str, tuple[int, ...]]] = {
    "parent": ("<i4", ()),
    "child_offset": ("<i4", ()),
    "child_count": ("<i4", ()),
    "depth": ("<i4", ()),
    "lod_box_min": ("<f8", (3,)),
    "lod_box_max": ("<f8", (3,)),
    "box_min": ("<f8", (3,)),
    "box_max": ("<f8", (3,)),
    "sphere_center": ("<f8", (3,)),
    "sphere_radius": ("<f8", ()),
    "error": ("<f8", ()),
    "cube_side": ("<f8", ()),
    "tri_offset": ("<i8", ()),
    "tri_count": ("<i8", ()),
    "vertex_offset": ("<i8", ()),
    "vertex_count": ("<i8", ()),
}


@dataclass(frozen=True, eq=False)
class Hlod:
    """A baked HLOD.

    Node table (n rows): see NODE_ARRAYS for dtypes.
      parent (n,) int32, -1 for the root; child_offset/child_count (n,) int32; depth (n,) int32,
      root 0; lod_box_min/max (n,3) float64: tight box of the node's own LOD geometry;
      box_min/max (n,3) float64: tight box of the LOD and all descendants (nested);
      sphere_center (n,3), sphere_radius (n,) float64: contains the LOD and the children's spheres;
      error (n,) float64: model-space error (MSE), model units, 0 at leaves, monotone up the tree;
      cube_side (n,) float64: side of the cube with the (padded) box's volume, model units;
      tri_offset/tri_count, vertex_offset/vertex_count (n,) int64: ranges into the buffers.
    Geometry: origin (3,) float64; positions (v,3) float32 relative to origin;
      indices (t,3) uint32 global rows of positions; normals (v,3) float32 or None.
    Appearance (None / empty when the scene has none): uvs (v,2) float32, colors (v,4) float32,
      tri_material (t,) uint16, materials: tuple of appearance.Material.
    meta: JSON-serialisable bake description (target_tris, max_depth, input_tris, sources, ...).
    """

    parent: np.ndarray
    child_offset: np.ndarray
    child_count: np.ndarray
    depth: np.ndarray
    lod_box_min: np.ndarray
    lod_box_max: np.ndarray
    box_min: np.ndarray
    box_max: np.ndarray
    sphere_center: np.ndarray
    sphere_radius: np.ndarray
    error: np.ndarray
    cube_side: np.ndarray
    tri_offset: np.ndarray
    tri_count: np.ndarray
    vertex_offset: np.ndarray
    vertex_count: np.ndarray
    origin: np.ndarray
    positions: np.ndarray
    indices: np.ndarray
    normals: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    uvs: np.ndarray | None = None
    colors: np.ndarray | None = None
    tri_material: np.ndarray | None = None
    materials: tuple = ()

    @property
    def node_count(self) -> int:
        return int(self.parent.shape[0])

    @property
    def is_leaf(self) -> np.ndarray:
        """(n,) bool."""
        return self.child_count == 0

    def node_arrays(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in NODE_ARRAYS}

    @property
    def has_appearance(self) -> bool:
        return self.uvs is not None or self.colors is not None or self.tri_material is not None

    def draw_parts(self) -> "DrawParts":
        """One ranged draw per (node, material run); computed once per call, vectorised."""
        n = self.node_count
        offset = np.asarray(self.tri_offset, np.int64)
        count = np.asarray(self.tri_count, np.int64)
        if self.tri_material is None:
            return DrawParts(first=np.arange(n, dtype=np.int64), count=np.ones(n, np.int64),
                             material=np.full(n, -1, np.int32), tri_offset=offset, tri_count=count)
        rows = segment_ranges(offset, count)  # every node's triangles, node after node
        node = np.repeat(np.arange(n, dtype=np.int64), count)
        material = np.asarray(self.tri_material, np.int64)[rows]
        start = np.ones(rows.shape[0], bool)
        start[1:] = (node[1:] != node[:-1]) | (material[1:] != material[:-1]) | (rows[1:] != rows[:-1] + 1)
        at = np.flatnonzero(start)
        ends = np.append(at[1:], rows.shape[0])
        part_node = node[at]
        return DrawParts(first=np.searchsorted(part_node, np.arange(n)).astype(np.int64),
                         count=np.bincount(part_node, minlength=n).astype(np.int64),
                         material=material[at].astype(np.int32), tri_offset=rows[at],
                         tri_count=(ends - at).astype(np.int64))

    def replace(self, **changes) -> "Hlod":
        return dataclasses.replace(self, **changes)

    def summary(self) -> dict:
        """Counts shared by `bake` and `info` (docs/how-it-works.md#the-bake; the CLI's JSON contract)."""
        leaves = self.is_leaf
        return {
            "nodes": self.node_count,
            "leaves": int(leaves.sum()),
            "depth": int(self.depth.max()),
            "input_tris": int(self.meta.get("input_tris", -1)),
            "leaf_tris": int(self.tri_count[leaves].sum()),
            "root_tris": int(self.tri_count[0]),
            "total_tris": int(self.indices.shape[0]),
            "max_error": float(self.error.max()),
            "nodes_over_budget": int(self.meta.get("nodes_over_budget", 0)),
            "pruned_pieces": int(self.meta.get("pruned_pieces", 0)),
            "pruned_tris": int(self.meta.get("pruned_tris", 0)),
        }


@dataclass(frozen=True, eq=False)
class DrawParts:
    """Draw ranges: node i draws parts first[i] .. first[i] + count[i] - 1; part j is triangles
    tri_offset[j] .. tri_offset[j] + tri_count[j] - 1 in material material[j] (-1: no material table)."""

    first: np.ndarray
    count: np.ndarray
    material: np.ndarray
    tri_offset: np.ndarray
    tri_count: np.ndarray


def cube_sides(box_min: np.ndarray, box_max: np.ndarray, pad: float) -> np.ndarray:
    """Side of the cube with the volume of each box enlarged by `pad` on every face
    (docs/how-it-works.md#alpha-three-ways).

    box_min, box_max: (n,3) float64; pad: model units. Returns (n,) float64 > 0 when pad > 0.
    """
    extent = (box_max - box_min) + 2.0 * pad
    return np.cbrt(np.prod(extent, axis=1))


@dataclass(frozen=True, eq=False)
class NodeGeometry:
    """One node's triangles as a standalone mesh: positions (v,3) float32 relative to hlod.origin,
    faces (t,3) int64 local indices, normals/uvs/colors per vertex or None, face_material (t,)
    int32 or None (triangles sorted by material, as in the file)."""

    positions: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None
    uvs: np.ndarray | None
    colors: np.ndarray | None
    face_material: np.ndarray | None


def node_geometry(hlod: Hlod, node: int) -> NodeGeometry:
    """One node's own LOD (or leaf) triangles as a standalone mesh (NodeGeometry): the vertices its
    triangles use, renumbered in the order of their rows in the shared buffer."""
    return nodes_geometry(hlod, [node])


def nodes_geometry(hlod: Hlod, nodes) -> NodeGeometry:
    """Several nodes' own triangles as one standalone mesh (node_geometry's, the nodes' triangles in
    the order given): what a 3D Tiles tile of several leaves holds."""
    spans = [(int(hlod.tri_offset[n]), int(hlod.tri_count[n])) for n in nodes]
    rows = np.concatenate([np.asarray(hlod.indices[a:a + k], np.int64) for a, k in spans])
    used, local = np.unique(rows, return_inverse=True)

    def per_vertex(arr):
        return None if arr is None else np.asarray(arr[used], np.float32)

    material = None if hlod.tri_material is None else np.concatenate(
        [np.asarray(hlod.tri_material[a:a + k], np.int32) for a, k in spans])
    return NodeGeometry(positions=np.asarray(hlod.positions[used], np.float32), faces=local.reshape(-1, 3),
                        normals=per_vertex(hlod.normals), uvs=per_vertex(hlod.uvs), colors=per_vertex(hlod.colors),
                        face_material=material)


def query_box_pad(box_min: np.ndarray, box_max: np.ndarray) -> float:
    """Query-box enlargement (model units) for an HLOD whose root box is row 0."""
    diag = float(np.linalg.norm(box_max[0] - box_min[0]))
    return QUERY_BOX_PAD_FRACTION * diag if diag > 0 else QUERY_BOX_PAD_FRACTION

