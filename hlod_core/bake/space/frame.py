"""The bake's frame: the origin and lattice unit every stored position is made in (lattice.py) and
the root cube every cell is an octant of (root_cube.py). A bake from scratch takes the frame of its
input's box; a re-bake keeps an earlier bake's frame while the edited input still fits it, so an
edit near the scene's edge moves no cell and no stored position that it does not touch.

Data form: `Frame` (origin (3,) float64 world, model units; unit_length float, model units;
root root_cube.RootCube, origin-relative), written into the file's meta as `Frame.to_meta`
(meta["frame"]) and into the bake cache's folder; `FrameChoice`: where a bake's frame came from
("input", "cache", "file") and why (meta["frame_source"], volatile).

The rule (`choose_lattice`, then `choose_root` once the positions are stored in that lattice):
- the earlier origin and unit stay while every used vertex lies within the earlier unit cube around
  the origin, widened by MARGIN units on every side, and the input's longest extent is at least
  MIN_SHARE of the unit; else the input's own (origin: the box's centre, unit: its longest extent);
- the earlier root cube stays (with the earlier lattice only) while it holds every centroid and
  their box spans at least MIN_SHARE of its side; a cube the centroids left grows (at most
  MAX_GROWTHS doublings, each keeping the old cube as an octant) when the grown cube passes the same
  test; else the cube around the centroids' box.
A bake's frame passes the rule's tests on its own input, so a re-bake of an unchanged input keeps it.
Why: docs/how-it-works.md#octree-cells-that-stay-put
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core.errors import InputError
from ...io import hlod_file
from . import lattice
from .root_cube import RootCube, tight_cube

#: Units (of the earlier lattice) an edited input's box may reach past the earlier box's unit cube
#: on every side and keep its lattice: an edit that moves the outermost object by a tenth of the
#: scene's extent stays well inside.
MARGIN = 0.25
#: Least share of the earlier unit (of the root cube's side) the input's extent (the centroids'
#: span) may shrink to and keep it: a frame far bigger than its scene would split it badly.
MIN_SHARE = 0.5
#: Most doublings of the root cube one re-bake may add.
MAX_GROWTHS = 2
#: Where a bake's frame came from (FrameChoice.source).
SOURCES = ("input", "cache", "file")


@dataclass(frozen=True, eq=False)
class Frame:
    """origin (3,) float64 world and unit_length (model units): the lattice; root: the root cube."""

    origin: np.ndarray
    unit_length: float
    root: RootCube

    def to_meta(self) -> dict:
        """meta["frame"]: JSON numbers that read back as the same float64s."""
        return {"origin": [float(x) for x in self.origin], "unit_length": float(self.unit_length),
                "root_corner": [float(x) for x in self.root.corner], "root_side": float(self.root.side),
                "root_growths": [int(c) for c in self.root.growths]}

    @staticmethod
    def from_meta(entry, *, where: str) -> "Frame":
        """The Frame of a meta["frame"] entry; InputError naming `where` when it is not one."""
        def bad(what: str) -> InputError:
            return InputError(f"{where}: the bake frame {what}")

        if not isinstance(entry, dict):
            raise bad("is missing (a file baked before frames were recorded: bake it again)")
        try:
            origin = np.array(entry["origin"], np.float64)
            corner = np.array(entry["root_corner"], np.float64)
            unit, side = float(entry["unit_length"]), float(entry["root_side"])
            growths = tuple(int(c) for c in entry["root_growths"])
        except (KeyError, TypeError, ValueError):
            raise bad("entry is malformed") from None
        if origin.shape != (3,) or corner.shape != (3,) or not np.all(np.isfinite(origin)) \
                or not np.all(np.isfinite(corner)) or not (math.isfinite(unit) and unit > 0) \
                or not (math.isfinite(side) and side >= 0):
            raise bad("has a non-finite or empty origin, unit or root cube")
        if len(growths) > 64 or any(not 0 <= c <= 7 for c in growths):
            raise bad("has growth codes outside 0..7")
        return Frame(origin=origin, unit_length=unit, root=RootCube(corner=corner, side=side, growths=growths))


def of_file(path: str | os.PathLike, *, where: str) -> Frame:
    """The frame an earlier bake recorded in its .hlod file (meta["frame"]); InputError naming
    `where` when the file is missing or has none, FormatError when it is not a .hlod file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{where}: no such file")
    return Frame.from_meta(hlod_file.load(path).meta.get("frame"), where=where)


@dataclass(frozen=True)
class FrameChoice:
    """Where a bake's frame came from (one of SOURCES) and why, as the bake's summary says it."""

    source: str
    reason: str

    def to_meta(self) -> dict:
        return {"from": self.source, "reason": self.reason}


#: The choice of a bake with no earlier frame.
FROM_SCRATCH = FrameChoice("input", "a bake from scratch: the frame of the input's box")


@dataclass(frozen=True, eq=False)
class Prior:
    """The frame a bake starts from: an earlier bake's, read from the cache folder ("cache") or a
    .hlod file ("file")."""

    frame: Frame
    source: str


def choose_lattice(prior: Prior | None, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, float, str | None]:
    """(origin (3,) float64, unit_length, why the prior's was not kept or None when it was) for the
    used vertices' box lo..hi (3,) float64 world."""
    own_origin, own_unit = 0.5 * (lo + hi), lattice.unit_length(lo, hi)
    if prior is None:
        return own_origin, own_unit, FROM_SCRATCH.reason
    origin, unit = prior.frame.origin, prior.frame.unit_length
    reach = (0.5 + MARGIN) * unit
    if np.any(lo < origin - reach) or np.any(hi > origin + reach):
        return own_origin, own_unit, (f"the input's box reaches past the {prior.source} frame's "
                                      f"margin ({MARGIN:g} of its unit on each side)")
    if own_unit < MIN_SHARE * unit:
        return own_origin, own_unit, f"the input's box is under {MIN_SHARE:g} of the {prior.source} frame's unit"
    return origin, unit, None


def choose_root(prior: Prior | None, lo: np.ndarray, hi: np.ndarray) -> tuple[RootCube, str | None]:
    """(root cube, why the prior's was not kept or None when it was, grown or not) for the
    centroids' box lo..hi (3,) float64, origin-relative in the prior's lattice (prior None: the
    lattice is the input's own)."""
    own = tight_cube(lo, hi)
    if prior is None:
        return own, None
    grown = prior.frame.root.grown_to(lo, hi, most=MAX_GROWTHS)
    if grown is None:
        return own, f"the centroids lie more than {MAX_GROWTHS} doublings outside the {prior.source} frame's root cube"
    if float(np.max(hi - lo)) < MIN_SHARE * grown.top.side:
        return own, f"the centroids span under {MIN_SHARE:g} of the {prior.source} frame's root cube"
    return grown, None


def choice_of(prior: Prior | None, *, lattice_why: str | None, root_why: str | None, grew: int) -> FrameChoice:
    """What meta["frame_source"] says of a frame chosen by choose_lattice and choose_root."""
    if prior is None:
        return FrameChoice("input", lattice_why)
    if lattice_why is not None:
        return FrameChoice("input", lattice_why)
    if root_why is not None:
        return FrameChoice("input", f"the {prior.source} frame's lattice, a new root cube: {root_why}")
    if grew:
        return FrameChoice(prior.source, f"the input fits the {prior.source} frame once its root cube doubles "
                                         f"{grew} time{'s' if grew > 1 else ''}")
    return FrameChoice(prior.source, f"the input fits the {prior.source} frame")
