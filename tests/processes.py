"""Child processes in tests: the command line (`python -m hlod_core`) and its contract (the last
stdout line is one JSON object; a failure is one line on stderr), waiting for a condition without
a fixed sleep, and whether a process or a process group is gone."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

from helpers import ROOT

#: How often wait_for looks again (seconds): short against what it waits for, long against a busy loop.
POLL_S = 0.02


def hlod(*args, check: bool = True, timeout_s: float = 600, env: dict | None = None) -> subprocess.CompletedProcess:
    """`python -m hlod_core ARGS` from the repository root; with `check`, exit status 0 is asserted.
    timeout_s guards against a hang only (it is not what a test measures); env: variables added to
    this process's environment."""
    proc = subprocess.run([sys.executable, "-m", "hlod_core", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout_s, env={**os.environ, "PYTHONPATH": str(ROOT), **(env or {})})
    if check:
        assert proc.returncode == 0, proc.stderr
    return proc


def last_json(proc: subprocess.CompletedProcess) -> dict:
    """The last stdout line, read as the command's one JSON object."""
    return json.loads(proc.stdout.strip().splitlines()[-1])


def one_line_error(proc: subprocess.CompletedProcess) -> str:
    """The failure is exactly one line, the last on stderr (progress lines may come before it)."""
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    errors = [line for line in lines if "error" in line.lower() or "traceback" in line.lower()]
    assert len(errors) == 1 and lines[-1] == errors[0], proc.stderr
    return errors[0]


def write_text(path: Path, text: str) -> Path:
    """`text` written to `path`; the path (for building bad input files inline)."""
    path.write_text(text)
    return path


def wait_for(predicate, timeout_s: float, what: str) -> None:
    """Return as soon as predicate() is true; fail naming `what` after timeout_s (a hang guard, far
    longer than the wait should take on a loaded machine, not a measurement)."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(POLL_S)


def group_is_gone(pgid: int) -> bool:
    """No process of process group `pgid` exists any more."""
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return True
    return False


def alive(pid: int) -> bool:
    """Whether `pid` runs (a zombie counts as ended: an orphan's reaper may be slow to reap it)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def live_processes() -> dict[int, tuple[int, int]]:
    """{pid: (parent pid, process group)} of the live processes (zombies left out), from /proc."""
    found = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if fields[0] != "Z":
                found[int(entry.name)] = (int(fields[1]), int(fields[2]))
    return found


def live_group(pgid: int) -> list[int]:
    """The live processes of process group `pgid` (from /proc; zombies left out)."""
    return [pid for pid, (_, group) in live_processes().items() if group == pgid]


def wait_gone(pids, timeout_s: float = 20.0) -> bool:
    """Whether every process of `pids` has ended within timeout_s (a hang guard)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if not any(alive(p) for p in pids):
            return True
        time.sleep(POLL_S)
    return False
