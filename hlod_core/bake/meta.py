"""The baked HLOD's meta: the input's size, the settings, the bake log, timings and what the cache
did, in one order whichever way the bake went (the file's bytes depend on it).

Data form: a JSON-serialisable dict (hierarchy.Hlod.meta). The entries the bake derives from
its nodes (`derived_meta`, DERIVED_META) are the ones a cached whole result keeps.
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from ..core.errors import InputError
from .decimate.collapse import OVER_BUDGET_FACTOR
from .decimate.simplify import NodeLod
from .settings import BakeSettings
from .space.octree import OctreeLayout

#: Lines the bake log keeps (the others are counted in "log_lines_dropped").
MAX_LOG_LINES = 200

#: meta entries that differ between two bakes of the same input at the same settings: timings, what
#: the cache did ("cache": {"nodes", "reused_nodes", "rebuilt_nodes", "reused_tris",
#: "rejected_entries", "reused_result", "budget_mb", "size_mb", "evicted_entries"}, present when
#: the bake had a cache folder) and where the frame came from ("frame_source": {"from", "reason"},
#: frame.FrameChoice). Everything else in the file is the same whether a bake came from scratch or
#: from the cache, given the same frame (`stable_meta`).
VOLATILE_META = ("bake_seconds", "phase_seconds", "cache", "frame_source")

#: The meta entries the bake derives from its nodes (`derived_meta`), with their JSON types: what a
#: cached whole result keeps (bake/run/cache.py); uv_seams_crossed_nodes only with appearance; frame: the
#: bake's frame (frame.Frame.to_meta).
DERIVED_META = {"leaves_over_budget": int, "collapsed_input_tris": int, "nodes_over_budget": int, "pruned_pieces": int,
                "pruned_tris": int, "log": list, "log_lines_dropped": int, "uv_seams_crossed_nodes": int,
                "frame": dict}

#: The meta entries a bake writes itself (extra_meta may not replace them).
OWN_META = frozenset({"generator", "input_tris", "input_vertices", "settings", "target_tris", "max_depth", "sources",
                      "proxies", *DERIVED_META, *VOLATILE_META})


def check_extra_meta(extra_meta: dict | None) -> None:
    """InputError where the caller's extra meta entries would replace the bake's own."""
    clash = sorted(set(extra_meta or {}) & OWN_META)
    if clash:
        raise InputError(f"extra_meta may not replace the bake's own meta entries ({', '.join(clash)})")


def stable_meta(meta: dict) -> dict:
    """meta without VOLATILE_META: what two bakes of the same input and settings agree on."""
    return {k: v for k, v in meta.items() if k not in VOLATILE_META}


@dataclass(frozen=True)
class InputSize:
    """What the meta says of the input: tris, vertices (used or not), name."""

    tris: int
    vertices: int
    name: str


class PhaseClock:
    """Seconds per bake phase (meta["phase_seconds"]), in the order the phases ran."""

    def __init__(self):
        self.started = time.perf_counter()
        self.seconds: dict[str, float] = {}
        self._last = self.started

    def lap(self, phase: str) -> None:
        """End `phase` now: it took the time since the previous lap (or the clock's start)."""
        now = time.perf_counter()
        self.seconds[phase] = now - self._last
        self._last = now

    def total(self) -> float:
        """Seconds since the clock started (meta["bake_seconds"])."""
        return time.perf_counter() - self.started


def counted_per_node(layout: OctreeLayout, counted) -> np.ndarray:
    """(n,) int64: each node's counted triangles (counted (f,) bool, by input triangle)."""
    counted_below = np.concatenate([[0], np.cumsum(counted[layout.tri_order])])
    return counted_below[layout.tri_end] - counted_below[layout.tri_begin]


def derived_meta(layout: OctreeLayout, made: dict[int, NodeLod], hausdorff: np.ndarray, *,
                 counted_per_node: np.ndarray, settings: BakeSettings, collapsed_tris: int, with_rows: bool,
                 frame: dict) -> dict:
    """The meta entries the bake derives from its nodes (DERIVED_META). made: inner node ->
    its LOD; hausdorff (n,) float64; counted_per_node (n,) int64; collapsed_tris: the input's
    triangles that are not counted; frame: the bake's frame (frame.Frame.to_meta). The log lists
    inner nodes in id order, however their LODs came."""
    bake_log: list[str] = []
    inner = np.flatnonzero(~layout.is_leaf)
    for node in inner:
        bake_log.extend(lod_notes(int(node), made[int(node)], error=hausdorff[node], target_tris=settings.target_tris))
    lods = [made[int(node)] for node in inner]
    pruned_pieces = sum(lod.pruned_pieces for lod in lods)
    pruned_tris = sum(lod.pruned_tris for lod in lods)
    freed = sum(int(lod.open_boundaries_freed) for lod in lods)
    if freed:
        bake_log.append(f"open boundaries collapsed to reach the target in {freed} nodes")
    if pruned_pieces:
        bake_log.append(f"pruned {pruned_pieces} pieces ({pruned_tris} input triangles) below their node's error "
                        f"or over its budget, in {sum(lod.pruned_pieces > 0 for lod in lods)} nodes")
    derived = {
        "leaves_over_budget": int((layout.is_leaf & (counted_per_node > settings.target_tris)).sum()),
        "collapsed_input_tris": int(collapsed_tris),
        "nodes_over_budget": sum(int(lod.faces.shape[0] > OVER_BUDGET_FACTOR * settings.target_tris) for lod in lods),
        "pruned_pieces": int(pruned_pieces),
        "pruned_tris": int(pruned_tris),
        "log": bake_log[:MAX_LOG_LINES],
        "log_lines_dropped": max(0, len(bake_log) - MAX_LOG_LINES),
        "frame": frame,
    }
    if with_rows:
        derived["uv_seams_crossed_nodes"] = sum(int(made[int(node)].uv_seams_crossed) for node in inner)
    return derived


def lod_notes(node: int, lod: NodeLod, *, error: float, target_tris: int) -> list[str]:
    """What the bake log says of one inner node's LOD (nothing for an ordinary one)."""
    notes = []
    tris = lod.faces.shape[0]
    if not lod.decimated:
        notes.append(f"node {node}: children hold {lod.input_tris} <= {target_tris} triangles; kept undecimated")
    elif tris >= lod.input_tris:
        notes.append(f"node {node}: LOD has {tris} triangles, not smaller than its children's {lod.input_tris}")
    elif tris > OVER_BUDGET_FACTOR * target_tris:
        kept = ("seam vertices (shared with neighbouring cells)" if lod.attributes is None
                else "seam, material-border and UV-seam vertices")
        notes.append(f"node {node}: decimation stopped at {tris} triangles, over {OVER_BUDGET_FACTOR:g} x the target "
                     f"{target_tris}: its {lod.locked_vertices} {kept} stay in place"
                     f"{'' if lod.open_boundaries_freed else ' with its open boundaries'}, and "
                     f"{lod.pieces - lod.pruned_pieces} separate pieces remain")
    if lod.uv_seams_crossed:
        notes.append(f"node {node}: UV seams crossed to reach {tris} triangles ({lod.seam_kept_tris} keeping "
                     f"them); {lod.island_spanning_faces} faces span two UV islands")
    if lod.zero_area:
        notes.append(f"node {node}: every triangle has zero area, which decimation removes; kept "
                     f"{tris} of the children's {lod.input_tris}")
    if lod.kept_in_place:
        notes.append(f"node {node}: optimal vertex placement left the node's box; decimated again "
                     "with vertices kept in place")
    if not np.isfinite(error):
        notes.append(f"node {node}: Hausdorff distance unavailable; error bounded by the node's box diagonal")
    return notes


#: The proxy settings meta["settings"] names only where they differ from the defaults.
PROXY_SETTINGS = ("proxy_materials", "texture_cap", "texture_floor")


def settings_meta(settings: BakeSettings) -> dict:
    """meta["settings"]: the settings' fields, but `error` only when it is not "exact": a file
    without it was measured exactly, and an exact bake writes the bytes it always wrote."""
    fields = asdict(settings)
    if fields["error"] == "exact":
        del fields["error"]
    for name in PROXY_SETTINGS:  # at their defaults a file writes the bytes it wrote before proxies
        if fields[name] == getattr(BakeSettings, name):
            del fields[name]
    return fields


def bake_meta(size: InputSize, settings: BakeSettings, derived: dict, *, cache_stats: dict | None,
              sources: list[str] | None, extra_meta: dict | None, clock: PhaseClock, frame_source: dict) -> dict:
    """The HLOD's meta, in one order whichever way the bake went (the file's bytes depend on it).
    derived: `derived_meta`'s entries; cache_stats: meta["cache"] (None: no cache); sources: the
    input files (default the input's name); extra_meta: the caller's entries (`check_extra_meta`);
    frame_source: where the frame came from (frame.FrameChoice.to_meta)."""
    meta = {
        "generator": "hlod_core",
        "input_tris": size.tris,
        "input_vertices": size.vertices,
        "settings": settings_meta(settings),
        "target_tris": settings.target_tris,
        "max_depth": settings.max_depth,
        "sources": list(sources or [size.name]),
        "leaves_over_budget": derived["leaves_over_budget"],
        "collapsed_input_tris": derived["collapsed_input_tris"],
        "nodes_over_budget": derived["nodes_over_budget"],
        "pruned_pieces": derived["pruned_pieces"],
        "pruned_tris": derived["pruned_tris"],
        "frame": derived["frame"],
        "frame_source": frame_source,
        "bake_seconds": clock.total(),
        "phase_seconds": clock.seconds,
        "log": derived["log"],
        "log_lines_dropped": derived["log_lines_dropped"],
    }
    if "uv_seams_crossed_nodes" in derived:
        meta["uv_seams_crossed_nodes"] = derived["uv_seams_crossed_nodes"]
    if "proxies" in derived:
        meta["proxies"] = derived["proxies"]
    if cache_stats is not None:
        meta["cache"] = cache_stats
    meta.update(extra_meta or {})
    return meta
