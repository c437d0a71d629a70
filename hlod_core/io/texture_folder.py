"""The folder a bake writes the images it makes into (a glTF input's embedded images, textures made
from Blender materials): OUT.textures/ beside OUT.hlod, published only once the .hlod is saved;
and the file names a texture gets in a folder of them."""
from __future__ import annotations

import dataclasses
import logging
import os
import re
import shutil
from pathlib import Path

from ..core.atomic import replace_folder
from ..core.errors import InputError
from .meshes import TriangleMesh

log = logging.getLogger("hlod_core")


def unique_file_name(stem: str, suffix: str, taken: set) -> str:
    """`stem` (any text) made a portable file name with `suffix` (".png"), numbered (_2, _3...) past
    the names in `taken` (lower case; the new one is added): one folder of textures, no clashes on
    case-insensitive file systems."""
    stem = re.sub(r"[^A-Za-z0-9_-]+", "_", stem).strip("_") or "texture"
    name, k = f"{stem}{suffix}", 1
    while name.lower() in taken:
        k += 1
        name = f"{stem}_{k}{suffix}"
    taken.add(name.lower())
    return name


class EmbeddedTextures:
    """Where a bake writes the images it makes (embedded in its glTF inputs, or made from Blender
    materials): OUT.textures/ beside OUT.hlod
    (the .hlod refers to them by relative path). They are written into a hidden scratch folder
    beside it, made only when an image is written; `publish`, after the .hlod is saved, renames
    it to OUT.textures (replacing the one an earlier bake to OUT left). A failed or interrupted
    bake removes the scratch folder and leaves OUT.textures as it was. No embedded image: nothing
    is written and an existing OUT.textures is left alone."""

    def __init__(self, output: Path):
        self.final = output.with_suffix(".textures")
        if self.final == output:  # -o NAME.textures
            self.final = output.with_name(output.name + ".textures")
        self.scratch = output.parent / f".{self.final.name}.partial-{os.getpid()}"

    def __enter__(self) -> "EmbeddedTextures":
        return self

    def __exit__(self, kind, exc, tb) -> None:
        self.discard()

    def discard(self) -> None:
        """Remove the scratch folder (nothing of it published); OUT.textures stays as it was."""
        shutil.rmtree(self.scratch, ignore_errors=True)

    def relocate(self, mesh: TriangleMesh) -> TriangleMesh:
        """The mesh with its texture paths in the scratch folder moved to the final folder."""
        if not self.scratch.is_dir():
            return mesh
        if self.final.exists() and not self.final.is_dir():
            raise InputError(f"{self.final}: is a file; the bake writes the inputs' embedded images into a folder "
                             "of that name")
        scratch = str(self.scratch.resolve())
        moved = tuple(dataclasses.replace(m, texture=str(self.final.resolve() / Path(m.texture).name))
                      if m.texture is not None and str(Path(m.texture).parent) == scratch else m
                      for m in mesh.materials)
        return dataclasses.replace(mesh, materials=moved)

    def publish(self) -> str | None:
        """Rename the scratch folder to OUT.textures (core.atomic.replace_folder: an earlier one is
        replaced whole); returns its path, or None when nothing was written."""
        if not self.scratch.is_dir():
            return None
        for path in replace_folder(self.scratch, self.final):
            log.warning("%s: earlier embedded images, not removed yet (a file in it is open); the next bake "
                        "removes them", path)
        log.info("embedded images: %s", self.final)
        return str(self.final)
