"""The .hlod reader under hostile input: a seeded fuzz run (benchmarks/fuzz_hlod.py) of mutated
small files, each opened, checked and, when it opens, rendered in a worker process. It fails on any
traceback, signal (the worker's SIGSEGV is caught and named), hang, or refusal that is not one line
naming the file. `bash bench.sh --fuzz N` runs the same with more cases."""
import json
import os
import subprocess
import sys

import pytest

from benchmarks import fuzz_hlod

from helpers import ROOT

pytestmark = [pytest.mark.gl, pytest.mark.slow]  # renders every accepted file; about 20 s

FUZZ_CASES = 800  # about 20 s here; every mutation kind gets FUZZ_CASES / 8
FUZZ_SEED = int(os.environ.get("HLOD_FUZZ_SEED", "1"))  # reproduce with --seed S --case I


def test_fuzzed_files_open_cleanly_or_are_refused_in_one_line(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-m", "benchmarks.fuzz_hlod", "--cases", str(FUZZ_CASES),
                           "--seed", str(FUZZ_SEED), "--keep", str(tmp_path / "failed")],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert "Traceback" not in proc.stderr, proc.stderr[-6000:]
    assert proc.returncode == 0, proc.stderr[-6000:]
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["cases"] == FUZZ_CASES and summary["failed"] == 0 and summary["failures"] == []
    assert summary["loaded"] + summary["refused"] == FUZZ_CASES
    # The run exercises both sides: many files refused, and enough accepted that the renderer and
    # the traversals met hostile geometry and bounds (every accepted file rendered every frame).
    assert summary["refused"] >= FUZZ_CASES // 2 and summary["loaded"] >= FUZZ_CASES // 10
    per_file = len(fuzz_hlod.RENDER_METHODS) * fuzz_hlod.RENDER_FRAMES
    assert summary["frames_rendered"] == per_file * summary["loaded"]
    assert {k: v["cases"] for k, v in summary["by_kind"].items()} == \
        {k: FUZZ_CASES // len(fuzz_hlod.MUTATIONS) for k in fuzz_hlod.MUTATIONS}
    # range pairs whose sum wraps (the `overflow` mutation) are all refused, none crashes
    assert summary["by_kind"]["overflow"]["refused"] == FUZZ_CASES // len(fuzz_hlod.MUTATIONS)
