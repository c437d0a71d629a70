"""The bake's canonical coordinates: every position the bake stores or makes is a point of one
lattice fixed by the input's box, so the same model in other units bakes from the same numbers.

Data form: positions (k,3) float32 relative to the bake's origin, model units, each
`float32(u * unit_length)` for a canonical coordinate u (float64 with at most CANONICAL_BITS
significant bits); unit_length (float64, model units) is the longest extent of the used vertices'
box, so |u| <= 0.5. `canonical` gets u back from the stored float32 exactly.

A change of units by a non-power of two rounds every float32 coordinate differently, and greedy
quadric decimation answers one-step differences with other LODs (errors 0.05 to 0.12 of spot's size
at its root). u is computed in float64 from the float64 input, where the scale cancels to about
1e-16, so it rounds to the same CANONICAL_BITS bits at every scale except within about 1e-16 of a
rounding boundary (about 4e-9 of coordinates).
Why: docs/how-it-works.md#the-unit-frame-of-a-node
"""
from __future__ import annotations

import numpy as np

#: Significant bits of a canonical coordinate. float32 has 24, so float32(u * unit_length) keeps
#: u apart from its neighbours with a margin of 4x its rounding error, and `canonical` recovers u
#: exactly; the stored positions are 2 bits coarser than plain float32.
CANONICAL_BITS = 22
#: The float64 fraction bits `snap` drops (52 stored, 1 implicit: CANONICAL_BITS - 1 of them kept).
_DROPPED_BITS = 52 - (CANONICAL_BITS - 1)


def unit_length(lo: np.ndarray, hi: np.ndarray) -> float:
    """The lattice's unit (model units) for the used vertices' box lo..hi (3,) float64: its longest
    extent, 1 for a box of one point."""
    extent = float(np.max(np.asarray(hi, np.float64) - np.asarray(lo, np.float64)))
    return extent if extent > 0 else 1.0


def snap(u: np.ndarray, *, out: np.ndarray | None = None) -> np.ndarray:
    """u (...) float64 rounded to CANONICAL_BITS significant bits (ties to even); 0 stays 0. On the
    bits of normal numbers: the dropped fraction bits rounded to even into the kept ones (a carry
    moves into the exponent, as rounding up to the next power of two does); zeros, subnormals and
    non-finite numbers by `snap_frexp`. The same floats as snap_frexp, in about half its time.
    out: u itself (C-contiguous float64) to round in place, with two temporaries instead of six."""
    if out is None:
        out = np.array(u, np.float64, order="C")
    elif out is not u or out.dtype != np.float64 or not out.flags.c_contiguous:
        raise ValueError("snap: out must be u itself, a C-contiguous float64 array")
    bits = out.view(np.uint64)
    scratch = bits >> np.uint64(52)  # the exponent: 0 (zero, subnormal) and 0x7FF (inf, nan) are odd
    scratch &= np.uint64(0x7FF)
    odd = np.flatnonzero((scratch == 0) | (scratch == 0x7FF))
    kept = out.reshape(-1)[odd]
    np.right_shift(bits, np.uint64(_DROPPED_BITS), out=scratch)
    scratch &= np.uint64(1)  # ties to even: the kept last bit
    bits += np.uint64((1 << (_DROPPED_BITS - 1)) - 1)
    bits += scratch
    bits &= ~np.uint64((1 << _DROPPED_BITS) - 1)
    if odd.size:
        out.reshape(-1)[odd] = snap_frexp(kept)
    return out


def snap_frexp(u: np.ndarray) -> np.ndarray:
    """`snap` by its definition: the mantissa scaled to CANONICAL_BITS bits and rounded (np.rint)."""
    mantissa, exponent = np.frexp(np.asarray(u, np.float64))
    return np.ldexp(np.rint(np.ldexp(mantissa, CANONICAL_BITS)), exponent - CANONICAL_BITS)


def stored(relative: np.ndarray, length: float, *, overwrite: bool = False) -> np.ndarray:
    """Origin-relative float64 positions (..., 3), model units -> the float32 lattice points the
    bake stores: float32(snap(relative / length) * length). overwrite: `relative` (C-contiguous
    float64) is the scratch space, its values lost (no temporary of its size)."""
    if not overwrite:
        return (snap(np.asarray(relative, np.float64) / length) * length).astype(np.float32)
    relative /= length
    snap(relative, out=relative)
    relative *= length
    return relative.astype(np.float32)


def stored_input(positions: np.ndarray, faces: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """A mesh's positions (v,3) float64 world as a bake of it stores them: relative to its `origin`
    (3,), on the lattice of the box of the vertices its faces (f,3) use (float32 (v,3))."""
    used = np.asarray(positions, np.float64)[np.unique(faces)]
    return stored(np.asarray(positions, np.float64) - origin, unit_length(used.min(axis=0), used.max(axis=0)))


def canonical(positions: np.ndarray, length: float) -> np.ndarray:
    """Stored float32 positions (..., 3) -> their canonical coordinates u (float64, exact)."""
    return snap(np.asarray(positions, np.float64) / length)


def from_canonical(u: np.ndarray, length: float) -> np.ndarray:
    """Canonical coordinates (..., 3) float64 (any float64: snapped first) -> stored float32."""
    return (snap(u) * length).astype(np.float32)


def unique_by_first(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """np.unique of keys (k,) with the distinct keys numbered in order of first appearance, not of
    value (a value order changes with the units, and pymeshlab's result with its vertex order):
    first (u,) int64, the row of each key's first appearance, ascending; inverse (k,) int64."""
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.shape[0])
    return first[order], rank[inverse.reshape(-1)]
