"""Runtime metrics of docs/how-it-works.md#the-runtime, vectorised over the node table: the screen-space error (SSE),
the bias P_{s,t} of VMSSE = P(mu) SSE, and the modulation m = 1 - P the overlay shows.

Papers (docs/how-it-works.md#papers): the VMSSE `SSE * P(q/alpha)` and the cube estimate of alpha
come from J. P. Charalambos, "Coherent Hierarchical Level-of-Detail (HLOD) Refinement Through
Hardware Occlusion Queries", SIACG 2006 (section 4); the bias `P_{s,t}` from J. P. Charalambos,
J. Bittner, M. Wimmer, E. Romero, "Optimized HLOD Refinement Driven by Hardware Occlusion
Queries", ISVC 2007 (section 3).

Data form: a `view.View` and per-node arrays of the `hierarchy.Hlod` table; every function returns
(n,) arrays (`bias_function`: P of one float, for the traversal's per-node path).
"""
from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ..model.view import View

# --- SSE (docs/how-it-works.md#sse) --------------------------------------------------------------------------

def sphere_distance(view: View, center: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """d = |e - c| - r (n,), model units; <= 0 when the eye is inside the sphere. The norm sums
    the axes' squares in order, as `np.linalg.norm(axis=1)` does, by columns: a column-major
    (Fortran-ordered) `center` (the traversal's) reads each column contiguously."""
    eye = view.eye
    dx, dy, dz = (center[:, axis] - eye[axis] for axis in range(3))
    squared = dx * dx
    squared += dy * dy
    squared += dz * dz
    return np.sqrt(squared, out=squared) - radius


def sse(view: View, error: np.ndarray, *, center: np.ndarray, radius: np.ndarray, is_leaf: np.ndarray) -> np.ndarray:
    """Screen-space error in pixels (n,) of nodes with MSE `error` (n,) model units, bounding
    spheres `center` (n,3) and `radius` (n,) model units, `is_leaf` (n,) bool: a sphere of diameter
    MSE at the point of the node's sphere nearest the eye. Perspective: MSE * (H/2) P11 / d;
    orthographic: MSE * (H/2) P11. d <= 0 (eye inside the sphere): +inf, the node must refine.
    Leaves: 0 (never 0 * inf)."""
    error, inside = sse_inputs(error, is_leaf)
    d = None if view.orthographic else sphere_distance(view, center, radius)
    return sse_at(view, error, distance=d, inside=inside)


def sse_inputs(error: np.ndarray, is_leaf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`sse_at`'s per-node inputs, view-independent: (error with the leaves' set to 0, the SSE
    where the eye is inside the sphere: inf, 0 for leaves)."""
    is_leaf = np.asarray(is_leaf, bool)
    return np.where(is_leaf, 0.0, error), np.where(is_leaf, 0.0, np.inf)


def sse_at(view: View, error: np.ndarray, *, distance: np.ndarray | None, inside: np.ndarray) -> np.ndarray:
    """`sse` from the nodes' sphere distances d = `distance` (n,) model units (unused for an
    orthographic view) and `sse_inputs`: error * (H/2) P11 / d where d > 0, else `inside`."""
    if view.orthographic:
        return error * view.pixels_per_unit_y
    # d tiny but positive: a huge finite or inf SSE, both refine; d <= 0 is replaced by inside
    # (whatever its quotient overflowed, divided by 0 or underflowed to)
    with np.errstate(all="ignore"):
        return np.where(distance > 0, error * view.pixels_per_unit_y / distance, inside)


# --- the bias P_{s,t} (docs/how-it-works.md#vmsse-and-the-bias-p_st) ---------------------------------------------

#: Below this k the normalised logistic is computed as its k -> 0 limit, mu itself (the
#: difference of two logistics then cancels catastrophically).
_K_LINEAR = 1e-6


def logistic(x: np.ndarray) -> np.ndarray:
    """L(x) = 1 / (1 + exp(-x)) as (1 + tanh(x/2)) / 2: no overflow for any finite or infinite x."""
    return 0.5 * (1.0 + np.tanh(0.5 * np.asarray(x, np.float64)))


def sigmoid_step(mu, t: float, *, k: float = np.inf) -> np.ndarray:
    """S_t(mu): the normalised logistic with turnover t and steepness k, or for k = inf the step
    [mu >= t] with S(0) = 0 and S(1) = 1. mu is clamped to [0, 1]."""
    mu = np.clip(np.asarray(mu, np.float64), 0.0, 1.0)
    if k <= 0 or np.isnan(k):
        raise ValueError(f"steepness k must be > 0, got {k}")
    if np.isinf(k):
        out = (mu >= t).astype(np.float64)
    elif k < _K_LINEAR:
        out = mu.copy()
    else:
        lo = logistic(-k * t)
        den = logistic(k * (1.0 - t)) - lo
        out = (logistic(k * (mu - t)) - lo) / den
    out = np.where(mu <= 0.0, 0.0, np.where(mu >= 1.0, 1.0, out))
    return np.clip(out, 0.0, 1.0)


def bias(mu, s: float, t: float, *, k: float = np.inf) -> np.ndarray:
    """P_{s,t}(mu) = (1 - s) mu + s S_t(mu); P(0) = 0 and P(1) = 1 exactly; s = 0 gives mu.

    Regions (the papers' aggressive/conservative split): for the step, P <= mu below t and P >= mu
    from t on, exactly. For finite k the same holds outside the band |mu - t| < band_half_width(k)
    (tests check k = 10 .. 1e9 on a grid)."""
    if not (0.0 <= s <= 1.0 and 0.0 <= t <= 1.0):
        raise ValueError(f"s and t must lie in [0, 1], got s={s}, t={t}")
    mu = np.clip(np.asarray(mu, np.float64), 0.0, 1.0)
    p = (1.0 - s) * mu + s * sigmoid_step(mu, t, k=k)
    p = np.where(mu <= 0.0, 0.0, np.where(mu >= 1.0, 1.0, p))
    return np.clip(p, 0.0, 1.0)


def bias_function(s: float, t: float, *, k: float = math.inf) -> Callable[[float], float]:
    """P_{s,t} of one float in plain Python with s, t, k bound (the traversal calls it per node; a
    numpy call per scalar costs more than the arithmetic). Same values as `bias` (tests compare
    them on a grid); s, t, k are not validated here (RuntimeSettings does it once); NaN mu counts
    as 0."""
    if math.isinf(k):
        def p(mu: float) -> float:  # the step S_t: s S_t(mu) is s or 0
            if not mu > 0.0:
                return 0.0
            if mu >= 1.0:
                return 1.0
            return _unit((1.0 - s) * mu + (s if mu >= t else 0.0))
        return p
    if k < _K_LINEAR:
        def step(mu: float) -> float:
            return mu
    else:
        lo = 0.5 * (1.0 + math.tanh(-0.5 * k * t))
        den = 0.5 * (1.0 + math.tanh(0.5 * k * (1.0 - t))) - lo

        def step(mu: float) -> float:
            return _unit((0.5 * (1.0 + math.tanh(0.5 * k * (mu - t))) - lo) / den)

    def p(mu: float) -> float:
        if not mu > 0.0:
            return 0.0
        if mu >= 1.0:
            return 1.0
        return _unit((1.0 - s) * mu + s * step(mu))
    return p


def _unit(x: float) -> float:
    """min(1.0, max(0.0, x)) of one float, NaN and -0.0 giving 0.0 as there, without the two calls."""
    return 0.0 if not x > 0.0 else (x if x < 1.0 else 1.0)


def band_half_width(k: float) -> float:
    """Half-width of the band around t where a finite-k logistic may cross the identity."""
    return 0.0 if np.isinf(k) else 2.0 * max(10.0, float(np.log(k))) / k


def modulation(p: np.ndarray) -> np.ndarray:
    """m = 1 - P: how strongly occlusion lowered the node's error (overlay: 0 blue, 0.5 magenta, 1 red)."""
    return 1.0 - np.asarray(p, np.float64)
