"""3D Tiles 1.1 export of a baked hierarchy: one tile per node, one GLB per node (`glb`).

Specification: OGC 3D Tiles 1.1 (tileset JSON, bounding volumes, geometricError, REPLACE
refinement, glTF content). The tileset is in the bake's model space (Z up, metres), translated by
the bake's float64 origin in the root's `transform`; a tile's geometricError is its node's
model-space error; its box the node's subtree box; attributes and materials only where the bake has
them; texture files copied once into `textures/` and referred to by every GLB; empty nodes left out.
Why: docs/how-it-works.md#3d-tiles-export

Data form: in, an Hlod; out, a folder tileset.json, tiles/<node>.glb, textures/ (when textured),
written into a temporary folder and put in place of an earlier export (`replace_export`).
"""
from __future__ import annotations

import json
import logging
import os
import shutil
import tempfile
from pathlib import Path
from urllib.parse import quote

import numpy as np

from ..core.atomic import replace_folder, umask_mode
from ..core.errors import InputError
from ..io.texture_folder import unique_file_name
from ..model.hierarchy import Hlod, node_geometry
from .glb import GENERATOR, TileImage, glb_bytes

log = logging.getLogger(__name__)

TILE_FOLDER, TEXTURE_FOLDER = "tiles", "textures"
#: The image formats of glTF 2.0 core, told by their first bytes: signature -> (mime type, suffix).
IMAGE_SIGNATURES = {b"\x89PNG\r\n\x1a\n": ("image/png", ".png"), b"\xff\xd8\xff": ("image/jpeg", ".jpg")}
#: Half sizes of the tiles' boxes are at least this fraction of the root diagonal (flat nodes), and
#: at least MIN_HALF_SIZE model units (a scene without extent).
MIN_HALF_SIZE_OF_DIAGONAL, MIN_HALF_SIZE = 1e-6, 1e-9


def copy_textures(hlod: Hlod, folder: Path) -> tuple[dict[str, TileImage], list[str]]:
    """Copy each distinct texture of the materials the HLOD's triangles use into `folder` (made
    here), once, under a unique name. Returns ({texture path: TileImage}, warnings); a texture that
    cannot be read or is not PNG/JPEG is left out with one warning naming it and its materials."""
    users = _texture_users(hlod)
    if not users:
        return {}, []
    if hlod.uvs is None:
        return {}, [f"3D Tiles export: the HLOD has no UVs; the textures of materials "
                    f"{', '.join(repr(n) for names in users.values() for n in names)} are left out"]
    images, warnings, names, by_file = {}, [], set(), {}
    for path, material_names in users.items():
        real = os.path.realpath(path)
        if real in by_file:  # the same file under another spelling
            images[path] = by_file[real]
            continue
        image = _copy_texture(path, folder, names=names, warnings=warnings, materials=material_names)
        if image is not None:
            images[path] = by_file[real] = image
    for line in warnings:
        log.warning("%s", line)
    return images, warnings


def _texture_users(hlod: Hlod) -> dict[str, list[str]]:
    """Texture path -> the names of the materials that use it, among the materials of the triangles."""
    if hlod.tri_material is None or not hlod.materials:
        return {}
    used = [hlod.materials[m] for m in np.unique(np.asarray(hlod.tri_material)).tolist()]
    users: dict[str, list[str]] = {}
    for material in used:
        if material.texture is not None:
            users.setdefault(material.texture, []).append(material.name)
    return users


def _copy_texture(path: str, folder: Path, *, names: set, warnings: list, materials: list[str]) -> TileImage | None:
    """Copy one texture file into `folder` under a name not in `names` (added to it); None, with a line
    in `warnings` naming it and its `materials`, when it cannot be read or is neither PNG nor JPEG."""
    which = f"material{'s' if len(materials) > 1 else ''} {', '.join(repr(n) for n in materials)}"
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        warnings.append(f"{path}: texture of {which} cannot be read ({exc.strerror or exc}); "
                        "exported without texture")
        return None
    kind = next((v for sig, v in IMAGE_SIGNATURES.items() if data.startswith(sig)), None)
    if kind is None:
        warnings.append(f"{path}: texture of {which} is neither PNG nor JPEG (glTF 2.0 has only those); "
                        "exported without texture")
        return None
    mime_type, suffix = kind
    name = unique_file_name(Path(path).stem, suffix, names)
    folder.mkdir(exist_ok=True)
    (folder / name).write_bytes(data)
    return TileImage(uri=f"../{TEXTURE_FOLDER}/{quote(name)}", mime_type=mime_type)


def _box(lo: np.ndarray, hi: np.ndarray, floor: float) -> list[float]:
    """3D Tiles' boundingVolume.box of an axis-aligned box: centre, then three half axes (columns),
    each half size at least `floor`."""
    centre, half = 0.5 * (lo + hi), np.maximum(0.5 * (hi - lo), floor)
    return [*centre.tolist(), half[0], 0.0, 0.0, 0.0, half[1], 0.0, 0.0, 0.0, half[2]]


def tileset(hlod: Hlod, content_uri) -> dict:
    """The tileset JSON; content_uri(node) names each node's GLB. InputError without triangles."""
    origin = np.asarray(hlod.origin, np.float64)
    lo_all, hi_all = hlod.box_min - origin, hlod.box_max - origin
    diagonal = float(np.linalg.norm(hi_all[0] - lo_all[0]))
    floor = max(MIN_HALF_SIZE_OF_DIAGONAL * diagonal, MIN_HALF_SIZE)

    def tile(node: int) -> dict | None:
        first, count = int(hlod.child_offset[node]), int(hlod.child_count[node])
        children = [t for t in (tile(c) for c in range(first, first + count)) if t is not None] if count else []
        if hlod.tri_count[node] == 0 and not children:
            return None  # an empty node is absent
        out = {"boundingVolume": {"box": _box(lo_all[node], hi_all[node], floor)},
               "geometricError": float(hlod.error[node])}
        if hlod.tri_count[node] > 0:
            out["content"] = {"uri": content_uri(node)}
        if children:
            out["children"] = children
        return out

    root = tile(0)
    if root is None:
        raise InputError("3D Tiles export: the hierarchy has no triangles")
    transform = np.eye(4)
    transform[:3, 3] = origin
    root["refine"] = "REPLACE"
    root["transform"] = transform.T.ravel().tolist()  # column-major
    return {"asset": {"version": "1.1", "generator": GENERATOR},
            "geometricError": max(diagonal, float(hlod.error[0])), "root": root}


def export(hlod: Hlod, out_dir: str | os.PathLike, *, platform: str | None = None) -> dict:
    """Write tileset.json, tiles/<node>.glb and, for textured materials, textures/ into out_dir,
    atomically: everything is written into a temporary folder beside it and renamed into place,
    replacing an earlier export (`replace_export`). Folders and files get the modes of ordinary
    ones (0o777 / 0o666 less the umask). `platform`: a sys.platform string (default this
    machine's) for replace_export.
    Returns a summary (tiles, glb files, triangles, bytes, image files, warnings)."""
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    try:
        os.chmod(staging, umask_mode(0o777))  # mkdtemp makes it 0700; the export is an ordinary folder
        images, warnings = copy_textures(hlod, staging / TEXTURE_FOLDER)
        written, tris, size = _write_tiles(hlod, staging / TILE_FOLDER, images=images)
        document = tileset(hlod, lambda node: f"{TILE_FOLDER}/{node}.glb")
        (staging / "tileset.json").write_text(json.dumps(document, indent=1))
        warnings = warnings + replace_export(out_dir, staging, platform=platform)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return {"format": "3dtiles", "output": str(out_dir), "tiles": _count(document["root"]), "glb_files": written,
            "triangles": tris, "bytes": size, "tileset_geometric_error": document["geometricError"],
            "image_files": len(set(images.values())), "warnings": warnings}


def _write_tiles(hlod: Hlod, folder: Path, *, images: dict[str, TileImage]) -> tuple[int, int, int]:
    """folder/<node>.glb for every node with triangles (folder made here); (files, triangles, bytes)."""
    folder.mkdir()
    written, tris, size = 0, 0, 0
    for node in np.flatnonzero(hlod.tri_count > 0).tolist():
        mesh = node_geometry(hlod, node)
        data = glb_bytes(mesh.positions, mesh.faces, mesh.normals, uvs=mesh.uvs, colors=mesh.colors,
                         face_material=mesh.face_material, materials=hlod.materials, images=images)
        (folder / f"{node}.glb").write_bytes(data)
        written, tris, size = written + 1, tris + mesh.faces.shape[0], size + len(data)
    return written, tris, size


def replace_export(out_dir: Path, staging: Path, *, platform: str | None = None) -> list[str]:
    """Put the export written in `staging` in out_dir's place (core.atomic.replace_folder: out_dir is
    the earlier export or the new one, whole; renames retried while Windows refuses them, a served
    tile being open; the earlier export put back when the new one cannot take its place), replacing
    an earlier export there (a folder holding tileset.json, or an empty one); InputError for any
    other folder. Returns warnings naming earlier exports renamed aside that could not be removed
    yet (a file in them still open): the next export removes them."""
    if out_dir.exists() and not (out_dir / "tileset.json").is_file() and any(out_dir.iterdir()):
        raise InputError(f"{out_dir}: exists, is not empty and holds no tileset.json; not replacing it")
    left = [f"{path}: an earlier export, not removed yet (a file in it is open); the next export removes it"
            for path in replace_folder(staging, out_dir, platform=platform)]
    for line in left:
        log.warning("%s", line)
    return left


def _count(tile: dict) -> int:
    return 1 + sum(_count(c) for c in tile.get("children", []))
