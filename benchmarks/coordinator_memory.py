"""Where the bake process's memory goes: its resident memory at each phase of a command-line bake,
and (--trace) which allocations hold it.

    PYTHONPATH=. .venv/bin/python -m benchmarks.coordinator_memory [--tris 2000000] [--jobs 2]
        [--trace] [--baseline DIR] [--repeat 1]

The scene: benchmarks/bake_memory.py's city of statues of at least --tris triangles. Each run is
a fresh process (`python -m hlod_core -q bake SPEC -o OUT --jobs J --no-cache`, run in-process by a
small driver) that samples its own VmRSS every 10 ms from /proc/self/status and marks the end of
each part: reading the input (`read`), every phase of the bake's clock (meta.PhaseClock.lap:
prepare, octree, leaves, seams, simplify, assemble, ...) and writing the file (`write`). For
each part: its seconds (the bake's phase_seconds; reading: the command line's load_seconds; the
write: since the mark before it), the resident bytes at its end (anonymous, and files' pages)
and the largest sampled while it ran, and the kernel's high-water mark VmHWM at its end, all per
input triangle. With --trace, tracemalloc runs too (it
slows the bake; its seconds do not count) and each part's end lists the allocation sites that hold
the most (file:line, bytes per input triangle). --baseline DIR: the same runs with another checkout
(PYTHONPATH=DIR), alternated, and whether its file is this checkout's, byte for byte but the
volatile meta (bake_memory.same_file; "same_file"). The run's load average comes with it.

Data form: out/bench/coordinator_memory.json, {"runs": [{"checkout", "triangles", "load",
"peak_bytes" (VmHWM), "parts": [{"part", "end_bytes", "peak_bytes", "hwm_bytes", "top": [[site,
bytes], ...]}], "phase_seconds", "seconds"}]}.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_SECONDS = 0.01
TOP_SITES = 8


def _status(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024
    return 0


class _Recorder:
    """The sampler thread and the parts' marks of one run (module docstring)."""

    def __init__(self, trace: bool):
        self.trace = trace
        self.parts: list[dict] = []
        self.peak = 0
        self.done = threading.Event()
        self.lock = threading.Lock()
        self.thread = threading.Thread(target=self._sample, daemon=True)

    def _sample(self) -> None:
        while not self.done.is_set():
            rss = _status("VmRSS")
            with self.lock:
                self.peak = max(self.peak, rss)
            time.sleep(SAMPLE_SECONDS)

    def mark(self, part: str) -> None:
        import tracemalloc

        rss = _status("VmRSS")
        with self.lock:
            peak, self.peak = max(self.peak, rss), rss
        entry = {"part": part, "at": time.perf_counter(), "end_bytes": rss, "peak_bytes": peak,
                 "hwm_bytes": _status("VmHWM"), "anon_bytes": _status("RssAnon"),
                 "file_bytes": _status("RssFile") + _status("RssShmem")}
        if self.trace:
            entry["traced_bytes"], entry["traced_peak_bytes"] = tracemalloc.get_traced_memory()
            tracemalloc.reset_peak()
            stats = tracemalloc.take_snapshot().statistics("lineno")[:TOP_SITES]
            entry["top"] = [[f"{Path(s.traceback[0].filename).name}:{s.traceback[0].lineno}", s.size] for s in stats]
        self.parts.append(entry)


def child(spec: str, out: str, jobs: int, trace: bool) -> dict:
    """One bake in this process, instrumented (module docstring)."""
    import tracemalloc

    from hlod_core.bake import meta
    from hlod_core.cli import bake as cli_bake
    from hlod_core.cli import main as cli_main
    from hlod_core.io import hlod_file, meshes

    if trace:
        tracemalloc.start(1)
    recorder = _Recorder(trace)
    recorder.thread.start()
    lap, load_inputs = meta.PhaseClock.lap, meshes.load_inputs

    def marked_lap(clock, phase):
        lap(clock, phase)
        recorder.mark(phase)

    def marked_load(*args, **options):
        mesh = load_inputs(*args, **options)
        recorder.mark("read")
        return mesh

    def wrap_writer(name: str):
        writer = getattr(hlod_file, name, None)
        if writer is None:
            return

        def marked(*args, **options):
            result = writer(*args, **options)
            recorder.mark("write")
            return result
        setattr(hlod_file, name, marked)

    from hlod_core.bake import assemble
    if hasattr(assemble, "Assembled"):  # the streamed write
        streamed = assemble.Assembled.write

        def marked_write(*args, **options):
            streamed(*args, **options)
            recorder.mark("write")
        assemble.Assembled.write = marked_write
    meta.PhaseClock.lap = marked_lap
    cli_bake.meshes.load_inputs = marked_load
    for name in ("save", "write_streamed"):
        wrap_writer(name)
    started = time.perf_counter()
    import contextlib
    import io
    captured = io.StringIO()
    with contextlib.redirect_stdout(captured):
        status = cli_main.main(["-q", "bake", spec, "-o", out, "--jobs", str(jobs), "--no-cache"])
    seconds = time.perf_counter() - started
    recorder.done.set()
    recorder.thread.join()
    if status != 0:
        raise SystemExit(f"bake failed with status {status}")
    summary = json.loads(captured.getvalue().strip().splitlines()[-1])
    return {"triangles": summary["input_tris"], "peak_bytes": _status("VmHWM"), "parts": recorder.parts,
            "phase_seconds": summary["phase_seconds"], "seconds": seconds, "load_seconds": summary["load_seconds"]}


def run(checkout: Path, spec: Path, out: Path, *, jobs: int, trace: bool) -> dict:
    """One run in a fresh process of `checkout`'s hlod_core."""
    load = os.getloadavg()[0]
    command = [sys.executable, str(Path(__file__).resolve()), "--child", str(spec), str(out), str(jobs)]
    if trace:
        command.append("--trace")
    done = subprocess.run(command, cwd=checkout, env={**os.environ, "PYTHONPATH": str(checkout)},
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"run in {checkout} failed:\n{done.stderr[-3000:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    result.update(checkout=str(checkout), load=[load, os.getloadavg()[0]])
    return result


def report(result: dict) -> None:
    tris = result["triangles"]
    print(f"{result['checkout']}: {tris:,} triangles, peak {result['peak_bytes'] / tris:.0f} bytes a triangle "
          f"(VmHWM {result['peak_bytes'] / 2**20:.0f} MiB), {result['seconds']:.1f} s, load "
          f"{result['load'][0]:.1f} to {result['load'][1]:.1f}"
          + (f", the same file: {result['same_file']}" if "same_file" in result else "") + "; bytes an input triangle:")
    print("| part | seconds | resident at its end (anonymous, files) | largest while it ran | high-water mark "
          "| traced at its end, largest while it ran |")
    print("|---|---:|---:|---:|---:|---:|")
    for k, part in enumerate(result["parts"]):
        s = result["phase_seconds"].get(part["part"])
        if part["part"] in ("read", "write"):  # not bake phases: the command line's reading, the file's write
            s = result["load_seconds"] if part["part"] == "read" else part["at"] - result["parts"][k - 1]["at"]
        traced = "-"
        if "traced_bytes" in part:
            traced = f"{part['traced_bytes'] / tris:.0f}, {part['traced_peak_bytes'] / tris:.0f}"
        print(f"| {part['part']} | {'-' if s is None else f'{s:.2f}'} | {part['end_bytes'] / tris:.0f} "
              f"({part['anon_bytes'] / tris:.0f}, {part['file_bytes'] / tris:.0f}) | {part['peak_bytes'] / tris:.0f} | "
              f"{part['hwm_bytes'] / tris:.0f} | {traced} |")
        for site, size in part.get("top", []):
            print(f"|   {site} | | {size / tris:.1f} | | | |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tris", type=int, default=2_000_000)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--trace", action="store_true", help="tracemalloc's largest holders at each part's end")
    parser.add_argument("--baseline", type=Path, default=None, help="another checkout, run alternately")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bench")
    parser.add_argument("--child", nargs=3, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        print(json.dumps(child(args.child[0], args.child[1], int(args.child[2]), args.trace)))
        return
    sys.path.insert(0, str(ROOT))
    from benchmarks import bake_memory

    args.out.mkdir(parents=True, exist_ok=True)
    runs = []
    with tempfile.TemporaryDirectory(prefix="coordinator-memory-") as scratch:
        spec = bake_memory.spec_of(args.tris, Path(scratch))
        checkouts = [ROOT] + ([args.baseline.resolve()] if args.baseline else [])
        for k in range(args.repeat):
            for checkout in checkouts if k % 2 == 0 else checkouts[::-1]:
                out = Path(scratch) / f"out-{checkouts.index(checkout)}.hlod"
                result = run(checkout, spec, out, jobs=args.jobs, trace=args.trace)
                if len(checkouts) > 1 and (Path(scratch) / "out-0.hlod").exists() and out.name != "out-0.hlod":
                    result["same_file"] = bake_memory.same_file(Path(scratch) / "out-0.hlod", out)
                report(result)
                runs.append(result)
    (args.out / "coordinator_memory.json").write_text(json.dumps({"runs": runs}, indent=1))


if __name__ == "__main__":
    main()
