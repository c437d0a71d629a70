"""GL query objects: a pool of ids reused across frames, and the non-blocking reads of their results.

Data form: a query object is a GL id (int). `Query` pairs a node with the ids of its occlusion
query (q, depth test on) and, for the `query` alpha estimator, of its unoccluded count (alpha,
depth test off); a multiquery (CHC++) is one q query over the boxes of several nodes, its
`members`. The pool generates ids in blocks of QUERY_BLOCK_SIZE and hands them out again
once their result has been read, to queries of the same target only: GL gives a query object the
type of its first glBeginQuery, and beginning it with another target is GL_INVALID_OPERATION.
"""
from __future__ import annotations

import ctypes
import time
from dataclasses import dataclass

from .gl_functions import GL, GLFunctions

#: Query ids generated per glGenQueries call when the pool runs dry.
QUERY_BLOCK_SIZE = 64
NS_PER_MS = 1e6


@dataclass
class Query:
    """One node's occlusion query in flight: GL ids of its q query and, optionally, its alpha query.
    A multiquery has the nodes whose boxes it drew in `members` (node: the first of them), no alpha."""

    node: int
    samples_query_id: int
    alpha_query_id: int | None
    members: tuple[int, ...] = ()


class QueryPool:
    """Query ids generated in blocks and reused; reads results without blocking where it can."""

    def __init__(self, gl: GLFunctions):
        self._gl = gl
        self._free: dict[int, list[int]] = {}  # target -> ids free for it
        self._all: list[int] = []
        self._unflushed = False  # an id was handed out since the last flush of `available`

    # --- ids --------------------------------------------------------------------------------------

    def acquire(self, target: int = GL.SAMPLES_PASSED) -> int:
        """A free id for queries of `target` (GL_SAMPLES_PASSED, or GL_TIME_ELAPSED for timers)."""
        self._unflushed = True
        free = self._free.setdefault(target, [])
        if not free:
            block = (ctypes.c_uint32 * QUERY_BLOCK_SIZE)()
            self._gl.gen_queries(QUERY_BLOCK_SIZE, block)
            self._all.extend(block)
            free.extend(block)
        return free.pop()

    def give_back(self, query_id: int, target: int = GL.SAMPLES_PASSED) -> None:
        """Hand `query_id` out again to queries of `target` (its result has been read)."""
        self._free.setdefault(target, []).append(query_id)

    @property
    def allocated(self) -> int:
        """How many ids the pool has generated (and not deleted)."""
        return len(self._all)

    @property
    def ids(self) -> list[int]:
        """Every id the pool has generated (and not deleted)."""
        return list(self._all)

    def release(self) -> None:
        """Delete every id this pool generated. Idempotent."""
        if self._all:
            ids = (ctypes.c_uint32 * len(self._all))(*self._all)
            self._gl.delete_queries(len(self._all), ids)
        self._all, self._free = [], {}

    # --- results ----------------------------------------------------------------------------------

    def available(self, query: Query) -> bool:
        """Non-blocking. When not yet available, flushes (so a deferred rasteriser starts) if a
        query was begun since the last such flush; a flush sends every command before it, so the
        query polled again needs none (llvmpipe: each flush ends its scene, about 40 us)."""
        flag = ctypes.c_uint32(0)
        last = query.alpha_query_id if query.alpha_query_id is not None else query.samples_query_id
        self._gl.get_query_uiv(last, GL.QUERY_RESULT_AVAILABLE, ctypes.byref(flag))
        if not flag.value and self._unflushed:
            self._unflushed = False
            self._gl.flush()
            self._gl.get_query_uiv(last, GL.QUERY_RESULT_AVAILABLE, ctypes.byref(flag))
        return bool(flag.value)

    def result(self, query: Query) -> tuple[int, int | None, float]:
        """(q, alpha or None, stall seconds). Blocks if the result is not available; the time
        blocked is returned as stall. Gives the query ids back to the pool."""
        ready = self.available(query)
        started = time.perf_counter()
        samples = self._read(query.samples_query_id)
        alpha = self._read(query.alpha_query_id) if query.alpha_query_id is not None else None
        stall_s = 0.0 if ready else time.perf_counter() - started
        self.give_back(query.samples_query_id)
        if query.alpha_query_id is not None:
            self.give_back(query.alpha_query_id)
        return samples, alpha, stall_s

    def elapsed_ms(self, timer_query_id: int) -> float:
        """A finished GL_TIME_ELAPSED query's time in milliseconds (blocks until it is available)."""
        value = ctypes.c_uint64(0)
        self._gl.get_query_ui64v(timer_query_id, GL.QUERY_RESULT, ctypes.byref(value))
        return value.value / NS_PER_MS

    def _read(self, query_id: int) -> int:
        value = ctypes.c_uint32(0)
        self._gl.get_query_uiv(query_id, GL.QUERY_RESULT, ctypes.byref(value))
        return int(value.value)
