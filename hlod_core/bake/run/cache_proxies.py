"""The proxy materials in the bake cache (cache.py): what a node entry holds of them, and how a hit
gets them back in a bake whose node numbers differ (an edit elsewhere renumbers the octree).

Data form: in the bake's rows a proxy's material id is proxy.proxy_material_id(node, alpha), past
the scene's materials; it names the node that made the proxy, the node itself or a descendant
whose proxy it kept. In an entry that id is -(1 + 2 j + alpha), j indexing the entry's
"proxy_paths": the path from the entry's node down to the proxy's node as child indices ([] for
the node itself), which a hit walks in the new bake's octree. An entry of a node that made a proxy
holds its texture (the PNG bytes the bake wrote, array "proxy_png" (b,) uint8) and its
proxy_plan.ProxyMade fields but the file (extra "proxy"); the texture's bytes count in the
folder's budget like every other entry's.

A whole result (`result_parts`, `result_proxies`) holds every texture the bake wrote, node by node
(the octree is the same: it is keyed by the input and its frame), as arrays "proxy_png_<i>" (b,)
uint8 with extra "proxy_result": {"textures": [[node, ProxyMade fields but the file], ...], "materials":
the proxy materials' JSON with their texture's file name alone, "meta": meta["proxies"] or None}.
A hit writes the textures into this bake's folder and names them from there (the folder a file's
materials name differs by output), so its file and textures are those of a bake from scratch.
Why: docs/how-it-works.md#proxy-materials-in-the-cache
"""
from __future__ import annotations

import dataclasses
import math
import struct
from pathlib import Path

import numpy as np

from ...core.errors import InputError
from ...model.appearance import Material
from ..appearance.proxy import proxy_of_id
from ..appearance.proxy_plan import ProxyMade, ProxyPlan, proxy_image_name
from ..space.octree import OctreeLayout
from .cache_files import CorruptEntry

#: The entry's extra keys and array of the proxies (module docstring).
PATHS, FIELDS, PNG = "proxy_paths", "proxy", "proxy_png"
#: A whole result's extra key of its proxies (module docstring).
RESULT = "proxy_result"
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_ALPHA_MODES = (None, "MASK", "BLEND")


def encode(rows: np.ndarray, node: int, layout: OctreeLayout, *, scene_materials: int,
           column: int) -> tuple[np.ndarray, list[list[int]]]:
    """(rows (k,A) float32 with the proxies' ids made relative to `node`, the paths they index);
    ValueError when a row names the proxy of a node outside node's subtree (never: a node keeps
    only its own or a descendant's)."""
    ids = rows[:, column].astype(np.int64)
    proxied = ids >= scene_materials
    if not proxied.any():
        return rows, []
    owners, alpha = proxy_of_id(ids[proxied], scene_materials=scene_materials)
    unique, local = np.unique(owners, return_inverse=True)
    paths = [_path(int(owner), node, layout) for owner in unique]
    out = rows.copy()
    out[proxied, column] = -(1 + 2 * local.reshape(-1) + alpha)
    return out, paths


def _path(owner: int, node: int, layout: OctreeLayout) -> list[int]:
    path = []
    while owner != node:
        parent = int(layout.parent[owner])
        if parent < 0:
            raise ValueError(f"the proxy of node {owner} is not below node {node}")
        path.append(owner - int(layout.child_offset[parent]))
        owner = parent
    return path[::-1]


def decode(rows: np.ndarray, paths, node: int, layout: OctreeLayout, *, scene_materials: int,
           column: int) -> np.ndarray:
    """The entry's rows with the bake's proxy ids of the nodes its paths lead to from `node` in this
    bake's octree (encode's inverse); CorruptEntry for an id or a path that leads nowhere."""
    ids = rows[:, column]
    if not np.all((ids == np.round(ids)) & (ids < scene_materials)):
        raise CorruptEntry("a row's material is not a material of this bake")
    local = ids < 0
    if not local.any():
        return rows
    code = (-ids[local]).astype(np.int64) - 1
    if not isinstance(paths, list) or int(code.max()) >= 2 * len(paths):
        raise CorruptEntry("a proxy id without its path")
    owners = np.array([_follow(path, node, layout) for path in paths], np.int64)
    out = rows.copy()
    out[local, column] = scene_materials + 2 * owners[code // 2] + code % 2
    return out


def _follow(path, node: int, layout: OctreeLayout) -> int:
    if not isinstance(path, list):
        raise CorruptEntry(f"proxy path {path!r}")
    for step in path:
        if not isinstance(step, int) or not 0 <= step < int(layout.child_count[node]):
            raise CorruptEntry(f"proxy path {path!r} leaves the subtree")
        node = int(layout.child_offset[node]) + step
    return node


def own_extra(made: ProxyMade) -> dict:
    """The entry's "proxy" extra: the ProxyMade fields but the file (named per bake and node)."""
    return {"width": int(made.width), "height": int(made.height), "texel_size": float(made.texel_size),
            "utilization": float(made.utilization), "alpha_mode": made.alpha_mode, "psnr_y": float(made.psnr_y),
            "psnr_reason": made.psnr_reason}


def own_proxy(extra: dict, arrays: dict) -> tuple[dict, bytes] | None:
    """(ProxyMade fields but the file, PNG bytes) of an entry whose node made a proxy, checked
    (the PNG's signature and size against the fields); None where it made none; CorruptEntry."""
    fields, png = extra.get(FIELDS), arrays.get(PNG)
    if fields is None and png is None:
        return None
    if not isinstance(fields, dict) or png is None or png.dtype != np.uint8 or png.ndim != 1:
        raise CorruptEntry("a proxy without its texture or fields")
    names = {f.name for f in dataclasses.fields(ProxyMade)} - {"file"}
    if set(fields) != names:
        raise CorruptEntry(f"proxy fields {sorted(fields)}")
    data = png.tobytes()
    width, height = fields["width"], fields["height"]
    if not (isinstance(width, int) and isinstance(height, int) and width > 0 and height > 0) \
            or len(data) < 24 or data[:8] != _PNG_SIGNATURE or struct.unpack(">II", data[16:24]) != (width, height):
        raise CorruptEntry(f"proxy texture of {len(data)} bytes is not a {width}x{height} PNG")
    numbers = [fields[k] for k in ("texel_size", "utilization", "psnr_y")]
    if not all(isinstance(v, (int, float)) for v in numbers) or not math.isfinite(fields["texel_size"]) \
            or fields["alpha_mode"] not in _ALPHA_MODES or not isinstance(fields["psnr_reason"], (str, type(None))):
        raise CorruptEntry(f"proxy fields {fields}")
    return fields, data


def result_parts(plan: ProxyPlan, materials: tuple, proxies_meta: dict | None) -> tuple[dict, dict]:
    """(extra, arrays) of a whole result's proxies: every texture `plan` wrote, the proxy materials
    (`materials` past the scene's) and meta["proxies"] (None where the bake made none)."""
    nodes = sorted(plan.made_proxies)
    arrays = {f"{PNG}_{i}": np.frombuffer(plan.texture_bytes(node), np.uint8) for i, node in enumerate(nodes)}
    own = []
    for material in materials[len(plan.scene_materials):]:
        value = material.to_json()
        value["texture"], value["image"] = Path(material.texture).name, None
        own.append(value)
    textures = [[int(node), own_extra(plan.made_proxies[node])] for node in nodes]
    return {RESULT: {"textures": textures, "materials": own, "meta": proxies_meta}}, arrays


def result_proxies(extra: dict, arrays: dict, *,
                   reference: Path) -> tuple[list[tuple[int, dict, bytes]], tuple[Material, ...], dict | None]:
    """A whole result's proxies, checked, their arrays taken out of `arrays`: ([(node, ProxyMade
    fields but the file, PNG bytes)], the proxy materials naming their textures in `reference` (the
    folder this bake's file names), meta["proxies"] or None); CorruptEntry. The caller checks the
    nodes against the result's octree."""
    part = extra.get(RESULT)
    if not isinstance(part, dict) or set(part) != {"textures", "materials", "meta"} \
            or not isinstance(part["textures"], list) or not isinstance(part["materials"], list) \
            or not isinstance(part["meta"], (dict, type(None))):
        raise CorruptEntry("a whole result without its proxies")
    textures = []
    for i, item in enumerate(part["textures"]):
        if not (isinstance(item, list) and len(item) == 2 and isinstance(item[0], int) and item[0] >= 0):
            raise CorruptEntry(f"proxy texture {i}: {item!r:.80}")
        found = own_proxy({FIELDS: item[1]}, {PNG: arrays.pop(f"{PNG}_{i}", None)})
        if found is None:
            raise CorruptEntry(f"proxy texture {i} without its fields")
        textures.append((item[0], *found))
    if len({node for node, _, _ in textures}) != len(textures) or any(name.startswith(PNG) for name in arrays):
        raise CorruptEntry("proxy textures named twice or without their fields")
    materials = []
    for i, value in enumerate(part["materials"]):
        name = value.get("texture") if isinstance(value, dict) else None
        if not isinstance(name, str) or name != Path(name).name or name in ("", ".", ".."):
            raise CorruptEntry(f"proxy material {i}: texture {name!r:.80}")
        try:
            material = Material.from_json(value, where=f"proxy material {i}")
        except InputError as exc:
            raise CorruptEntry(str(exc)) from None
        file = str(reference / name)
        materials.append(dataclasses.replace(material, texture=file, image=proxy_image_name(file)))
    return textures, tuple(materials), part["meta"]
