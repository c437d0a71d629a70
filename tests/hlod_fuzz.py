"""The .hlod reader's fuzz run (tests/test_fuzz.py; benchmarks/fuzz_hlod.py runs it with more cases):
each mutated file (tests/hlod_mutations.py) opened, summarised, checked and, when it opens,
rendered, in a worker process, so that a crash (signal), a hang or a traceback is caught and named
with the case that causes it.

The worker (tests/hlod_fuzz_worker.py, a process of its own) runs each case: `hlod_file.load`
(memory-mapped and read, alternating), `Hlod.summary` and `checks.check` (what `info` prints),
then, if it opened, the methods `full`, `vfc` and `coh` over a generated inspection path on one
standalone EGL context. A typed error (HlodError) with a one-line message naming the file is a
clean refusal; anything else is a failure: another exception (its traceback), a refusal message on
several lines or without the file name, a GL error left pending, the worker killed by a signal, or
no answer within the timeout. Failures go to stderr as they come.
"""
from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from hlod_mutations import MUTATIONS, base_file, base_of, make_case

ROOT = Path(__file__).resolve().parents[1]
#: The worker: a script run in a process of its own, one file at a time.
WORKER_SCRIPT = Path(__file__).resolve().parent / "hlod_fuzz_worker.py"


class Worker:
    """The worker process, restarted after a crash or a hang."""

    def __init__(self, scratch: Path):
        self.scratch = scratch
        self.proc = None
        self.stderr_path = scratch / "worker_stderr.txt"

    def start(self) -> None:
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
        self._stderr = open(self.stderr_path, "ab")
        self.proc = subprocess.Popen([sys.executable, str(WORKER_SCRIPT)], cwd=ROOT, env=env,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr)

    def ask(self, index: int, path: Path, timeout_s: float) -> dict:
        if self.proc is None:
            self.start()
        try:
            self.proc.stdin.write(f"{index} {path}\n".encode())
            self.proc.stdin.flush()
        except BrokenPipeError:
            pass
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout_s)
        line = self.proc.stdout.readline() if ready else b""
        if line:
            return json.loads(line)
        if not ready:
            self.stop()
            return {"outcome": "failed", "stage": "?", "error": f"no answer within {timeout_s:g} s (hang)"}
        code = self.proc.wait()
        self.proc = None
        self._stderr.close()
        tail = self.stderr_path.read_bytes()[-2000:].decode("utf-8", "replace")
        what = f"signal {signal.Signals(-code).name}" if code < 0 else f"exit status {code}"
        return {"outcome": "failed", "stage": "?", "error": f"worker died: {what}\n{tail}"}

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait()
            self.proc = None
            self._stderr.close()


# --- driver --------------------------------------------------------------------------------------

def fuzz(*, cases: list[int], seed: int, timeout_s: float, keep: Path | None) -> dict:
    """Run `cases` of `seed` through one worker (restarted after a crash or a hang); the summary: counts
    by outcome and by kind, frames rendered, where refusals happened, the failures (their files
    written into `keep` when given), seconds."""
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="hlod_fuzz_") as scratch_name:
        scratch = Path(scratch_name)
        base = base_of(base_file(scratch))
        bake_s = time.perf_counter() - started
        worker = Worker(scratch)
        totals = {"loaded": 0, "refused": 0, "failed": 0}
        kinds = {k: {"cases": 0, "loaded": 0, "refused": 0, "failed": 0} for k in MUTATIONS}
        stages: dict[str, int] = {}
        failures, frames = [], 0
        try:
            sanity = _ask_file(worker, scratch, index=-1, data=base.data, timeout_s=timeout_s)
            if sanity["outcome"] != "loaded":
                raise RuntimeError(f"the unmutated base file does not load and render: {sanity}")
            for index in cases:
                what, data = make_case(base, seed, index)
                answer = _ask_file(worker, scratch, index=index, data=data, timeout_s=timeout_s)
                outcome = answer["outcome"]
                totals[outcome] += 1
                frames += answer.get("frames", 0)
                if outcome == "refused":
                    stages[answer["stage"]] = stages.get(answer["stage"], 0) + 1
                kind = MUTATIONS[index % len(MUTATIONS)]
                kinds[kind]["cases"] += 1
                kinds[kind][outcome] += 1
                if outcome == "failed":
                    failures.append({"case": index, "mutation": what, **answer})
                    print(f"hlod_fuzz: FAILED case {index} (reproduce: python -m benchmarks.fuzz_hlod "
                          f"--seed {seed} --case {index}): {what}\n  at {answer['stage']}: {answer['error']}",
                          file=sys.stderr, flush=True)
                    if keep is not None:
                        keep.mkdir(parents=True, exist_ok=True)
                        (keep / f"case_{seed}_{index}.hlod").write_bytes(data)
        finally:
            worker.stop()
    seconds = time.perf_counter() - started
    return {"seed": seed, "cases": len(cases), **totals, "frames_rendered": frames, "refused_at": stages,
            "by_kind": kinds, "base": {"bytes": len(base.data), "nodes": base.nodes, "tris": base.tris},
            "seconds": seconds, "bake_seconds": bake_s, "cases_per_second": len(cases) / (seconds - bake_s),
            "failures": [{k: f[k] for k in ("case", "mutation", "stage")} for f in failures]}


def _ask_file(worker: Worker, scratch: Path, *, index: int, data: bytes, timeout_s: float) -> dict:
    # A new name per case: the worker may still map the previous file, and rewriting a mapped file
    # in place would crash it (SIGBUS) for a reason that is ours, not the reader's.
    path = scratch / f"case_{index}.hlod"
    path.write_bytes(data)
    try:
        return worker.ask(index, path, timeout_s)
    finally:
        path.unlink()
