"""Where the simplify phase's tasks run: in this process (jobs = 1), in a pool of spawned worker
processes, or on a Dask cluster's workers (dask_cluster.py), behind one interface, `Workers`.

Workers read the exact measure's shared arrays (tasks.py) from a scratch folder of the bake
(`$TMPDIR/hlod-bake-*`, or one inside the cluster's shared scratch folder), removed when the
bake ends; inline they are this process's own arrays. Starting workers happens inside
core.signals.stop_signals_held: a signal's exception raised half-way through a process start
would leave the new worker reading half of its start-up data.
"""
from __future__ import annotations

import concurrent.futures as cf
import contextlib
import multiprocessing
import os
import signal
import sys
import tempfile
from dataclasses import dataclass

import numpy as np

from ...core.signals import stop_signals_held
from . import tasks

#: A memory-backed file system that processes of this machine share (Linux's tmpfs): writing through a
#: map costs about a third of writing a file of the disk-backed temporary folder (0.2 to 0.3 s
#: against 0.7 s for 240 MB on the Xeon).
SHARED_MEMORY = "/dev/shm"
#: How long a stopped pool waits for each killed worker to be gone (seconds; a kill takes milliseconds).
STOP_JOIN_SECONDS = 5.0


def init_worker() -> None:
    """A worker process's initializer. Ctrl-C in a terminal (and a hangup) reaches the whole
    process group: the parent cancels and shuts the pool down, so the workers ignore these and
    print no tracebacks of their own."""
    for name in ("SIGINT", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_IGN)


def warm_up() -> None:
    """A worker's first task, submitted when the pool starts: pymeshlab's import (about half a
    second) then overlaps the bake's prepare, octree and cache phases."""
    import pymeshlab  # noqa: F401 - imported for its import time only (the warm-up)


class InlineExecutor:
    """The Executor interface, running each task at submit time (jobs = 1)."""

    def submit(self, fn, *args, **kwargs) -> cf.Future:
        fut: cf.Future = cf.Future()
        fut.set_result(fn(*args, **kwargs))
        return fut


@dataclass
class Workers:
    """Where the simplify phase's tasks run: executor (submit(fn, *args, **kwargs) -> Future), at
    most `limit` in flight, and `scratch`, a folder every worker reads the shared arrays from (""
    inline: this process's own arrays). prioritised: the executor takes submit(..., priority=int)
    (a Dask cluster, whose scheduler orders the tasks it queues). memory: a folder in shared memory
    (SHARED_MEMORY) that every worker maps too ("" where there is none: a cluster's workers on
    other machines), where the early phases' chunk stores go (bake/space/chunk_store.py)."""

    executor: object
    limit: int
    scratch: str
    prioritised: bool = False
    memory: str = ""

    def submit(self, order: tuple[int, int], fn, *args, **kwargs) -> cf.Future:
        """fn(*args, **kwargs) as a task; order: the scheduling loop's heap key (kind, size),
        smallest first, given to a prioritised executor as its priority (largest first):
        decimations before measurements, then -size (negative depths and triangle counts, below 2**40)."""
        if not self.prioritised:
            return self.executor.submit(fn, *args, **kwargs)
        kind, size = order
        return self.executor.submit(fn, *args, priority=-(kind << 40) - size, **kwargs)

    def share(self, arrays: dict[str, np.ndarray]) -> None:
        """Make `arrays` (tasks.SHARED_ARRAYS) readable by every worker, before any task reads them."""
        if self.scratch:
            tasks.save_shared(self.scratch, arrays)
        else:
            tasks.share_inline(arrays)


@contextlib.contextmanager
def open_workers(jobs: int, *, scheduler=None, scratch_dir: str | os.PathLike | None = None):
    """Workers for `jobs`: inline for 1; else a pool of `jobs` spawned worker processes, started at
    once (each imports pymeshlab while the bake prepares: `warm_up`), and a scratch folder
    (`$TMPDIR/hlod-bake-*`). With a scheduler (an address or a distributed.Client), the Dask
    cluster's workers instead, and a scratch folder inside `scratch_dir` (dask_cluster.on_cluster).
    All are gone when the block exits, however it exits."""
    with stop_signals_held():
        if scheduler is not None:
            from . import dask_cluster  # only here: Dask is a command-line-only dependency

            with dask_cluster.on_cluster(scheduler, scratch_dir=scratch_dir, release=tasks.release_shared) as cluster:
                yield Workers(cluster.executor, cluster.limit, cluster.scratch, prioritised=True)
            return
        if jobs == 1:
            try:
                yield Workers(InlineExecutor(), 1, "")
            finally:
                tasks.release_shared("")
            return
        with contextlib.ExitStack() as stack:
            scratch = stack.enter_context(tempfile.TemporaryDirectory(prefix="hlod-bake-"))
            stack.enter_context(_main_module_importable())
            executor = cf.ProcessPoolExecutor(max_workers=jobs, initializer=init_worker,
                                              mp_context=multiprocessing.get_context("spawn"))
            stack.callback(executor.shutdown, wait=True, cancel_futures=True)
            for _ in range(jobs):
                executor.submit(warm_up)
            try:
                yield Workers(executor, jobs, scratch, memory=SHARED_MEMORY if os.path.isdir(SHARED_MEMORY) else "")
            except BaseException:
                stop_pool(executor)
                raise


def stop_pool(executor: cf.ProcessPoolExecutor) -> None:
    """A pool the bake leaves by an exception (a cancel, a stop signal, a failed task): its
    workers killed, and the pool's result pipe closed on this side, so that its shutdown cannot
    hang. A worker killed while it wrote a result (a cancel stops the whole process group) leaves
    half a message in that pipe; the executor's manager thread then waits for the rest forever,
    since this process holds the pipe's write end too, and `shutdown(wait=True)` with it. Closing
    that end gives the reader end of file: the pool counts as broken and shuts down. Reaches into
    the executor's `_processes` and `_result_queue` (CPython 3.11 to 3.13)."""
    processes = list((getattr(executor, "_processes", None) or {}).values())
    for process in processes:
        with contextlib.suppress(OSError, ValueError):
            process.kill()
    for process in processes:
        with contextlib.suppress(OSError, ValueError, AssertionError):
            process.join(STOP_JOIN_SECONDS)
    writer = getattr(getattr(executor, "_result_queue", None), "_writer", None)
    if writer is not None:
        with contextlib.suppress(OSError):
            writer.close()


@contextlib.contextmanager
def _main_module_importable():
    """Spawned workers re-import the parent's __main__ from its __file__. When that is no file
    (python reading stdin, an embedding host), hide it while the pool starts its workers: the
    workers only need hlod_core, which they import by name."""
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    hide = main is not None and getattr(main, "__spec__", None) is None and path is not None \
        and not os.path.isfile(path)
    if hide:
        del main.__file__
    try:
        yield
    finally:
        if hide:
            main.__file__ = path
