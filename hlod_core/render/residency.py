"""Which nodes' geometry and textures are on the GPU, under a byte budget: the bookkeeping of
streamed nodes (docs/how-it-works.md#streaming-node-geometry). No GL here: the renderer's
`StreamedGeometry` uploads and frees what this decides.

Data form: node table arrays (n,) from hlod_core.model.hierarchy.Hlod; `node_bytes` (n,) int64 is
what node i's geometry takes on the GPU (its vertex buffers and its index buffer); `node_textures`
per node the numbers of the textures it draws with, of `texture_bytes` (k,) int64 (texture_table.py).
A texture is resident while a resident node uses it (a count of them per texture): it comes with
the first such node and goes with the last, so a proxy texture, which one node uses, comes and goes
with its node, and a source texture shared by many leaves is counted once. A node's bytes are its
geometry and the textures it would bring. Per node: resident, pinned (the root and the top levels,
never evicted) and the frame it was last used in.

A frame: the traversal calls `use(node)` for every node it visits and `can_refine(node, ...)`
before it descends into a node's children: False when a child is not resident, and then that node
is drawn in its children's place (it is their nearest resident ancestor: a node is only reached
through a parent whose children were all resident) and its missing children are requested with
the traversal's priority (visible first, then screen-space error over tau). After the frame,
`plan()` says which nodes to evict and which to upload: requests in priority order, at most
`upload_bytes_per_frame` a frame (at least one node, so a node larger than that still comes), room
made by evicting the least recently used nodes that this frame did not use and that are not
pinned (with the textures no other resident node uses); a request that cannot fit waits, and a
node larger than the budget by itself waits for ever (its ancestor stands in). Resident bytes
never exceed the budget, except that the root is always resident (one node's slack when the
budget is below the root's size with its textures).

When the whole file fits in the budget every node is made resident at the start (`preload_all`):
no node is ever waited for, and the frames are those of an unlimited budget.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError

#: Default bytes uploaded per frame when streaming: a few milliseconds of copying.
UPLOAD_BYTES_PER_FRAME = 4 << 20
#: Share of the budget the pinned top levels may take (whole levels only; the root always).
PINNED_SHARE = 0.125
BYTES_PER_MB = 1 << 20
#: Generations below a held-back node that are requested with it (children, grandchildren, ...),
#: following the nodes whose screen-space error says they would refine.
PREFETCH_GENERATIONS = 4
#: A node wanted now takes the place of nodes unused for at least this many frames; a prefetched
#: node, of nodes unused for PREFETCH_EVICTS_AFTER_FRAMES.
EVICTS_AFTER_FRAMES = 1
PREFETCH_EVICTS_AFTER_FRAMES = 8


@dataclass(frozen=True)
class StreamingSettings:
    """budget_bytes: the GPU bytes node geometry and textures may take (0: unlimited, everything
    uploaded at the start); upload_bytes_per_frame: the most bytes uploaded after one frame."""

    budget_bytes: int = 0
    upload_bytes_per_frame: int = UPLOAD_BYTES_PER_FRAME

    def __post_init__(self):
        for name in ("budget_bytes", "upload_bytes_per_frame"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise InputError(f"{name}: expected a whole number of bytes >= 0, got {value!r}")
        if self.upload_bytes_per_frame == 0:
            raise InputError("upload_bytes_per_frame: expected at least 1 byte a frame")

    @property
    def unlimited(self) -> bool:
        return self.budget_bytes == 0

    @classmethod
    def from_megabytes(cls, budget_mb: float, **kwargs) -> "StreamingSettings":
        """budget in MB (2**20 bytes; 0: unlimited)."""
        if not np.isfinite(budget_mb) or budget_mb < 0:
            raise InputError(f"GPU budget: expected a number of MB >= 0, got {budget_mb!r}")
        return cls(budget_bytes=int(round(budget_mb * BYTES_PER_MB)), **kwargs)


@dataclass(frozen=True)
class Plan:
    """What to do after a frame: free `evict` (node ids), then upload `upload` (node ids, in order)."""

    evict: tuple[int, ...]
    upload: tuple[int, ...]


class Residency:
    """Residency of node geometry and textures under `settings.budget_bytes` (module docstring).
    child_offset, child_count, depth: (n,) node table arrays; node_bytes (n,) int64; node_textures:
    per node a tuple of texture numbers, of texture_bytes (k,) int64 (None: no textures)."""

    def __init__(self, *, child_offset: np.ndarray, child_count: np.ndarray, depth: np.ndarray,
                 node_bytes: np.ndarray, settings: StreamingSettings, node_textures=None, texture_bytes=None):
        if settings.unlimited:
            raise InputError("Residency needs a GPU budget (an unlimited budget uploads every node at the start)")
        self.settings = settings
        self.node_bytes = np.asarray(node_bytes, np.int64)
        n = self.node_bytes.shape[0]
        self.texture_bytes = np.zeros(0, np.int64) if texture_bytes is None else np.asarray(texture_bytes, np.int64)
        self._textures = [()] * n if node_textures is None else [tuple(t) for t in node_textures]
        self._texture_size = self.texture_bytes.tolist()
        self.texture_users = np.zeros(self.texture_bytes.shape[0], np.int64)  # resident nodes using each
        self._planned_textures: set[int] = set()  # the textures the last plan's uploads draw with
        self._held: set[int] = set()  # of those, the ones whose last user was evicted before they came
        self._child_offset = np.asarray(child_offset, np.int64).tolist()
        self._child_count = np.asarray(child_count, np.int64).tolist()
        self._bytes = self.node_bytes.tolist()
        self.resident = np.zeros(n, bool)
        self.pinned = np.zeros(n, bool)
        self.last_used = np.full(n, -1, np.int64)
        self.frame = 0
        self.resident_bytes = 0
        self.resident_bytes_peak = 0
        self.uploaded_bytes = 0  # since the start
        self.substitutions = 0  # this frame: refinements held back by a child not yet resident
        self.upload_seconds = 0.0  # the owner's evictions and uploads after the last frame
        self._requests: dict[int, tuple[float, float]] = {}
        depth = np.asarray(depth, np.int64)
        per_level = self._bytes_per_level(depth)
        self.preload_all = int(per_level.sum()) <= settings.budget_bytes
        self.pinned[self._pinned_levels(depth, per_level)] = True

    def _bytes_per_level(self, depth: np.ndarray) -> np.ndarray:
        """(depth.max() + 1,) float64: each level's geometry, and each texture once, at the
        shallowest level that uses it (so levels 0..d together hold their textures once)."""
        levels = int(depth.max()) + 1 if depth.size else 1
        per_level = np.bincount(depth, weights=self.node_bytes.astype(np.float64), minlength=levels)
        shallowest = np.full(self.texture_bytes.shape[0], levels, np.int64)
        users = np.repeat(np.arange(len(self._textures)), [len(t) for t in self._textures])
        np.minimum.at(shallowest, np.fromiter((t for ts in self._textures for t in ts), np.int64), depth[users])
        used = shallowest < levels
        per_level += np.bincount(shallowest[used], weights=self.texture_bytes[used].astype(np.float64),
                                 minlength=levels)
        return per_level

    def _pinned_levels(self, depth: np.ndarray, per_level: np.ndarray) -> np.ndarray:
        """Every node when the file fits; else the root and whole top levels within PINNED_SHARE."""
        if self.preload_all:
            return np.ones(depth.shape[0], bool)
        share = PINNED_SHARE * self.settings.budget_bytes
        levels = int(np.searchsorted(np.cumsum(per_level), share, side="right"))
        return depth < max(1, levels)

    @property
    def texture_resident(self) -> np.ndarray:
        """(k,) bool: the textures some resident node uses (or a planned upload will)."""
        resident = self.texture_users > 0
        resident[list(self._held)] = True
        return resident

    def textures_to_make(self, node: int) -> tuple[int, ...]:
        """The textures `node` uses that are not resident: the owner makes them with it."""
        users, held = self.texture_users, self._held
        return tuple(t for t in self._textures[node] if users[t] == 0 and t not in held)

    # --- the start ---------------------------------------------------------------------------------

    def initial_uploads(self) -> tuple[int, ...]:
        """The pinned nodes, root first (top-down): upload them before the first frame."""
        return tuple(int(i) for i in np.flatnonzero(self.pinned))

    def uploaded(self, node: int) -> None:
        """The owner uploaded `node` and made its `textures_to_make` (after a plan's evictions)."""
        self._planned_textures = set()  # the plan's evictions are done
        if not self.resident[node]:
            size = self._bytes[node] + sum(self._texture_size[t] for t in self.textures_to_make(node))
            for t in self._textures[node]:
                self.texture_users[t] += 1
                self._held.discard(t)
            self.resident[node] = True
            self.resident_bytes += size
            self.uploaded_bytes += size
            self.resident_bytes_peak = max(self.resident_bytes_peak, self.resident_bytes)

    def evicted(self, node: int) -> tuple[int, ...]:
        """The owner freed `node`; the textures no resident node uses now (the owner frees them).
        A texture that a node the plan uploads draws with is kept for it, not freed and made again."""
        if not self.resident[node]:
            return ()
        self.resident[node] = False
        self.resident_bytes -= self._bytes[node]
        unused = []
        for t in self._textures[node]:
            self.texture_users[t] -= 1
            if self.texture_users[t] > 0:
                continue
            if t in self._planned_textures:
                self._held.add(t)
            else:
                unused.append(t)
                self.resident_bytes -= self._texture_size[t]
        return tuple(unused)

    # --- a frame ---------------------------------------------------------------------------------

    def begin_frame(self) -> None:
        self.frame += 1
        self.substitutions = 0
        self._requests.clear()

    def use(self, node: int) -> None:
        """The traversal visits `node` this frame (it will not be evicted after it)."""
        self.last_used[node] = self.frame

    def can_refine(self, node: int, *, visible: bool, error_over_tau: float, needed=None, refines=None) -> bool:
        """May the traversal descend into `node`'s children? False when one it needs is not
        resident (`needed(child)`: would the traversal draw or refine it if visible, e.g. is it in
        the frustum; None: every child): the node then stands in for them this frame (counted) and
        they are requested with priority (visible, error_over_tau): visible first, then the larger
        screen-space error over tau. `refines(child)`: would the child refine at full visibility
        (its SSE over tau)? Then its needed children are requested too, a generation later, and so
        on down: the levels a moving view is about to want come in one frame, not one a frame."""
        first = self._child_offset[node]
        resident = self.resident
        needed_children = [c for c in range(first, first + self._child_count[node]) if needed is None or needed(c)]
        missing = [c for c in needed_children if not resident[c]]
        if not missing:
            return True
        self.substitutions += 1
        self.last_used[needed_children] = self.frame  # the resident ones wait for their siblings: kept
        requests, rank = self._requests, 1.0 if visible else 0.0
        generation, level = 0, missing
        while level and generation < PREFETCH_GENERATIONS:
            priority = (rank, -float(generation), float(error_over_tau))
            deeper = []
            for child in level:
                if not resident[child] and requests.get(child, (-1.0, -1e9, -1.0)) < priority:
                    requests[child] = priority
                if refines is not None and refines(child):
                    first = self._child_offset[child]
                    deeper.extend(c for c in range(first, first + self._child_count[child])
                                  if needed is None or needed(c))
            generation, level = generation + 1, deeper
        return False

    @property
    def waiting(self) -> int:
        """Nodes requested this frame and not resident (after `plan`'s uploads: still waiting)."""
        resident = self.resident
        return sum(1 for node in self._requests if not resident[node])

    def plan(self) -> Plan:
        """Evictions and uploads after this frame (module docstring); the owner performs them and
        calls `evicted` / `uploaded` for each."""
        budget = self.settings.budget_bytes
        cap = self.settings.upload_bytes_per_frame
        order = sorted(self._requests, key=lambda node: self._requests[node], reverse=True)
        candidates = [int(i) for i in np.flatnonzero(self.resident & ~self.pinned & (self.last_used < self.frame))]
        candidates.sort(key=lambda i: (int(self.last_used[i]), -i))  # least recently used first, deepest id first
        users = self.texture_users
        planned: dict[int, int] = {}  # texture -> its users after this plan, where they change

        def users_of(texture: int) -> int:
            return planned.get(texture, users[texture])

        evict, upload = [], []
        projected = self.resident_bytes
        sent = 0
        for node in order:
            textures = self._textures[node]
            size = self._bytes[node] + sum(self._texture_size[t] for t in textures if users_of(t) == 0)
            if upload and sent + size > cap:
                break
            # a node wanted now pushes out nodes unused this frame and the last (a cut that does not
            # fit then settles instead of alternating); a prefetched one only nodes unused for a while
            unused_frames = EVICTS_AFTER_FRAMES if self._requests[node][1] == 0.0 else PREFETCH_EVICTS_AFTER_FRAMES
            oldest = self.frame - unused_frames
            taken, freed, dropped = 0, 0, {}  # dropped: texture -> users the evictions take away
            while projected - freed + size > budget and taken < len(candidates) \
                    and self.last_used[candidates[taken]] < oldest:
                victim = candidates[taken]
                freed += self._bytes[victim]
                for t in self._textures[victim]:  # its textures go with the last user (not one `node` needs)
                    dropped[t] = dropped.get(t, 0) + 1
                    if dropped[t] == users_of(t) and t not in textures:
                        freed += self._texture_size[t]
                taken += 1
            if projected - freed + size > budget:
                continue  # no room can be made for it this frame (a nearer request may still fit)
            for t, count in dropped.items():
                planned[t] = users_of(t) - count
            for t in textures:
                planned[t] = users_of(t) + 1
            evict.extend(candidates[:taken])
            del candidates[:taken]
            projected -= freed
            upload.append(node)
            projected += size
            sent += size
        self._planned_textures = {t for node in upload for t in self._textures[node]}
        return Plan(evict=tuple(evict), upload=tuple(upload))
