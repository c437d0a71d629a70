"""The traversal's own Python time, measured apart from the renderer's (benchmarks/traversal_cpu.py
prints it; the traversal tests check the measurement): a timing proxy (TimedRenderer) takes the
time spent inside the renderer (GL calls, waits for query results, the frame's start and end) out
of the frame, a renderer without GL (NullRenderer) leaves the Python alone, and another version's
traversal (baseline_traversal) runs next to this one's for a paired comparison.

Data form: run's result, {method: {"visited", "prepare_us", "walk_us_per_node", "python_us_per_node",
"renderer_ms", "frames"}} (medians over repeats of per-path means).
"""
from __future__ import annotations

import importlib.util
import statistics
import sys
import time
from pathlib import Path
from types import ModuleType
from typing import NamedTuple

import numpy as np

from hlod_core.io.textures import load_images
from hlod_core.model.camera_path import CameraPath
from hlod_core.model.hierarchy import Hlod, query_box_pad
from hlod_core.render.queries import Query
from hlod_core.render.renderer import Renderer
from hlod_core.traversal.methods import make
from hlod_core.traversal.settings import RuntimeSettings

US_PER_S = 1e6
MS_PER_S = 1e3
#: The renderer calls a traversal makes; time inside them is the renderer's, not the traversal's.
RENDERER_CALLS = ("begin_frame", "end_frame", "draw_node", "issue_query", "issue_queries", "issue_multiquery",
                  "available", "result")
#: --clock: seconds of wall time, or of this thread's CPU time.
CLOCKS = {"wall": time.perf_counter, "thread": time.thread_time}


class TimedRenderer:
    """Forwards to a real renderer and sums the seconds (of `clock`) spent inside RENDERER_CALLS."""

    def __init__(self, renderer: Renderer, clock=time.perf_counter):
        self._renderer = renderer
        self._clock = clock
        self.inside_s = 0.0
        self.calls = 0
        for name in RENDERER_CALLS:
            if hasattr(renderer, name):  # the batched calls are optional (traversal.protocol.NodeRenderer)
                setattr(self, name, self._timed(getattr(renderer, name)))

    def _timed(self, call):
        clock = self._clock

        def timed(*args, **kwargs):
            self.calls += 1
            started = clock()
            try:
                return call(*args, **kwargs)
            finally:
                self.inside_s += clock() - started
        return timed

    def __getattr__(self, name):  # attributes such as query_box_pad
        return getattr(self._renderer, name)


class NullRenderer:
    """A renderer without GL for the traversal's Python alone: draws nothing; every query is back at
    once with q = NULL_ALPHA_PX * v(node), v a seeded visibility in [0, 1) per node, 0 for a fifth of
    the nodes (hidden), alpha = NULL_ALPHA_PX."""

    NULL_ALPHA_PX = 1000

    def __init__(self, hlod: Hlod, seed: int = 0):
        visibility = np.random.default_rng(seed).random(hlod.node_count)
        visibility[visibility < 0.2] = 0.0
        self._q = (self.NULL_ALPHA_PX * visibility).astype(np.int64).tolist()
        self.query_box_pad = query_box_pad(hlod.box_min, hlod.box_max)

    def begin_frame(self, view) -> None:
        pass

    def end_frame(self) -> float:
        return 0.0

    def draw_node(self, node: int, ratio_p: float = 1.0) -> None:
        pass

    def issue_query(self, node: int, *, with_alpha: bool) -> Query:
        return Query(node=node, samples_query_id=0, alpha_query_id=None)

    def issue_queries(self, nodes, *, with_alpha: bool) -> list[Query]:
        return [Query(node=node, samples_query_id=0, alpha_query_id=None) for node in nodes]

    def issue_multiquery(self, nodes) -> Query:
        return Query(node=nodes[0], samples_query_id=0, alpha_query_id=None, members=tuple(nodes))

    def available(self, query: Query) -> bool:
        return True

    def result(self, query: Query) -> tuple[int, int | None, float]:
        if query.members:  # a multiquery: the sum of its members' counts, no alpha
            return sum(self._q[node] for node in query.members), None, 0.0
        return self._q[query.node], self.NULL_ALPHA_PX, 0.0

    def release(self) -> None:
        pass


def proxy_overhead_s(calls: int = 20000, clock=time.perf_counter) -> float:
    """Seconds the proxy adds per call outside its own clock reads (the closure, the counter), measured
    here and taken out of the traversal's time."""
    proxy = TimedRenderer.__new__(TimedRenderer)
    proxy.inside_s, proxy.calls, proxy._clock = 0.0, 0, clock
    timed = TimedRenderer._timed(proxy, lambda: None)
    started = clock()
    for _ in range(calls):
        timed()
    return max(0.0, (clock() - started - proxy.inside_s) / calls)


class Baseline(NamedTuple):
    """Another version's traversal: the module with its `make`, and its RuntimeSettings class."""

    methods: ModuleType
    settings_type: type


def baseline_traversal(folder: str) -> Baseline:
    """The traversal of the hlod_core package in `folder`, imported as package hlod_core_baseline
    (its relative imports resolve inside it)."""
    package = Path(folder) / "hlod_core"
    flat = (package / "traversal.py").is_file()  # a version from before the subpackages
    if not flat and not (package / "traversal" / "methods.py").is_file():
        raise SystemExit(f"--baseline {folder}: no hlod_core/traversal/methods.py there")
    for name in [name for name in sys.modules if name.split(".")[0] == "hlod_core_baseline"]:
        del sys.modules[name]  # a baseline imported before, maybe from another folder
    spec = importlib.util.spec_from_file_location("hlod_core_baseline", package / "__init__.py",
                                                  submodule_search_locations=[str(package)])
    module = importlib.util.module_from_spec(spec)
    sys.modules["hlod_core_baseline"] = module
    spec.loader.exec_module(module)
    methods = importlib.import_module("hlod_core_baseline.traversal" + ("" if flat else ".methods"))
    if hasattr(methods, "RuntimeSettings"):  # a version before traversal/settings.py
        return Baseline(methods, methods.RuntimeSettings)
    return Baseline(methods, importlib.import_module("hlod_core_baseline.traversal.settings").RuntimeSettings)


def measure(hlod: Hlod, method: str, path: CameraPath, *, settings: RuntimeSettings, size: tuple[int, int],
            renderer: Renderer, call_overhead_s: float, clock=time.perf_counter,
            baseline: Baseline | None = None) -> dict:
    """One pass of `method` over `path`: per-frame means of the traversal's Python time (`clock`
    seconds; call_overhead_s measured with the same clock). baseline: another version's traversal
    (`baseline_traversal`), its RuntimeSettings made from `settings`' fields."""
    proxy = TimedRenderer(renderer, clock)
    if baseline is None:
        traversal = make(method, hlod, proxy, settings=settings)
    else:
        fields = baseline.settings_type.__dataclass_fields__
        theirs = baseline.settings_type(**{k: v for k, v in vars(settings).items() if k in fields})
        traversal = baseline.methods.make(method, hlod, proxy, settings=theirs)
    # the per-frame vectorised step, `prepare` (`_prepare` in versions before the traversal's subpackage)
    prepare_name = "prepare" if hasattr(traversal, "prepare") else "_prepare"
    prepare = getattr(traversal, prepare_name)
    prepare_s = {"s": 0.0}

    def timed_prepare(view):
        started = clock()
        prepare(view)
        prepare_s["s"] += clock() - started
    setattr(traversal, prepare_name, timed_prepare)
    visited = 0
    total_s = 0.0
    for i in range(len(path)):
        view = path.view(i, size)
        started = clock()
        stats = traversal.frame(view)
        total_s += clock() - started
        visited += stats.traversed
    frames = len(path)
    python_s = total_s - proxy.inside_s - proxy.calls * call_overhead_s
    walk_s = python_s - prepare_s["s"]
    return {"visited": visited / frames, "prepare_us": US_PER_S * prepare_s["s"] / frames,
            "walk_us_per_node": US_PER_S * walk_s / max(visited, 1),
            "python_us_per_node": US_PER_S * python_s / max(visited, 1),
            "renderer_ms": MS_PER_S * proxy.inside_s / frames, "frames": frames}


def run(hlod: Hlod, path: CameraPath, size: tuple[int, int], *, methods: list[str], repeat: int,
        settings: RuntimeSettings, clock: str = "wall", null_renderer: bool = False,
        baseline: Baseline | None = None) -> dict:
    """{row: medians}, a row per method, and per "METHOD (baseline)" with a baseline."""
    overhead_s = proxy_overhead_s(clock=CLOCKS[clock])
    versions = [(m, m, None) for m in methods]
    if baseline is not None:  # each method's two versions side by side, alternating which goes first
        versions = [v for m in methods for v in ((m, m, None), (f"{m} (baseline)", m, baseline))]
    runs: dict[str, list[dict]] = {row: [] for row, _, _ in versions}
    if null_renderer:
        renderer = NullRenderer(hlod)
    else:
        renderer = Renderer.create_standalone(hlod, size, images=load_images(hlod))
    try:
        for rep in range(repeat):
            for row, method, module in (versions if rep % 2 == 0 else versions[::-1]):
                runs[row].append(measure(hlod, method, path, settings=settings, size=size, renderer=renderer,
                                         call_overhead_s=overhead_s, clock=CLOCKS[clock], baseline=module))
    finally:
        renderer.release()
    return {row: {k: statistics.median(r[k] for r in runs[row]) for k in runs[row][0]} for row in runs}
