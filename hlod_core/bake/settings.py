"""The bake's settings: one frozen dataclass, checked when made, that every front end builds
(the command line, the Blender extension's properties, a bake job's JSON)."""
from __future__ import annotations

from dataclasses import dataclass

from ..core.errors import InputError
from .meshlab import DecimationSettings

#: BakeSettings.error: the inner nodes' error measures. "exact" measures each inner node's LOD
#: against every original triangle below it; "bound" against its children's LODs only, plus the
#: largest child error (an upper bound of the exact error, cheaper; schedule.compose_bounds).
ERROR_MEASURES = ("exact", "bound")


@dataclass(frozen=True)
class BakeSettings:
    """target_tris: triangles per node (leaf budget and LOD size); max_depth: deepest node level
    (root = 0); jobs: worker processes for decimation (1 = in this process); error: the inner nodes'
    error measure (ERROR_MEASURES); the rest go to meshlab.DecimationSettings."""

    target_tris: int = 2000
    max_depth: int = 12
    jobs: int = 1
    quality_threshold: float = 0.3
    preserve_normals: bool = False
    boundary_weight: float = 1.0
    error: str = "exact"

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

    def decimation(self) -> DecimationSettings:
        """The settings pymeshlab's collapse takes (meshlab.quadric_collapse)."""
        return DecimationSettings(target_tris=self.target_tris, quality_threshold=self.quality_threshold,
                                  preserve_normals=self.preserve_normals, boundary_weight=self.boundary_weight)
