"""Assemble the baked nodes into the file's arrays (hierarchy.Hlod): one vertex and one index
buffer with each node's ranges, the appearance arrays from the attribute rows (each node's
triangles sorted by material: one draw per (node, material)), and the bounds, vectorised per
level: tight nested boxes, nested spheres, monotone errors, cube sides.

Data form in: lods, per node (positions (k,3) f32 origin-relative, faces (m,3) int32 local,
normals (k,3) f32 or None, attribute rows (k,A) f32 or None); errors (n,) float64 model units.
Bounds are float64 world coordinates (positions + origin), computed a block of nodes at a time.
"""
from __future__ import annotations

import numpy as np

from ..core.errors import InputError
from ..model import appearance
from ..model.hierarchy import Hlod, cube_sides, query_box_pad
from .space.octree import OctreeLayout

#: Vertices `assemble` turns into float64 world coordinates at a time (whole nodes; a node of more
#: vertices is one block): its working memory, 24 bytes a vertex and a few copies.
BLOCK_VERTICES = 1 << 20


def _concat_nodes(lods, vertex_offset: np.ndarray, tri_offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """concat_indexed of the nodes' (positions, faces), written straight into the file's arrays:
    positions (V,3) float32 and indices (F,3) uint32 (V < 2**32, checked by the caller)."""
    vertices = int(vertex_offset[-1]) + lods[-1][0].shape[0]
    tris = int(tri_offset[-1]) + lods[-1][1].shape[0]
    positions = np.empty((vertices, 3), np.float32)
    indices = np.empty((tris, 3), np.uint32)
    for lod, v, t in zip(lods, vertex_offset, tri_offset):
        positions[v:v + lod[0].shape[0]] = lod[0]
        indices[t:t + lod[1].shape[0]] = lod[1]
        indices[t:t + lod[1].shape[0]] += np.uint32(v)
    return positions, indices


def _vertex_blocks(vertex_offset: np.ndarray, vertex_count: np.ndarray) -> list[tuple[int, int]]:
    """Runs of consecutive nodes [first, last) of about BLOCK_VERTICES vertices each."""
    ends = vertex_offset + vertex_count
    out, first = [], 0
    n = vertex_count.shape[0]
    while first < n:
        last = int(np.searchsorted(ends, vertex_offset[first] + BLOCK_VERTICES, side="right"))
        last = max(last, first + 1)
        out.append((first, last))
        first = last
    return out


def _block_world(positions, origin, *, vertex_offset, vertex_count, first: int, last: int):
    """The vertices of nodes first..last-1 as float64 world coordinates (positions + origin), and
    each node's start in them (for reduceat)."""
    begin, end = int(vertex_offset[first]), int(vertex_offset[last - 1] + vertex_count[last - 1])
    world = positions[begin:end].astype(np.float64)
    world += origin
    return world, vertex_offset[first:last] - begin


def assemble(layout: OctreeLayout, lods, origin, *, hausdorff_error: np.ndarray, normals: bool,
             row_layout: appearance.AttributeLayout) -> Hlod:
    """The Hlod of the baked nodes: lods per node (module docstring), origin (3,) float64,
    hausdorff_error (n,) float64 (NaN: unavailable, bounded by the node's box diagonal; leaves 0);
    normals: the LODs carry them; row_layout: the rows' columns (empty: none). InputError for an
    empty LOD or more vertices than 32-bit indices address."""
    n = layout.node_count
    vertex_count = np.array([lod[0].shape[0] for lod in lods], np.int64)
    tri_count = np.array([lod[1].shape[0] for lod in lods], np.int64)
    if np.any(tri_count == 0):
        raise InputError("a node's LOD came out empty (pymeshlab removed every triangle)")
    vertex_offset = np.concatenate([[0], np.cumsum(vertex_count)[:-1]])
    tri_offset = np.concatenate([[0], np.cumsum(tri_count)[:-1]])
    if vertex_count.sum() >= 2**32:
        raise InputError(f"the HLOD would need {int(vertex_count.sum())} vertices, more than 32-bit indices address")
    positions, indices = _concat_nodes(lods, vertex_offset, tri_offset)
    node_normals = np.concatenate([lod[2] for lod in lods]).astype(np.float32) if normals else None
    uvs = colors = tri_material = None
    if not row_layout.empty:
        uvs, colors, face_material = appearance.unpack(row_layout, np.concatenate([lod[3] for lod in lods]), indices)
        if face_material is not None:
            order = np.lexsort((face_material, np.repeat(np.arange(n), tri_count)))  # node, then material
            indices, tri_material = indices[order], face_material[order].astype(np.uint16)

    bounds = _bounds(layout, positions, origin, vertex_offset=vertex_offset, vertex_count=vertex_count,
                     hausdorff_error=hausdorff_error)
    return Hlod(parent=layout.parent, child_offset=layout.child_offset, child_count=layout.child_count,
                depth=layout.depth, **bounds, tri_offset=tri_offset, tri_count=tri_count, vertex_offset=vertex_offset,
                vertex_count=vertex_count, origin=np.asarray(origin, np.float64), positions=positions,
                indices=indices, normals=node_normals, uvs=uvs, colors=colors, tri_material=tri_material)


def _bounds(layout: OctreeLayout, positions: np.ndarray, origin, *, vertex_offset: np.ndarray,
            vertex_count: np.ndarray, hausdorff_error: np.ndarray) -> dict[str, np.ndarray]:
    """The node table's bounds (float64, world coordinates): LOD boxes, subtree boxes nested
    deepest level first, spheres around them that contain their children's, errors made monotone
    (unavailable ones bounded by the box diagonal), cube sides."""
    n = layout.node_count
    blocks = _vertex_blocks(vertex_offset, vertex_count)
    lod_box_min = np.empty((n, 3), np.float64)
    lod_box_max = np.empty((n, 3), np.float64)
    for first, last in blocks:
        world, starts = _block_world(positions, origin, vertex_offset=vertex_offset, vertex_count=vertex_count,
                                     first=first, last=last)
        lod_box_min[first:last] = np.minimum.reduceat(world, starts, axis=0)
        lod_box_max[first:last] = np.maximum.reduceat(world, starts, axis=0)
    box_min, box_max = lod_box_min.copy(), lod_box_max.copy()
    levels = [np.flatnonzero(layout.depth == d) for d in range(int(layout.depth.max()), 0, -1)]
    for nodes in levels:  # deepest first: a child's subtree box is final before its parent's
        np.minimum.at(box_min, layout.parent[nodes], box_min[nodes])
        np.maximum.at(box_max, layout.parent[nodes], box_max[nodes])
    center = 0.5 * (box_min + box_max)
    # |world - centre of its node| per vertex, max per node: sqrt((dx^2 + dy^2) + dz^2) as
    # np.linalg.norm sums it, and the max taken before the root (sqrt is monotone: the same float)
    radius = np.empty(n, np.float64)
    for first, last in blocks:
        world, starts = _block_world(positions, origin, vertex_offset=vertex_offset, vertex_count=vertex_count,
                                     first=first, last=last)
        world -= np.repeat(center[first:last], vertex_count[first:last], axis=0)
        world *= world
        squared = world[:, 0] + world[:, 1]
        squared += world[:, 2]
        radius[first:last] = np.sqrt(np.maximum.reduceat(squared, starts))
    del world, squared
    diag = np.linalg.norm(box_max - box_min, axis=1)
    error = np.where(np.isfinite(hausdorff_error), hausdorff_error, diag)
    error[layout.is_leaf] = 0.0
    for nodes in levels:
        parents = layout.parent[nodes]
        np.maximum.at(radius, parents, np.linalg.norm(center[nodes] - center[parents], axis=1) + radius[nodes])
        np.maximum.at(error, parents, error[nodes])
    return {"lod_box_min": lod_box_min, "lod_box_max": lod_box_max, "box_min": box_min, "box_max": box_max,
            "sphere_center": center, "sphere_radius": radius, "error": error,
            "cube_side": cube_sides(box_min, box_max, query_box_pad(box_min, box_max))}
