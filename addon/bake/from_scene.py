"""A bake of Blender objects, from gathering the scene to the started bake job: the one flow the
Bake operator (operators/bake.py) and the background command (addon/cli.py) share, on Blender's
main thread.

`start_bake` runs, in order:
1. the cache folder: OUT.hlod.cache beside the output, or the folder given, none when the cache is
   off (hlod_core.bake.run.cache.folder_for, the rule every front end of the core asks too); the bake
   keeps the frame the last bake left there while the scene fits it (hlod_core/bake/space/frame.py), or
   an earlier .hlod file's when one is given;
2. the scene gathered in one pass (scene/gather.py), the colours no node tree reading gives
   baked by Cycles on each object that draws them on the way (scene/surface_bakes.py);
3. the textures the materials need, copied into the bake's texture folder (materials/textures.py),
   which `SceneBake.finish` publishes as OUT.textures once the .hlod is written;
4. the bake job: a child process of Blender's Python (bake/job.py).
What the caller reports (what was skipped, which materials Cycles baked) and records (the objects
the bake took) comes back with the job.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ...hlod_core.bake.run import cache
from ...hlod_core.bake.settings import BakeSettings
from ...hlod_core.bake.space import frame as frames
from ...hlod_core.core.errors import InputError
from ...hlod_core.io.texture_folder import EmbeddedTextures
from ..materials.cycles_bake import CyclesBake
from ..materials.images import material_images
from ..materials.textures import place_textures
from ..scene.gather import Gathered, gather
from .job import BakeJob


@dataclass
class SceneBake:
    """A started bake of Blender objects: its job, what gathering the scene found (the Cycles bakes
    among it), and the bake's texture folder (published by `finish`)."""

    job: BakeJob
    gathered: Gathered
    textures: EmbeddedTextures

    @property
    def cycles_bakes(self) -> list[CyclesBake]:
        """The Cycles bakes of colours no node tree reading gives, one per object (the report's line)."""
        return self.gathered.cycles_bakes

    def finish(self) -> None:
        """Once the job has ended: the textures the bake made published as OUT.textures when the
        .hlod was written (an OSError doing so becomes the job's error), else dropped, and the
        texture folder's scratch removed either way."""
        try:
            if self.job.error is None:
                self.textures.publish()
        except OSError as exc:
            self.job.error = exc
        finally:
            self.textures.discard()


def start_bake(context, objects, output: Path, settings: BakeSettings, *, use_cache: bool = True,
               cache_folder: str | None = None, include_hidden: bool = False, cache_budget_mb: float | None = None,
               frame_from: str | None = None) -> SceneBake:
    """Gather `objects` (include_hidden: hidden ones too) and start their bake into `output` (a
    .hlod path whose folder exists) with `settings` (module notes). use_cache / cache_folder: the
    bake cache, kept in cache_folder or OUT.hlod.cache beside the output, within cache_budget_mb
    (None: the cache's default); frame_from: an earlier bake's .hlod whose frame the bake keeps while
    the scene fits it. InputError when the cache folder names a file, a budget comes without a cache,
    frame_from has no frame or nothing gives triangles; the scene is left as it was."""
    output = Path(output)
    cache_dir = cache.folder_for(output, folder=cache_folder, enabled=use_cache)
    if cache_dir is None and cache_budget_mb is not None:
        raise InputError("cache budget: a budget of the bake cache, which is off")
    options = {"cache_budget_mb": cache.DEFAULT_BUDGET_MB if cache_budget_mb is None else cache_budget_mb}
    if frame_from is not None:
        options["frame_from"] = frames.of_file(frame_from, where=f"frame from {frame_from}")
    gathered = gather(context, objects, include_hidden=include_hidden)
    textures = EmbeddedTextures(output)
    try:
        mesh = place_textures(gathered.mesh, textures)
        if settings.proxy_materials:  # what the inner nodes' proxy materials are baked from
            options.update(images=material_images(mesh.materials), textures=textures)
        job = BakeJob(mesh, settings, output, extra_meta=gathered.attributes or None, cache_dir=cache_dir,
                      job_options=options)
    except BaseException:
        textures.discard()
        raise
    return SceneBake(job=job, gathered=gathered, textures=textures)
