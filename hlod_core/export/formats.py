"""Outputs of the core: where a file may be written, and the export of a baked hierarchy in a
chosen format (3D Tiles 1.1 or the native .hlod). Used by the command line (hlod_core/cli/files.py) and
by the Blender background command (addon/cli.py).
"""
from __future__ import annotations

import os
from pathlib import Path

from ..core.errors import InputError
from ..io import hlod_file
from . import tiles3d
from .place import Place


def check_output_file(path: str, option: str = "-o", example: str = "scene.hlod") -> None:
    """Fail before a long bake, not after it, when OUT cannot be written. `path` is the text as
    given: pathlib drops a trailing slash, so `-o old.hlod/` would overwrite the file old.hlod and
    `-o new/` would create a file named new. A name ending in a separator (or in . or ..) names a
    folder, and is refused like an existing folder."""
    out = Path(path)
    if out.is_dir() or os.path.basename(str(path)) in ("", ".", ".."):
        if out.is_file():
            raise InputError(f"{option} {path}: names a folder, but {out} is a file; "
                             f"to replace it, write {option} {out}")
        raise InputError(f"{option} {path}: names a folder; give a file name such as {out / example}")
    parent = next((p for p in [out.parent, *out.parent.parents] if p.exists()), None)
    if parent is not None and not parent.is_dir():
        raise InputError(f"{out}: cannot create it, {parent} is a file")
    if parent is not None and not os.access(parent, os.W_OK):
        raise InputError(f"{out}: folder {parent} is not writable")


MESH_ENCODINGS, TEXTURE_ENCODINGS = tiles3d.MESH_ENCODINGS, tiles3d.texture_codec.TEXTURE_ENCODINGS


def export_hlod(hlod, fmt: str, out_dir, *, stem: str, place: Place | None = None, mesh: str = "plain",
                textures: str = "original", merge_leaves: bool = False) -> dict:
    """Export into out_dir in format `fmt` ("3dtiles" or "hlod"): 3D Tiles (tileset.json, tiles/,
    textures/ when textured; on the globe at `place` when given; `mesh` one of MESH_ENCODINGS,
    `textures` one of TEXTURE_ENCODINGS, `merge_leaves` a node's leaves in one tile) or the native
    file <stem>.hlod (which has none of these). Returns the export's summary."""
    if fmt == "3dtiles":
        return tiles3d.export(hlod, out_dir, place=place, mesh=mesh, textures=textures, merge_leaves=merge_leaves)
    target = Path(out_dir) / f"{stem}.hlod"
    check_output_file(str(target))
    hlod_file.save(hlod, target)
    return {"format": "hlod", "output": str(target), "nodes": hlod.node_count}
