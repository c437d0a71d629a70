"""What one traversal frame did (docs/how-it-works.md#the-traversal-methods): `FrameStats`, its counters (`COUNTERS`,
the columns of per-frame tables, then `QUERY_COUNTERS`, under a GPU budget `STREAM_COUNTERS`, and with a host's
depth `DEPTH_COUNTERS`) and the node lists behind some of them."""
from __future__ import annotations

from dataclasses import dataclass, field

MS_PER_S = 1e3

#: FrameStats' counters, in the order of its fields (the columns of per-frame tables).
COUNTERS = ("dn", "rarn", "d", "tris", "queries", "traversed", "stall_ms", "cpu_ms", "gpu_ms", "frame_ms",
            "queries_off")
#: Counters added to COUNTERS after per-frame files were first written, with the value an older
#: file's frames had (report.per_frame_file fills them in): no frame had its queries off.
LATER_COUNTERS = {"queries_off": 0.0}
#: FrameStats' counters of the query stream (CHC++), after COUNTERS: not columns of the
#: evaluation's per-frame files, which keep the counters they were saved with.
QUERY_COUNTERS = ("multiqueries", "state_changes", "predicted", "probes")
#: FrameStats' counters of streamed node geometry and textures (render.residency), 0 without a GPU budget.
STREAM_COUNTERS = ("substitutions", "waiting", "resident_bytes", "upload_bytes", "upload_ms")
#: FrameStats' counter of a host's depth imported into the frame (the renderer's `depth_import_ms`;
#: render.depth_import), 0 without one.
DEPTH_COUNTERS = ("depth_import_ms",)


@dataclass
class FrameStats:
    """Counters of one frame (docs/how-it-works.md#the-traversal-methods). Times in milliseconds."""

    dn: int = 0          # drawn nodes
    rarn: int = 0        # drawn, then refined in the same frame
    d: int = 0           # drawn only after waiting for their own query
    tris: int = 0
    queries: int = 0     # node occlusion queries issued (the query alpha estimator adds one GL query each)
    traversed: int = 0   # nodes visited inside the frustum
    stall_ms: float = 0.0
    cpu_ms: float = 0.0
    gpu_ms: float = 0.0
    frame_ms: float = 0.0
    queries_off: int = 0    # 1: the method's queries were off this frame, drawn as VFC (query_gate)
    multiqueries: int = 0   # of `queries`, those over several nodes' boxes (CHC++)
    state_changes: int = 0  # the renderer's switches between drawing and querying (its `state_changes`)
    predicted: int = 0      # nodes not visited last frame drawn at once, assumed visible (predict_new)
    probes: int = 0         # of `queries`, those of a probe while the queries were off (query_gate)
    substitutions: int = 0  # nodes drawn in place of children whose geometry was not resident yet
    waiting: int = 0        # nodes wanted and still not resident after the frame's uploads
    resident_bytes: int = 0  # node geometry and textures on the GPU after the frame
    upload_bytes: int = 0    # node geometry and textures uploaded after the frame
    upload_ms: float = 0.0   # of frame_ms, the evictions and uploads after the frame
    depth_import_ms: float = 0.0  # of frame_ms, the host's depth uploaded and written at the frame's start
    drawn: list = field(default_factory=list)       # node ids in draw order (not counters)
    delayed: list = field(default_factory=list)     # the nodes counted in d
    refined_after_draw: list = field(default_factory=list)  # the nodes counted in rarn
    skipped: list = field(default_factory=list)  # visible, stopped nodes drawn without their query
    queries_note: str = ""  # with queries_off: why (query_gate.QueryGate.reason)
