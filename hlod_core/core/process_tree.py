"""A child process and every process it starts, stopped together, on every platform
(docs/how-it-works.md#stopping-a-bake-on-every-platform).

The Blender extension bakes in a child process (bake/run/child.py) that starts worker processes. A
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

A child that dies on its own (a crash, End task) must not leave its workers running
(`end_with_self`, `end_leftovers`). POSIX: its pid names its process group until the parent reaps
it, and the parent SIGKILLs the group before reaping it. Windows ends no process's children with it,
and taskkill /T walks the tree from a live root: the child puts itself, before it starts any
worker, in a job object that ends every process in it when its last handle closes
(JOB_OBJECT_LIMIT_KILL_ON_JOB_CLOSE); the only handle is the child's, which Windows closes as the
child ends, however it ends, and the workers it starts are in the job too.

Each function takes `platform` (a `sys.platform` string, default this machine's) so that each
branch can run on any machine; only a Windows machine runs the Windows branch end to end.
"""
from __future__ import annotations

import _thread
import ctypes
import os
import signal
import subprocess
import sys

#: Windows' process creation flags (subprocess names them only on Windows).
CREATE_NEW_PROCESS_GROUP = 0x00000200
CREATE_NO_WINDOW = 0x08000000
#: Windows' job objects (winnt.h): the limit flag, and SetInformationJobObject's class of
#: JOBOBJECT_EXTENDED_LIMIT_INFORMATION.
JOB_OBJECT_LIMIT_KILL_ON_JOB_CLOSE = 0x00002000
JOB_OBJECT_EXTENDED_LIMIT_INFORMATION_CLASS = 9


class _BasicLimits(ctypes.Structure):
    """JOBOBJECT_BASIC_LIMIT_INFORMATION (winnt.h): LARGE_INTEGER int64, SIZE_T and ULONG_PTR size_t, DWORD uint32."""

    _fields_ = [("PerProcessUserTimeLimit", ctypes.c_int64), ("PerJobUserTimeLimit", ctypes.c_int64),
                ("LimitFlags", ctypes.c_uint32), ("MinimumWorkingSetSize", ctypes.c_size_t),
                ("MaximumWorkingSetSize", ctypes.c_size_t), ("ActiveProcessLimit", ctypes.c_uint32),
                ("Affinity", ctypes.c_size_t), ("PriorityClass", ctypes.c_uint32), ("SchedulingClass", ctypes.c_uint32)]


class JobLimits(ctypes.Structure):
    """JOBOBJECT_EXTENDED_LIMIT_INFORMATION (winnt.h; 144 bytes on 64-bit Windows): the basic
    limits, IO_COUNTERS (six uint64) and four SIZE_T."""

    _fields_ = [("BasicLimitInformation", _BasicLimits), ("IoInfo", ctypes.c_uint64 * 6),
                ("ProcessMemoryLimit", ctypes.c_size_t), ("JobMemoryLimit", ctypes.c_size_t),
                ("PeakProcessMemoryUsed", ctypes.c_size_t), ("PeakJobMemoryUsed", ctypes.c_size_t)]


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


def end_with_self(*, platform: str | None = None, kernel32=None) -> int | None:
    """Make every process this one starts from now on end when this one ends, however it ends
    (module notes); call it before starting any. Windows: this process put in a new job object
    with JOB_OBJECT_LIMIT_KILL_ON_JOB_CLOSE (a job inside the job Blender may run in: Windows 8 and
    later nest them); returns the job's handle, which nothing closes: Windows closes it as this
    process ends. OSError when Windows refuses. `kernel32`: the Windows API (default
    ctypes.WinDLL's). POSIX: nothing to do (None): the parent kills the group (end_leftovers)."""
    if windows(platform):
        api = ctypes.WinDLL("kernel32", use_last_error=True) if kernel32 is None else kernel32
        api.CreateJobObjectW.restype = api.GetCurrentProcess.restype = ctypes.c_void_p
        job = api.CreateJobObjectW(None, None)
        if not job:
            raise _windows_error("CreateJobObjectW")
        limits = JobLimits()
        limits.BasicLimitInformation.LimitFlags = JOB_OBJECT_LIMIT_KILL_ON_JOB_CLOSE
        if not api.SetInformationJobObject(ctypes.c_void_p(job), JOB_OBJECT_EXTENDED_LIMIT_INFORMATION_CLASS,
                                           ctypes.byref(limits), ctypes.sizeof(limits)):
            raise _windows_error("SetInformationJobObject")
        if not api.AssignProcessToJobObject(ctypes.c_void_p(job), ctypes.c_void_p(api.GetCurrentProcess())):
            raise _windows_error("AssignProcessToJobObject")
        return job
    return None


def end_leftovers(pid: int, *, platform: str | None = None) -> None:
    """End what is left of the tree of the child `pid` (started with child_options) once it has
    exited, however (module notes). POSIX: SIGKILL to its process group; call it before reaping
    the child, while its pid still names the group. Windows: nothing is left to end: the child's
    job object (end_with_self) ended its workers as Windows closed the child's handles, and
    taskkill /T cannot reach them from a root that has gone."""
    if windows(platform):
        return
    kill_tree(pid, platform=platform)


def _windows_error(call: str) -> OSError:
    """The OSError of a failed Windows API call (its last error code)."""
    code = ctypes.get_last_error() if hasattr(ctypes, "get_last_error") else 0
    return OSError(code, f"{call} failed (Windows error {code})")


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
