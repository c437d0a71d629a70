"""A child process and every process it starts, stopped together, on every platform
(docs/how-it-works.md#stopping-a-bake-on-every-platform).

The Blender extension bakes in a child process (bake/child.py) that starts worker processes. A
cancel must end them all, and a child whose parent has gone must end them itself:

- POSIX (Linux, macOS): the child leads a process group of its own (`start_new_session`); a stop is
  SIGTERM to the group (the child unwinds: its worker pool and scratch files go), a kill SIGKILL
  to the group.
- Windows has no process groups to signal: a stop closes the child's stdin, which the child reads
  (`--parent-stdin`) and takes as the request to stop, raising Terminated in its main thread
  (`stop_self`: the same unwinding as SIGTERM); a kill ends the tree with `taskkill /T /F`
  (TerminateProcess of the child and every descendant). The child is started in a new process
  group without a console window, so that a Ctrl-C or Ctrl-Break in Blender's console reaches
  Blender only.

Each function takes `platform` (a `sys.platform` string, default this machine's) so that each
branch can run on any machine; only a Windows machine runs the Windows branch end to end.
"""
from __future__ import annotations

import _thread
import os
import signal
import subprocess
import sys

#: Windows' process creation flags (subprocess names them only on Windows).
CREATE_NEW_PROCESS_GROUP = 0x00000200
CREATE_NO_WINDOW = 0x08000000


def windows(platform: str | None = None) -> bool:
    """Whether `platform` (default: this machine's sys.platform) is Windows."""
    return (sys.platform if platform is None else platform) == "win32"


def child_options(*, platform: str | None = None) -> dict:
    """subprocess.Popen's keyword arguments that make the child the root of a tree `ask_to_stop` and
    `kill_tree` reach (module notes). Pass stdin=subprocess.PIPE too: on Windows closing it is the stop."""
    if windows(platform):
        return {"creationflags": CREATE_NEW_PROCESS_GROUP | CREATE_NO_WINDOW}
    return {"start_new_session": True}


def ask_to_stop(proc: subprocess.Popen, *, platform: str | None = None) -> None:
    """Ask the child `proc` (started with child_options) and its workers to stop and clean up:
    POSIX, SIGTERM to its process group; Windows, its stdin closed (module notes). Nothing when it
    has ended already."""
    if windows(platform):
        if proc.stdin is not None and not proc.stdin.closed:
            try:
                proc.stdin.close()
            except OSError:  # a broken pipe: the child has gone
                pass
        return
    try:
        os.killpg(proc.pid, signal.SIGTERM)
    except (ProcessLookupError, PermissionError):
        pass


def kill_tree(pid: int, *, platform: str | None = None) -> None:
    """End the process `pid` and every process it started, now: POSIX, SIGKILL to its process group
    (pid leads it: child_options); Windows, `taskkill /PID pid /T /F`. Nothing when none is left."""
    if windows(platform):
        subprocess.run(["taskkill", "/PID", str(pid), "/T", "/F"], stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL, creationflags=CREATE_NO_WINDOW, check=False)
        return
    try:
        os.killpg(pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


def stop_self(*, platform: str | None = None) -> None:
    """The child's stop when its parent has gone or asked (module notes), from any thread: POSIX,
    SIGTERM to its process group when it leads one (its workers too), else to itself; Windows,
    Terminated raised in the main thread through its SIGTERM handler (`_thread.interrupt_main`:
    os.kill there would end the process at once, without its cleanup). The handler is
    core.signals.signals_as_exceptions's; without one nothing happens on Windows."""
    if windows(platform):
        _thread.interrupt_main(signal.SIGTERM)
        return
    if os.getpgrp() == os.getpid():
        os.killpg(os.getpgrp(), signal.SIGTERM)
    else:
        os.kill(os.getpid(), signal.SIGTERM)
