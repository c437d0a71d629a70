"""The octree's root cube and its growths: the cell every other cell of a bake is an octant of.

Data form: `Cube` and `RootCube` hold a corner (3,) float64 and a side (float), model units,
relative to the bake's origin (the frame of the triangle centroids the octree splits). A RootCube
is a base cube R_0 (`tight_cube` of the centroids in a bake from scratch) and the octant codes of
its growths: R_{i+1} is R_i doubled, R_i one of its octants, so every cell of a bake in R_i is a
cell of a bake in R_{i+1}, one level down, with the same floats (`GrowthChain` gives the octree
R_i's exact centre and half side instead of computing them from R_{i+1}'s, which would round).

A growth code has bit a set when the cube grows toward +a (R_i is then on the - side of axis a).
R_{i+1} splits at R_i's face, widened by `FACE_TOLERANCE` of R_i's side, so that its octant R_i
holds exactly the centroids `Cube.contains` counts as inside R_i.
Why: docs/how-it-works.md#octree-cells-that-stay-put
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Share of a cube's side by which a centroid may lie outside a face and still count as inside: a
#: tight cube's corner and side are rounded, so the extreme centroids may lie a rounding outside.
FACE_TOLERANCE = 2.0 ** -32


@dataclass(frozen=True)
class Cube:
    """corner (3,) float64 and side, model units, in the frame of the centroids."""

    corner: np.ndarray
    side: float

    @property
    def center(self) -> np.ndarray:
        """(3,) float64."""
        return self.corner + 0.5 * self.side

    @property
    def tolerance(self) -> float:
        """How far outside a face a centroid still counts as inside (model units)."""
        return self.side * FACE_TOLERANCE

    def contains(self, lo: np.ndarray, hi: np.ndarray) -> bool:
        """Whether the box lo..hi (3,) float64 lies in the cube, faces widened by `tolerance`."""
        tol = self.tolerance
        return bool(np.all(lo >= self.corner - tol) and np.all(hi <= (self.corner + self.side) + tol))

    def grown(self, code: int) -> "Cube":
        """The cube doubled toward +a where bit a of `code` is set, toward -a elsewhere."""
        up = np.array([(code >> a) & 1 for a in range(3)], bool)
        return Cube(corner=np.where(up, self.corner, self.corner - self.side), side=2.0 * self.side)

    def split_plane(self, code: int) -> np.ndarray:
        """(3,) float64: where the cube grown by `code` splits so that its octant `inner_octant(code)`
        holds exactly what `contains` counts as inside this cube (on +a: below the widened upper
        face; on -a: at or above the widened lower face)."""
        up = np.array([(code >> a) & 1 for a in range(3)], bool)
        tol = self.tolerance
        upper = np.nextafter((self.corner + self.side) + tol, np.inf)
        return np.where(up, upper, self.corner - tol)


def inner_octant(code: int) -> int:
    """The octant (bit a: + side of axis a) of the grown cube that the cube grown by `code` was."""
    return (~code) & 7


@dataclass(frozen=True)
class RootCube:
    """A bake's root: the base cube (corner (3,) float64, side; model units, origin-relative) and
    the growth codes applied to it, oldest first (module docstring)."""

    corner: np.ndarray
    side: float
    growths: tuple[int, ...] = ()

    @property
    def center(self) -> np.ndarray:
        """(3,) float64: the base cube's centre."""
        return self.corner + 0.5 * self.side

    @property
    def cubes(self) -> list[Cube]:
        """R_0 (the base) .. R_g (the top), g = len(growths)."""
        cubes = [Cube(np.asarray(self.corner, np.float64), float(self.side))]
        for code in self.growths:
            cubes.append(cubes[-1].grown(code))
        return cubes

    @property
    def top(self) -> Cube:
        """The cube the octree's root cell is."""
        return self.cubes[-1]

    def grown_to(self, lo: np.ndarray, hi: np.ndarray, *, most: int) -> "RootCube | None":
        """This root grown (at most `most` more times) until it contains the box lo..hi (3,)
        float64: on each axis toward the side the box leaves it on (toward - when below the cube,
        else toward +); None when that takes more growths."""
        root = self
        for _ in range(most + 1):
            top = root.top
            if top.contains(lo, hi):
                return root
            below = lo < top.corner - top.tolerance
            code = sum(1 << a for a in range(3) if not below[a])
            root = RootCube(self.corner, self.side, root.growths + (code,))
        return None


def tight_cube(lo: np.ndarray, hi: np.ndarray) -> RootCube:
    """The cube with its lowest corner at the box [lo, hi]'s ((3,) float64, finite) and its longest
    extent as side (0 for a box of one point). On the box's shorter axes the cube reaches past hi, so
    the first splits along a flat scene's thin axis fall above it instead of through its middle
    (docs/how-it-works.md#octree-cells-that-stay-put)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    side = float(np.max(hi - lo))
    return RootCube(corner=lo.copy(), side=side)


@dataclass(frozen=True, eq=False)
class GrowthChain:
    """The grown cubes R_1..R_g of a RootCube as the octree meets them: center (g,3), half (g,)
    (a cell is R_i when both are bit-identical), plane (g,3) where each splits, inner (g,) the
    octant R_{i-1} is, and inner_center (g,3) / inner_half (g,): R_{i-1}'s exact cell."""

    center: np.ndarray
    half: np.ndarray
    plane: np.ndarray
    inner: np.ndarray
    inner_center: np.ndarray
    inner_half: np.ndarray

    @staticmethod
    def of(root: RootCube) -> "GrowthChain | None":
        """None for a root that never grew (the octree then splits every cell at its centre)."""
        if not root.growths:
            return None
        cubes = root.cubes
        grown, inner = cubes[1:], cubes[:-1]
        return GrowthChain(center=np.array([c.center for c in grown]), half=np.array([0.5 * c.side for c in grown]),
                           plane=np.array([c.split_plane(code) for c, code in zip(inner, root.growths)]),
                           inner=np.array([inner_octant(code) for code in root.growths], np.int64),
                           inner_center=np.array([c.center for c in inner]),
                           inner_half=np.array([0.5 * c.side for c in inner]))

    def index(self, center: np.ndarray, half: np.ndarray) -> np.ndarray:
        """(k,) int64: which grown cube each cell (center (k,3), half (k,)) is, -1 for none."""
        same = (center[:, None, :] == self.center[None]).all(axis=2) & (half[:, None] == self.half[None])
        return np.where(same.any(axis=1), np.argmax(same, axis=1), -1)

    def planes(self, center: np.ndarray, half: np.ndarray) -> np.ndarray:
        """(k,3): where each cell splits: its centre, or a grown cube's plane."""
        which = self.index(center, half)
        return np.where((which >= 0)[:, None], self.plane[np.maximum(which, 0)], center)

    def enter_inner(self, which: np.ndarray, octant: np.ndarray, center: np.ndarray, half: np.ndarray) -> None:
        """Cells `which` (k,) int64 (`index` of their parent cell) that went into `octant` (k,) take
        R_{i-1}'s exact cell where that octant is the inner one: center (k,3) and half (k,), in place."""
        into = (which >= 0) & (octant == self.inner[np.maximum(which, 0)])
        center[into] = self.inner_center[which[into]]
        half[into] = self.inner_half[which[into]]
