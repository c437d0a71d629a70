"""Assemble the baked nodes into the file's arrays (hierarchy.Hlod): one vertex and one index
buffer with each node's ranges, the appearance arrays from the attribute rows (each node's
triangles sorted by material: one draw per (node, material)), and the bounds, vectorised per
level: tight nested boxes, nested spheres, monotone errors, cube sides.

Data form in: lods, per node (positions (k,3) f32 origin-relative, faces (m,3) int32 local,
normals (k,3) f32 or None, attribute rows (k,A) f32 or None; any of them may be spilled to the
bake's scratch file, run/lod_spill.py, and is read back a block of nodes at a time); errors (n,)
float64 model units.
Bounds are float64 world coordinates (positions + origin), computed a block of nodes at a time.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from ..io import hlod_file
from ..model import appearance
from ..model.hierarchy import NODE_ARRAYS, Hlod, cube_sides, query_box_pad
from .run.lod_spill import loaded
from .space.octree import OctreeLayout

#: Vertices `assemble` handles at a time (whole nodes; a node of more vertices is one block): the
#: block it turns into float64 world coordinates for the bounds, and the geometry rows it makes and
#: writes at a time; its working memory, about 24 bytes a vertex and a few copies.
BLOCK_VERTICES = 1 << 18


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


def _block_world(lods, origin, *, vertex_offset, first: int, last: int):
    """The vertices of nodes first..last-1 as float64 world coordinates (their float32 positions +
    origin), and each node's start in them (for reduceat)."""
    world = np.concatenate([loaded(lod[0]) for lod in lods[first:last]]).astype(np.float32, copy=False)
    world = world.astype(np.float64)
    world += origin
    return world, vertex_offset[first:last] - vertex_offset[first]


@dataclass(eq=False)
class Assembled:
    """The baked nodes as the file holds them (hierarchy.Hlod): the node table (`table`: NODE_ARRAYS'
    arrays) and origin (3,) float64 in memory, the geometry made from `lods` a block of nodes at a
    time (`blocks`): the same rows whether they go into arrays in memory (`hlod`) or straight into
    the file (`write`, io.hlod_file.StreamedWriter), never the whole buffers at once."""

    table: dict[str, np.ndarray]
    origin: np.ndarray
    lods: list
    normals: bool
    row_layout: appearance.AttributeLayout

    def shapes(self) -> dict[str, tuple[int, ...]]:
        """Every array's shape, in the file's order (io/hlod_file.py)."""
        vertices, tris = int(self.table["vertex_count"].sum()), int(self.table["tri_count"].sum())
        shapes = {name: array.shape for name, array in self.table.items()}
        shapes.update(origin=(3,), positions=(vertices, 3), indices=(tris, 3))
        columns = {} if self.row_layout.empty else self.row_layout.columns()
        optional = {"normals": ((vertices, 3), self.normals), "uvs": ((vertices, 2), "uv" in columns),
                    "colors": ((vertices, 4), "color" in columns), "tri_material": ((tris,), "material" in columns)}
        shapes.update({name: shape for name, (shape, present) in optional.items() if present})
        return shapes

    def blocks(self):
        """Yield, for each run of nodes of about BLOCK_VERTICES vertices, their rows of every
        geometry array (name -> rows): positions float32, indices uint32 (global), normals, uvs,
        colors, and tri_material uint16 with each node's triangles sorted by material (stable)."""
        offsets = self.table["vertex_offset"]
        for first, last in _vertex_blocks(offsets, self.table["vertex_count"]):
            lods = [tuple(loaded(a) for a in lod) for lod in self.lods[first:last]]  # spilled ones read back
            rows = {"positions": np.concatenate([lod[0] for lod in lods]).astype(np.float32, copy=False)}
            if self.normals:
                rows["normals"] = np.concatenate([lod[2] for lod in lods]).astype(np.float32, copy=False)
            indices, materials, uvs, colors = [], [], [], []
            for lod, start in zip(lods, offsets[first:last]):
                faces = np.asarray(lod[1]).astype(np.uint32)
                faces += np.uint32(start)
                if not self.row_layout.empty:
                    uv, color, face_material = appearance.unpack(self.row_layout, lod[3], lod[1])
                    uvs.append(uv)
                    colors.append(color)
                    if face_material is not None:
                        order = np.argsort(face_material, kind="stable")
                        faces, face_material = faces[order], face_material[order].astype(np.uint16)
                        materials.append(face_material)
                indices.append(faces)
            rows["indices"] = np.concatenate(indices)
            for name, parts in (("uvs", uvs), ("colors", colors), ("tri_material", materials)):
                if parts and parts[0] is not None:
                    rows[name] = np.concatenate(parts)
            yield rows

    def hlod(self, *, meta: dict | None = None, materials: tuple = ()) -> Hlod:
        """The Hlod in memory."""
        shapes = self.shapes()
        geometry = {name: np.empty(shapes[name], HLOD_DTYPES[name]) for name in GEOMETRY if name in shapes}
        done = dict.fromkeys(geometry, 0)
        for rows in self.blocks():
            for name, part in rows.items():
                geometry[name][done[name]:done[name] + part.shape[0]] = part
                done[name] += part.shape[0]
        return Hlod(**self.table, origin=np.asarray(self.origin, np.float64), meta=meta or {}, materials=materials,
                    **geometry)

    def write(self, path, *, meta: dict, materials: tuple = ()) -> None:
        """Write the file to `path` a block of nodes at a time (io.hlod_file.StreamedWriter: atomic,
        no file left by a failed write): the bytes hlod_file.save(self.hlod(meta=..., ...)) writes."""
        with hlod_file.StreamedWriter(path, self.shapes(), meta=meta, materials=materials) as out:
            for name, array in self.table.items():
                out.append(name, array)
            out.append("origin", np.asarray(self.origin, np.float64))
            for rows in self.blocks():
                for name, part in rows.items():
                    out.append(name, part)


#: The geometry arrays, in the file's order, and their dtypes in an Hlod.
GEOMETRY = ("positions", "indices", "normals", "uvs", "colors", "tri_material")
HLOD_DTYPES = {"positions": np.float32, "indices": np.uint32, "normals": np.float32, "uvs": np.float32,
               "colors": np.float32, "tri_material": np.uint16}


def assemble(layout: OctreeLayout, lods, origin, *, hausdorff_error: np.ndarray, normals: bool,
             row_layout: appearance.AttributeLayout) -> Assembled:
    """The file of the baked nodes (Assembled: its node table made here, its geometry a block at a
    time when it is written): lods per node (module docstring), origin (3,) float64,
    hausdorff_error (n,) float64 (NaN: unavailable, bounded by the node's box diagonal; leaves 0);
    normals: the LODs carry them; row_layout: the rows' columns (empty: none). InputError for an
    empty LOD or more vertices than 32-bit indices address."""
    vertex_count = np.array([lod[0].shape[0] for lod in lods], np.int64)
    tri_count = np.array([lod[1].shape[0] for lod in lods], np.int64)
    if np.any(tri_count == 0):
        raise InputError("a node's LOD came out empty (pymeshlab removed every triangle)")
    vertex_offset = np.concatenate([[0], np.cumsum(vertex_count)[:-1]])
    tri_offset = np.concatenate([[0], np.cumsum(tri_count)[:-1]])
    if vertex_count.sum() >= 2**32:
        raise InputError(f"the HLOD would need {int(vertex_count.sum())} vertices, more than 32-bit indices address")
    bounds = _bounds(layout, lods, origin, vertex_offset=vertex_offset, vertex_count=vertex_count,
                     hausdorff_error=hausdorff_error)
    table = dict(parent=layout.parent, child_offset=layout.child_offset, child_count=layout.child_count,
                 depth=layout.depth, **bounds, tri_offset=tri_offset, tri_count=tri_count, vertex_offset=vertex_offset,
                 vertex_count=vertex_count)
    return Assembled(table={name: table[name] for name in NODE_ARRAYS}, origin=np.asarray(origin, np.float64),
                     lods=lods, normals=normals, row_layout=row_layout)


def _bounds(layout: OctreeLayout, lods, origin, *, vertex_offset: np.ndarray,
            vertex_count: np.ndarray, hausdorff_error: np.ndarray) -> dict[str, np.ndarray]:
    """The node table's bounds (float64, world coordinates): LOD boxes, subtree boxes nested
    deepest level first, spheres around them that contain their children's, errors made monotone
    (unavailable ones bounded by the box diagonal), cube sides."""
    n = layout.node_count
    blocks = _vertex_blocks(vertex_offset, vertex_count)
    lod_box_min = np.empty((n, 3), np.float64)
    lod_box_max = np.empty((n, 3), np.float64)
    for first, last in blocks:
        world, starts = _block_world(lods, origin, vertex_offset=vertex_offset, first=first, last=last)
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
        world, starts = _block_world(lods, origin, vertex_offset=vertex_offset, first=first, last=last)
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
