"""The folder a bake writes its glTF inputs' embedded images into: OUT.textures/ beside OUT.hlod,
published only once the .hlod is saved."""
from __future__ import annotations

import dataclasses
import logging
import os
import shutil
from pathlib import Path

from ..core.errors import InputError
from ..io.meshes import TriangleMesh

log = logging.getLogger("hlod_core")


class EmbeddedTextures:
    """Where a bake writes the images embedded in its glTF inputs: OUT.textures/ beside OUT.hlod
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
        """Rename the scratch folder to OUT.textures; returns its path, or None when nothing was written."""
        if not self.scratch.is_dir():
            return None
        old = self.final.parent / f".{self.final.name}.old-{os.getpid()}"
        if self.final.is_dir():
            os.replace(self.final, old)
        os.replace(self.scratch, self.final)
        shutil.rmtree(old, ignore_errors=True)
        log.info("embedded images: %s", self.final)
        return str(self.final)
