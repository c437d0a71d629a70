"""The .hlod reader under hostile input: a seeded fuzz run (tests/hlod_fuzz.py) of mutated small
files (tests/hlod_mutations.py), each opened, checked and, when it opens, rendered in a worker
process. It fails on any traceback, signal (the worker's SIGSEGV is caught and named), hang, or
refusal that is not one line naming the file. `bash bench.sh --fuzz N` runs the same with more cases."""
import os

import pytest

from hlod_fuzz import fuzz
from hlod_fuzz_worker import RENDER_FRAMES, RENDER_METHODS
from hlod_mutations import MUTATIONS

pytestmark = [pytest.mark.gl, pytest.mark.slow]  # renders every accepted file; about 20 s

FUZZ_CASES = 800  # about 20 s here; every mutation kind gets FUZZ_CASES / 8
FUZZ_SEED = int(os.environ.get("HLOD_FUZZ_SEED", "1"))  # reproduce with --seed S --case I


def test_fuzzed_files_open_cleanly_or_are_refused_in_one_line(tmp_path, capfd):
    summary = fuzz(cases=list(range(FUZZ_CASES)), seed=FUZZ_SEED, timeout_s=60.0, keep=tmp_path / "failed")
    stderr = capfd.readouterr().err
    assert "Traceback" not in stderr, stderr[-6000:]
    assert summary["cases"] == FUZZ_CASES and summary["failed"] == 0 and summary["failures"] == [], stderr[-6000:]
    assert summary["loaded"] + summary["refused"] == FUZZ_CASES
    # The run exercises both sides: many files refused, and enough accepted that the renderer and
    # the traversals met hostile geometry and bounds (every accepted file rendered every frame).
    assert summary["refused"] >= FUZZ_CASES // 2 and summary["loaded"] >= FUZZ_CASES // 10
    assert summary["frames_rendered"] == len(RENDER_METHODS) * RENDER_FRAMES * summary["loaded"]
    per_kind = FUZZ_CASES // len(MUTATIONS)
    assert {k: v["cases"] for k, v in summary["by_kind"].items()} == {k: per_kind for k in MUTATIONS}
    # range pairs whose sum wraps (the `overflow` mutation) are all refused, none crashes
    assert summary["by_kind"]["overflow"]["refused"] == FUZZ_CASES // len(MUTATIONS)
