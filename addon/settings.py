"""Property group to core settings: the one pair of converters (STYLE: one function converts the
Blender PropertyGroup into core settings). `scene.hlod` (addon/properties.py) and the background
command's parsed arguments (addon/cli.py) carry the same field names, so both go through here.
"""
from __future__ import annotations

from ..hlod_core.bake import BakeSettings
from ..hlod_core.traversal import RuntimeSettings


def bake_settings(source, *, jobs: int = 1) -> BakeSettings:
    """`source`: scene.hlod or the command's arguments (target_tris, max_depth, quality_threshold).
    jobs = 1: worker processes would have to import this package by its Blender name
    (bl_ext.<repo>.hlod), which a plain Python child cannot; the bake runs in this process."""
    return BakeSettings(target_tris=int(source.target_tris), max_depth=int(source.max_depth), jobs=jobs,
                        quality_threshold=float(source.quality_threshold))


def runtime_settings(props) -> RuntimeSettings:
    """scene.hlod -> the traversal's settings (step on means k = inf). The overlay is not one of
    them: the preview sets it on its renderer (`Renderer.overlay`), the drawing side."""
    return RuntimeSettings(tau=props.tau, s=props.s, t=props.t, k=float("inf") if props.step else props.k,
                           bias=props.bias, alpha=props.alpha)
