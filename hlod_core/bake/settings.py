"""The bake's settings: one frozen dataclass, checked when made, and `bake_settings`, the builder
every front end calls (the command line, the Blender extension's properties and its background
command); a bake job's JSON holds the dataclass's fields."""
from __future__ import annotations

import os
from dataclasses import dataclass

from ..core.errors import InputError
from .appearance.proxy import ProxySettings
from .decimate.meshlab import DecimationSettings

#: Largest side of a proxy texture (texels) a bake may ask for.
MAX_TEXTURE_SIDE = 16384

#: BakeSettings.error: the inner nodes' error measures. "exact" measures each inner node's LOD
#: against every original triangle below it; "bound" against its children's LODs only, plus the
#: largest child error (an upper bound of the exact error, cheaper; schedule.compose_bounds).
ERROR_MEASURES = ("exact", "bound")


@dataclass(frozen=True)
class BakeSettings:
    """target_tris: triangles per node (leaf budget and LOD size); max_depth: deepest node level
    (root = 0); jobs: worker processes for decimation (1 = in this process); error: the inner nodes'
    error measure (ERROR_MEASURES); proxy_materials, texture_cap, texture_floor: the inner nodes'
    proxy materials (`proxy`); the rest go to meshlab.DecimationSettings."""

    target_tris: int = 2000
    max_depth: int = 12
    jobs: int = 1
    quality_threshold: float = 0.3
    preserve_normals: bool = False
    boundary_weight: float = 1.0
    error: str = "exact"
    proxy_materials: bool = True
    texture_cap: int = 1024
    texture_floor: int = 16

    def __post_init__(self):
        if self.target_tris < 1:
            raise InputError(f"target_tris must be at least 1, got {self.target_tris}")
        if not 0 <= self.max_depth <= 64:
            raise InputError(f"max_depth must be between 0 and 64, got {self.max_depth}")
        if self.jobs < 1:
            raise InputError(f"jobs must be at least 1, got {self.jobs}")
        if not 0.0 <= self.quality_threshold <= 1.0:
            raise InputError(f"quality_threshold must be in [0, 1], got {self.quality_threshold}")
        if self.error not in ERROR_MEASURES:
            raise InputError(f"error must be one of {', '.join(ERROR_MEASURES)}, got {self.error!r}")
        if not 1 <= self.texture_floor <= self.texture_cap <= MAX_TEXTURE_SIDE:
            raise InputError(f"texture sizes must satisfy 1 <= floor <= cap <= {MAX_TEXTURE_SIDE}, got floor "
                             f"{self.texture_floor} and cap {self.texture_cap}")

    def proxy(self) -> ProxySettings:
        """The inner nodes' proxy materials (appearance/proxy.py)."""
        return ProxySettings(enabled=self.proxy_materials, texture_cap=self.texture_cap,
                             texture_floor=self.texture_floor)

    def decimation(self) -> DecimationSettings:
        """The settings pymeshlab's collapse takes (meshlab.quadric_collapse)."""
        return DecimationSettings(target_tris=self.target_tris, quality_threshold=self.quality_threshold,
                                  preserve_normals=self.preserve_normals, boundary_weight=self.boundary_weight)


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity where the platform has one), at least 1."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1


def resolve_jobs(jobs: int) -> int:
    """Worker processes for a front end's `jobs`: `jobs` itself when >= 1; 0 = all the cores this
    process may use but one, at least 1 (the bake's own process schedules the tasks and composes
    their results; in Blender it also keeps the interface responsive). InputError below 0."""
    if jobs < 0:
        raise InputError(f"jobs must be 0 (all cores but one) or a number of worker processes, got {jobs}")
    return int(jobs) if jobs > 0 else max(1, usable_cores() - 1)


def bake_settings(*, target_tris: int, max_depth: int, jobs: int, quality_threshold: float,
                  preserve_normals: bool = False, error: str = "exact", proxy_materials: bool = True,
                  texture_cap: int = 1024, texture_floor: int = 16) -> BakeSettings:
    """The BakeSettings of a front end's values (the command line's options, the extension's
    properties or its background command's options): plain ints, floats and strings (Blender's
    properties give their own), jobs through resolve_jobs. InputError for a value out of range."""
    return BakeSettings(target_tris=int(target_tris), max_depth=int(max_depth), jobs=resolve_jobs(int(jobs)),
                        quality_threshold=float(quality_threshold), preserve_normals=bool(preserve_normals),
                        error=str(error), proxy_materials=bool(proxy_materials), texture_cap=int(texture_cap),
                        texture_floor=int(texture_floor))
