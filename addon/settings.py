"""Property group to core settings: the one pair of converters (STYLE: one function converts the
Blender PropertyGroup into core settings). `scene.hlod` (addon/properties.py) and the background
command's parsed arguments (addon/cli.py) carry the same field names, so both go through here.
"""
from __future__ import annotations

import os

from ..hlod_core.bake.pipeline import BakeSettings
from ..hlod_core.traversal.settings import RuntimeSettings


def default_jobs() -> int:
    """All the cores this process may use but one, at least 1: Blender keeps a core while the
    bake's worker processes (issue 14) use the rest."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, cores - 1)


def bake_settings(source) -> BakeSettings:
    """`source`: scene.hlod or the command's arguments (target_tris, max_depth, quality_threshold,
    jobs: worker processes, 0 = default_jobs()). The bake runs in a child process of Blender's
    Python (addon/bake_job.py), where worker processes import hlod_core as from the command line."""
    jobs = int(getattr(source, "jobs", 0) or 0) or default_jobs()
    return BakeSettings(target_tris=int(source.target_tris), max_depth=int(source.max_depth), jobs=jobs,
                        quality_threshold=float(source.quality_threshold),
                        error=str(getattr(source, "error", "exact") or "exact"))


def runtime_settings(props) -> RuntimeSettings:
    """scene.hlod -> the traversal's settings (step on means k = inf). The overlay is not one of
    them: the preview sets it on its renderer (`Renderer.overlay`), the drawing side."""
    return RuntimeSettings(tau=props.tau, s=props.s, t=props.t, k=float("inf") if props.step else props.k,
                           bias=props.bias, alpha=props.alpha, skip_queries=props.skip_queries,
                           multiquery=props.multiquery, batch_queries="on" if props.batch_queries else "off",
                           predict_new="on" if props.predict_new else "off")
