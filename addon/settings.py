"""Property group to core settings: the one place the Blender PropertyGroup (scene.hlod) becomes
the core's settings, over the core's builders (hlod_core.bake.settings.bake_settings, the one every
front end calls; RuntimeSettings). Imports no Blender module: it reads the property group's values.
"""
from __future__ import annotations

from ..hlod_core.bake.settings import BakeSettings
from ..hlod_core.bake.settings import bake_settings as core_bake_settings
from ..hlod_core.render.residency import StreamingSettings
from ..hlod_core.traversal.settings import RuntimeSettings


def bake_settings(props) -> BakeSettings:
    """scene.hlod -> the bake's settings (jobs 0 = all cores but one: bake.settings.resolve_jobs).
    The bake runs in a child process of Blender's Python (addon/bake/job.py), where worker
    processes import hlod_core as from the command line."""
    return core_bake_settings(target_tris=props.target_tris, max_depth=props.max_depth, jobs=props.jobs,
                              quality_threshold=props.quality_threshold, error=props.error,
                              proxy_materials=props.proxy_materials, texture_cap=props.texture_cap,
                              texture_floor=min(props.texture_cap, BakeSettings.texture_floor))


def runtime_settings(props) -> RuntimeSettings:
    """scene.hlod -> the traversal's settings (step on means k = inf). The overlay is not one of
    them: the preview sets it on its renderer (`Renderer.overlay`), the drawing side."""
    return RuntimeSettings(tau=props.tau, s=props.s, t=props.t, k=float("inf") if props.step else props.k,
                           bias=props.bias, alpha=props.alpha, skip_queries=props.skip_queries,
                           multiquery=props.multiquery, batch_queries="on" if props.batch_queries else "off",
                           predict_new="on" if props.predict_new else "off")


def streaming_settings(props) -> StreamingSettings:
    """scene.hlod -> the preview's GPU budget for node geometry and textures (0 MB: unlimited)."""
    return StreamingSettings.from_megabytes(float(props.gpu_budget_mb))
