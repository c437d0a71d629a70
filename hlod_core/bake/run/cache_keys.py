"""The bake cache's keys (cache.py): what a node entry, an input and a whole result are keyed by.

Keys (blake2b, 32 bytes) are a Merkle tree over the octree (`node_keys`): a leaf's key hashes its
triangles as the bake sees them (origin-relative lattice points) and, in a bake that makes proxy
materials, the looks of the materials its rows use (`material_digests`: their fields and their
texture images' pixels); an inner node's, its children's keys; both hash the lattice (origin and
unit) and `context_digest` (the formats, every setting that changes a LOD, an error or a proxy, the
versions of pymeshlab and numpy, and the source of RESULT_MODULES). Equal keys mean equal results.
A whole input's key (`input_key`) hashes the mesh's arrays and materials and, with proxy
materials, the same digests of every material; `result_key` adds the frame.
No key holds a cell or its level: a root cube that grew puts the same subtrees one level down.
Why: docs/how-it-works.md#re-bakes-and-the-cache-keys
"""
from __future__ import annotations

import dataclasses
import hashlib
import importlib.metadata
import json
from pathlib import Path

import numpy as np

from ...io import hlod_file
from ...model.appearance import AttributeLayout
from ..appearance.proxy import ProxySettings
from ..decimate.meshlab import DecimationSettings
from ..space.frame import Frame
from ..space.octree import OctreeLayout
from . import cache_files
from .cache_files import KEY_BYTES

#: Modules whose code computes LODs, errors or the result's arrays and meta (their source is part
#: of every key: editing one retires every entry).
RESULT_MODULES = ("bake.decimate.simplify", "bake.decimate.collapse", "bake.decimate.meshlab",
                  "bake.decimate.seams", "bake.decimate.cell_seams", "bake.decimate.pieces",
                  "bake.measure.hausdorff", "model.appearance", "model.hierarchy", "core.arrays",
                  "bake.space.octree", "bake.settings", "bake.prepare", "bake.sources",
                  "bake.space.partition", "bake.measure.leaf_arrays", "bake.run.tasks",
                  "bake.run.schedule", "bake.space.octree_passes", "bake.assemble", "bake.meta",
                  "bake.pipeline", "bake.run.cache", "bake.run.cache_files", "bake.space.lattice",
                  "bake.run.cache_keys", "bake.run.cache_proxies", "bake.space.frame",
                  "bake.space.root_cube", "bake.appearance.proxy", "bake.appearance.atlas",
                  "bake.appearance.texels", "bake.appearance.surface_colour",
                  "bake.appearance.quality", "bake.appearance.proxy_task",
                  "bake.appearance.proxy_plan", "core.cpu_raster", "core.colour", "core.png",
                  "io.textures")


def context_digest(settings: DecimationSettings, *, with_normals: bool,
                   row_layout: AttributeLayout | None, error: str = "exact",
                   proxies: ProxySettings | None = None) -> bytes:
    """32 bytes: everything besides a subtree's triangles that its LODs and errors depend on;
    error: the error measure (BakeSettings.error), so a bound is never served for an exact error
    nor the other way round; proxies: the proxy materials' settings of a bake that makes them
    (texture cap and floor, tau; None: a bake without them, keep-materials included)."""
    core = Path(__file__).resolve().parents[2]
    code = hashlib.blake2b(digest_size=KEY_BYTES)
    for name in RESULT_MODULES:
        try:
            code.update((core / f"{name.replace('.', '/')}.py").read_bytes())
        except OSError:  # not installed as source files: the versions below still key it
            code.update(name.encode())
    described = {
        "cache_version": cache_files.CACHE_VERSION,
        "hlod_format": hlod_file.FORMAT_VERSION,
        "decimation": dataclasses.asdict(settings),
        "with_normals": bool(with_normals),
        "error": str(error),
        "proxies": None if proxies is None else dataclasses.asdict(proxies),
        "rows": None if row_layout is None or row_layout.empty else [row_layout.material, row_layout.uv,
                                                                     row_layout.color],
        "pymeshlab": _version("pymeshlab"),
        "numpy": np.__version__,
        "code": code.hexdigest(),
    }
    return hashlib.blake2b(json.dumps(described, sort_keys=True).encode(), digest_size=KEY_BYTES).digest()


def _version(package: str) -> str:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def _hash_array(h, part: np.ndarray | None) -> None:
    if part is None:
        h.update(b"\0")
        return
    part = np.ascontiguousarray(part)
    h.update(part.dtype.str.encode() + np.asarray(part.shape, "<i8").tobytes())
    h.update(memoryview(part).cast("B"))


def input_key(mesh, *, max_depth: int, context: bytes, looks: np.ndarray | None = None) -> bytes:
    """32 bytes keying a bake's whole input: the mesh's arrays and materials, max_depth and
    `context` (the settings and versions); looks: (materials, 32) uint8 `material_digests` in a bake
    that makes proxy materials (their textures' pixels: a texture re-painted under the same file
    name changes the key). `result_key` adds the frame."""
    h = hashlib.blake2b(context, digest_size=KEY_BYTES, person=b"hlod input")
    h.update(np.asarray([max_depth], "<i8").tobytes())
    for part in (mesh.positions, mesh.faces, mesh.normals, mesh.uvs, mesh.colors, mesh.material_ids):
        _hash_array(h, part)
    h.update(json.dumps([m.to_json() for m in mesh.materials], sort_keys=True).encode())
    if looks is not None:
        _hash_array(h, looks)
    return h.digest()


def result_key(input_digest: bytes, frame: Frame) -> bytes:
    """32 bytes keying a whole result: the input (`input_key`) baked in `frame`."""
    h = hashlib.blake2b(input_digest, digest_size=KEY_BYTES, person=b"hlod result")
    h.update(json.dumps(frame.to_meta(), sort_keys=True).encode())
    return h.digest()


def node_keys(layout: OctreeLayout, lods: list, *, origin: np.ndarray, context: bytes,
              unit_length: float = 0.0, seams=None, looks: tuple[int, np.ndarray] | None = None) -> list[bytes]:
    """(n,) 32-byte keys, one per node (module docstring). lods: per node (positions, faces,
    normals or None, attribute rows or None); only the leaves' are read; unit_length: the lattice
    the positions are points of (bake/space/lattice.py), which the decimations snap to; seams
    (cell_seams.CellSeams or None): an inner node's key hashes the positions it shares with the
    cells around it too, which its decimation keeps in place; looks: (the rows' material column,
    (materials, 32) uint8 `material_digests`) in a bake that makes proxy materials: a leaf's key
    hashes the digests of the materials its rows use, so a re-painted texture misses only the nodes
    above the leaves that show it."""
    n = layout.node_count
    keys: list[bytes] = [b""] * n
    # the stored positions' frame; not the cells: a LOD is made from the leaves' positions and the
    # tree's shape below it, whatever cell holds them (a grown root cube puts them one level down)
    lattice = np.array([*np.asarray(origin, np.float64).reshape(3), unit_length], "<f8").tobytes()
    for node in range(n - 1, -1, -1):  # children have larger ids than their parent
        if layout.child_count[node] == 0:
            h = hashlib.blake2b(context, digest_size=KEY_BYTES, person=b"hlod leaf")
            h.update(lattice)
            for part in lods[node]:
                _hash_array(h, part)
            if looks is not None:
                column, digests = looks
                h.update(digests[np.unique(lods[node][3][:, column]).astype(np.int64)].tobytes())
        else:
            h = hashlib.blake2b(context, digest_size=KEY_BYTES, person=b"hlod node")
            h.update(lattice)
            first = int(layout.child_offset[node])
            h.update(b"".join(keys[first:first + int(layout.child_count[node])]))
            if seams is not None:
                h.update(seams.digest(node))
        keys[node] = h.digest()
    return keys




def material_digests(materials: tuple, images: dict) -> np.ndarray:
    """(len(materials), 32) uint8: per material row a digest of what a proxy material reads of it,
    its fields (appearance.Material.to_json, but its name and its texture's path and image name: a
    texture folder that moves changes no proxy) and its texture image's pixels (images: row ->
    (h,w,4) uint8; a texture without an image is drawn in its base colour). An image shared by
    several rows (io.textures reads each path once) is hashed once."""
    out = np.zeros((len(materials), KEY_BYTES), np.uint8)
    pixels: dict[int, bytes] = {}
    for row, material in enumerate(materials):
        fields = {k: v for k, v in material.to_json().items() if k not in ("name", "texture", "image")}
        fields["textured"] = material.texture is not None
        h = hashlib.blake2b(json.dumps(fields, sort_keys=True).encode(), digest_size=KEY_BYTES, person=b"hlod look")
        image = images.get(row)
        if image is not None:
            if id(image) not in pixels:
                one = hashlib.blake2b(digest_size=KEY_BYTES)
                _hash_array(one, np.asarray(image))
                pixels[id(image)] = one.digest()
            h.update(pixels[id(image)])
        else:
            h.update(b"no image")
        out[row] = np.frombuffer(h.digest(), np.uint8)
    return out
