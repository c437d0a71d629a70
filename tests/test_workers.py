"""The bake's worker pool (hlod_core/bake/run/workers.py) when a worker dies while it sends its
result: a cancel stops the whole process group, so a worker can be killed half-way through
writing a result to the pool's pipe. The pool's manager thread then waited for the rest of that
message forever, and the bake's exit with it (a Blender bake's child outlived Blender, holding its
scratch folder). Checked in a separate process, so that a hang is a timeout, not a stuck suite."""
import subprocess
import sys
import textwrap

from helpers import ROOT

#: A hang guard: leaving the pool takes well under a second once its workers are killed.
EXIT_TIMEOUT_S = 120

SCRIPT = textwrap.dedent("""
    import os, signal, sys, time
    import numpy as np
    from hlod_core.bake.run import workers

    class Stop(Exception):
        pass

    victim, left_s = None, None
    try:
        with workers.open_workers(2) as pool:
            pool.executor.submit(np.ones, 200_000_000, np.uint8)  # a 200 MB result: written in many pieces
            deadline = time.monotonic() + 60
            while victim is None and time.monotonic() < deadline:
                for pid in list(pool.executor._processes):
                    try:
                        with open(f"/proc/{pid}/wchan") as f:
                            if "pipe_write" in f.read():  # blocked half-way through the result
                                victim = pid
                    except OSError:
                        pass
            if victim is not None:
                os.kill(victim, signal.SIGKILL)
            started = time.monotonic()
            raise Stop()
    except Stop:
        left_s = time.monotonic() - started
    print(victim is not None, round(left_s, 2))
""")


def test_a_worker_killed_while_it_writes_a_result_does_not_hang_the_bake(tmp_path):
    """A worker is killed while blocked writing a 200 MB result into the pool's pipe, then the
    block is left by an exception (as a cancel leaves it): it is left, in seconds."""
    run = subprocess.run([sys.executable, "-c", SCRIPT], cwd=ROOT, capture_output=True, text=True,
                         timeout=EXIT_TIMEOUT_S, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin",
                                                      "TMPDIR": str(tmp_path)})
    assert run.returncode == 0, run.stderr[-2000:]
    killed_mid_write, left_s = run.stdout.split()
    assert killed_mid_write == "True", run.stdout
    assert float(left_s) < EXIT_TIMEOUT_S / 2, run.stdout
