"""A node's UV atlas (docs/how-it-works.md#proxy-materials-for-the-inner-nodes): xatlas charts and
packs the LOD, at the texel density the node's error asks for.

Data form: in, a LOD's positions (k,3) float32 model units and faces (m,3) int; out, `Atlas`: the
LOD's vertices split along chart borders (`vertex_of` maps each atlas vertex to its LOD vertex),
faces over them, and per atlas vertex a UV in [0, 1] in the GL convention (origin at the image's
bottom-left, v up), over a width x height image.

xatlas (Castaño, https://github.com/jpcy/xatlas; the `xatlas` wheel) segments the surface into
charts of low distortion, parametrises them and packs them; it is deterministic for a given input.

Freeing an xatlas Atlas can hang. Its task scheduler's destructor sets each worker thread's wake-up
flag and notifies the thread without holding the thread's mutex: a thread that has just found the
flag clear and is about to sleep misses the notification, and the destructor waits for it forever.
A worker thread is in that window right after `generate()` returns, going back to sleep, and on a
loaded machine it can be pre-empted there. So an Atlas is freed here only once it has been idle for
IDLE_BEFORE_FREE_SECONDS (`_retire`): by then its threads sleep, and the notification reaches them.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

#: Texels of padding around each chart, so bilinear filtering and the first mip levels of one chart
#: do not read its neighbours (the texture bake fills the padding from the chart's border).
PADDING_TEXELS = 2
#: Longest chart boundary xatlas grows, in units of the square root of the LOD's area: its charting
#: time grows faster than a chart's size (parametrising one large chart is most of it), and on the
#: statue square's deepest nodes this bound made xatlas 4 to 5x faster for 12% more texels (more,
#: smaller charts, each with its padding; 7% over the whole bench size) (docs/performance.md#with-proxy-materials).
MAX_BOUNDARY_PER_SQRT_AREA = 2.0
#: xatlas's chart-growing iterations after the first pass (its default 1): 0 halves the charting
#: time there, the packed texels within 1%.
CHART_ITERATIONS = 0
#: Packs tried per node: a pack whose longer side is over the cap (or whose shorter side is under
#: the floor) is made again with the density scaled to fit.
MAX_PACKS = 3
#: How long an xatlas Atlas stays alive after its last use before it is freed (module docstring):
#: far longer than a runnable thread waits for a core on a loaded machine.
IDLE_BEFORE_FREE_SECONDS = 0.5

#: Atlases done with, each with the monotonic time it was retired: freed by `_retire` once idle.
retired: list[tuple[float, object]] = []
RETIRED_LOCK = threading.Lock()


def _retire(atlas: object | None) -> None:
    """Keep `atlas` (None: none) alive, and free the retired atlases idle for IDLE_BEFORE_FREE_SECONDS."""
    now = time.monotonic()
    with RETIRED_LOCK:
        idle = [entry for entry in retired if now - entry[0] >= IDLE_BEFORE_FREE_SECONDS]
        retired[:] = [entry for entry in retired if now - entry[0] < IDLE_BEFORE_FREE_SECONDS]
        if atlas is not None:
            retired.append((now, atlas))
    del idle  # the idle atlases are freed here, outside the lock


@dataclass(frozen=True, eq=False)
class Atlas:
    """vertex_of (j,) int64 LOD vertex of each atlas vertex; faces (m,3) int32 over the atlas
    vertices (the LOD's faces, in order); uvs (j,2) float32 in [0, 1], GL convention; width, height:
    the image's texels; texels_per_unit: the packed density (texels per model unit); utilization:
    the share of the image the charts cover (xatlas's measure of packing efficiency)."""

    vertex_of: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    width: int
    height: int
    texels_per_unit: float
    utilization: float


def texture_side(area: float, texel_size: float, *, efficiency: float, floor: int, cap: int) -> int:
    """The side N of a square texture with texels of `texel_size` model units over `area` square
    model units, packed at `efficiency` (share of the image the charts fill): N^2 = area / (s^2 eta),
    clamped to [floor, cap]. texel_size 0 (a lossless node) gives the cap."""
    if not texel_size > 0 or not area > 0:
        return cap if area > 0 else floor
    side = float(np.sqrt(area / (texel_size * texel_size * max(efficiency, 1e-3))))
    return int(min(cap, max(floor, np.ceil(side))))


def surface_area(positions: np.ndarray, faces: np.ndarray) -> float:
    """Total area of the triangles, square model units (float64)."""
    p = np.asarray(positions, np.float64)
    f = np.asarray(faces, np.int64)
    if f.shape[0] == 0:
        return 0.0
    cross = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
    return float(0.5 * np.sqrt((cross * cross).sum(axis=1)).sum())


def node_atlas(positions: np.ndarray, faces: np.ndarray, *, texels_per_unit: float, floor: int,
               cap: int) -> Atlas:
    """The atlas of a LOD (module docstring) packed at `texels_per_unit` texels per model unit, made
    again at a scaled density while its longer side is over `cap` or under `floor` (at most
    MAX_PACKS packs); a pack still outside them is scaled into them as a whole (its UVs are fractions
    of the image). A LOD without faces gets an empty atlas of floor x floor, and one whose faces are
    all too thin for xatlas to chart one of floor x floor with every UV at its centre (texels_per_unit
    0: the proxy is then one colour)."""
    import xatlas

    f = np.ascontiguousarray(faces, np.uint32)
    p = np.ascontiguousarray(positions, np.float32)
    if f.shape[0] == 0:
        return Atlas(vertex_of=np.zeros(0, np.int64), faces=np.zeros((0, 3), np.int32),
                     uvs=np.zeros((0, 2), np.float32), width=floor, height=floor, texels_per_unit=0.0,
                     utilization=0.0)
    # xatlas works best on unit-sized input: pack in a frame where the LOD's box diagonal is 1
    lo, hi = p.min(axis=0).astype(np.float64), p.max(axis=0).astype(np.float64)
    diagonal = float(np.linalg.norm(hi - lo)) or 1.0
    local = ((p - 0.5 * (lo + hi)) / diagonal).astype(np.float32)
    density = max(float(texels_per_unit), 1e-12) * diagonal  # texels per local unit
    charts = xatlas.ChartOptions()
    charts.max_iterations = CHART_ITERATIONS
    local_area = surface_area(local, f)
    if local_area > 0:
        charts.max_boundary_length = float(MAX_BOUNDARY_PER_SQRT_AREA * np.sqrt(local_area))
    atlas = None
    for _ in range(MAX_PACKS):
        _retire(atlas)
        atlas = xatlas.Atlas()
        atlas.add_mesh(local, f)
        pack = xatlas.PackOptions()
        pack.padding = PADDING_TEXELS
        pack.bilinear = True
        pack.texels_per_unit = float(density)
        atlas.generate(charts, pack)
        side = max(atlas.width, atlas.height)
        if atlas.atlas_count == 1 and floor <= side <= cap:
            break
        density *= (cap if side > cap or atlas.atlas_count != 1 else floor) / max(side, 1) * 0.97
    vertex_of, atlas_faces, uvs = atlas[0]
    uvs = np.asarray(uvs, np.float32)
    side = max(atlas.width, atlas.height)
    width_texels, height_texels = atlas.width, atlas.height
    charted = side > 0 and atlas.atlas_count > 0 and np.asarray(atlas_faces).size == f.size
    packed_density = float(atlas.texels_per_unit)
    utilization = float(atlas.utilization) if charted else 0.0
    _retire(atlas)
    del atlas
    if not charted:  # every face too thin to chart: one colour
        return Atlas(vertex_of=np.arange(p.shape[0], dtype=np.int64), faces=np.asarray(f, np.int32),
                     uvs=np.full((p.shape[0], 2), 0.5, np.float32), width=floor, height=floor, texels_per_unit=0.0,
                     utilization=0.0)
    # the UVs are in [0, 1] of the image: an image within [floor, cap] holds the same charts scaled
    scale = min(cap, max(floor, side)) / side
    width, height = (max(1, min(cap, int(round(n * scale)))) for n in (width_texels, height_texels))
    return Atlas(vertex_of=np.asarray(vertex_of, np.int64), faces=np.asarray(atlas_faces, np.int32).reshape(-1, 3),
                 uvs=np.ascontiguousarray(uvs), width=width, height=height,
                 texels_per_unit=packed_density * scale / diagonal, utilization=utilization)
