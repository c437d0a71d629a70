"""The bake's simplify phase on a Dask cluster: its tasks (decimations, deepest first;
measurements, largest first; schedule.py) run as Dask tasks on a `distributed` scheduler's
workers instead of local worker processes (workers.open_workers), and the output is the file a
local bake writes, byte for byte.

What moves where:
- a task is a module-level function of hlod_core and its arguments (numpy arrays and small tuples:
  the children's LODs of a decimation, the node's LOD of a measurement), sent with the task as they
  are to local workers; its result (a simplify.NodeLod, or an error float) comes back to the bake's
  process, which keeps every LOD (it assembles the file);
- the exact measure's shared arrays (the leaves' triangles) are written once per bake as .npy files
  into a fresh folder `hlod-bake-*` inside the scratch folder, which every worker must read (shared
  storage on a cluster); workers memory-map them on first use (tasks.shared) and drop them when the
  bake ends, and the folder is removed however the bake ends.

`DaskExecutor` adapts a `distributed.Client` to what the scheduling loop expects of an executor:
`submit(fn, *args, priority=)` returns a concurrent.futures.Future; the loop keeps at most
TASKS_PER_THREAD x the cluster's threads in flight (its `limit`: one running and one waiting per
thread) and passes its own order as the Dask priority, so the tasks the scheduler and the workers
queue (the waiting ones; a lost worker's, retried) run in the loop's order. Tasks are
deterministic, so a task retried on another worker returns the same result. Measured costs (one
Dask task costs about 7 ms of CPU here beside its 30-45 ms of work) are in
docs/performance.md#baking-on-a-dask-cluster.

Before a bake uses a cluster, `check_cluster` asks every worker for the versions and sources that
decide LODs and errors (cache_keys.context_digest) and reads a probe file in the scratch folder:
a worker with other code or without the shared folder is refused before anything is baked.

Command line only: Dask (`dask[distributed]`) is an optional dependency of `python -m hlod_core`;
the Blender extension never imports this module (workers.py imports it only when given a scheduler).
"""
from __future__ import annotations

import concurrent.futures as cf
import contextlib
import logging
import os
import re
import secrets
import shutil
import sys
import tempfile
import threading
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ...core.errors import InputError

log = logging.getLogger(__name__)

#: Tasks in flight per worker thread: one running and one waiting on its worker, its arguments
#: already there, so that a thread does not idle through the round trip (its result to the bake,
#: the next task to the worker: about 10 ms here) between two tasks.
TASKS_PER_THREAD = 2
#: Seconds to wait for a scheduler to answer (and for its first worker) unless told otherwise.
CONNECT_TIMEOUT_S = 10.0
#: A scheduler address: distributed's TCP transport, "tcp://host:port" (TLS would need Dask's
#: security settings, which the bake does not pass: not taken).
_ADDRESS = re.compile(r"^(?:tcp://)?(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})$")
_PROBE = "probe"
_INSTALL_HINT = ("it needs the dask[distributed] package "
                 "(pip install -r requirements.txt: a command-line-only dependency)")


class ClusterError(InputError):
    """The scheduler or the scratch folder cannot be used. about: "scheduler" or "scratch" (what is
    at fault: the command line names its option, --scheduler or --scratch), value: the address or
    folder as given, reason: what is wrong."""

    def __init__(self, about: str, value, reason: str):
        super().__init__(f"{about} {value}: {reason}")
        self.about, self.value, self.reason = about, str(value), reason


def check_address(address: str) -> str:
    """`address` as distributed takes it, "tcp://host:port" ("host:port" means tcp); ClusterError otherwise."""
    match = _ADDRESS.match(address.strip())
    if match is None or not 0 < int(match.group(2)) < 65536:
        raise ClusterError("scheduler", address, "not a scheduler address; expected tcp://HOST:PORT "
                                                 "(e.g. tcp://node1:8786)")
    return f"tcp://{match.group(1)}:{int(match.group(2))}"


def check_scratch(folder: str | os.PathLike) -> str:
    """The scratch folder as an absolute path; ClusterError unless it is an existing folder this
    process can create files in (the bake writes a subfolder there)."""
    path = os.path.abspath(os.fspath(folder))
    if not os.path.isdir(path):
        raise ClusterError("scratch", folder, f"{'not a folder' if os.path.exists(path) else 'no such folder'}; "
                                              "it must be an existing folder on storage every worker can read")
    try:
        with tempfile.NamedTemporaryFile(dir=path, prefix=".hlod-write-check-"):
            pass
    except OSError as exc:
        raise ClusterError("scratch", folder, f"cannot write there ({exc.strerror or exc})") from None
    return path


def _distributed(address: str):
    """The distributed package, or ClusterError saying how to get it."""
    try:
        import distributed
    except ImportError:
        raise ClusterError("scheduler", address, f"Dask is not installed; {_INSTALL_HINT}") from None
    return distributed


def connect(address: str, *, timeout_s: float = CONNECT_TIMEOUT_S):
    """A distributed.Client of the scheduler at `address` with at least one worker; ClusterError if
    no scheduler answers, or no worker joins, within `timeout_s`."""
    distributed = _distributed(address)
    checked = check_address(address)
    try:
        client = distributed.Client(checked, timeout=timeout_s, set_as_default=False)
    except (OSError, TimeoutError):
        raise ClusterError("scheduler", address, f"no Dask scheduler answered within {timeout_s:g} s") from None
    try:
        client.wait_for_workers(1, timeout=timeout_s)
    except (OSError, TimeoutError):
        client.close()
        raise ClusterError("scheduler", address, f"the scheduler has no workers (none joined within {timeout_s:g} s)") \
            from None
    except BaseException:
        client.close()
        raise
    return client


def fingerprint() -> str:
    """What decides a task's result besides its arguments: the Python version and, through
    cache_keys.context_digest, the sources of the modules that compute LODs and errors and the
    pymeshlab and numpy versions. Runs on each worker (check_cluster) and here."""
    from ..decimate import simplify
    from . import cache_keys

    digest = cache_keys.context_digest(simplify.DecimationSettings(), with_normals=False, row_layout=None)
    return f"python {sys.version_info[0]}.{sys.version_info[1]} {digest.hex()}"


def read_probe(path: str) -> str:
    """Runs on each worker: the probe file's text, or why it cannot be read."""
    try:
        with open(path, encoding="ascii") as f:
            return f.read()
    except OSError as exc:
        return f"cannot read {path}: {exc.strerror or exc}"


def check_cluster(client, scratch: str) -> int:
    """The cluster's total worker threads (the bake's task limit), after checking that every worker
    runs this machine's code and versions (fingerprint) and reads a probe file written into
    `scratch` (a folder of the bake's; the probe is removed). ClusterError naming the worker otherwise."""
    address = client.scheduler.address
    try:
        theirs = client.run(fingerprint)
    except Exception as exc:  # noqa: BLE001 - what a worker raised, e.g. it cannot import hlod_core
        raise ClusterError("scheduler", address, f"a worker cannot run the bake's code ({type(exc).__name__}: {exc}); "
                                                 "every worker needs this hlod_core on its PYTHONPATH, with the "
                                                 "pinned requirements") from None
    ours = fingerprint()
    for worker, print_ in sorted(theirs.items()):
        if print_ != ours:
            raise ClusterError("scheduler", address, f"worker {worker} runs other code or versions ({print_}; here "
                                                     f"{ours}); every worker needs the same hlod_core, pymeshlab and "
                                                     "numpy, or its LODs would differ")
    token = secrets.token_hex(16)
    probe = os.path.join(scratch, _PROBE)
    with open(probe, "w", encoding="ascii") as f:
        f.write(token)
    try:
        read = client.run(read_probe, probe)
    finally:
        os.unlink(probe)
    for worker, text in sorted(read.items()):
        if text != token:
            seen = text if text.startswith("cannot") else "it reads another file there"
            raise ClusterError("scratch", os.path.dirname(scratch),
                               f"Dask worker {worker} does not see it ({seen}); it must be storage every worker shares")
    return max(1, sum(client.nthreads().values()))


def array_bytes(value) -> int:
    """Bytes of the numpy arrays in `value` (arrays, tuples, lists and dicts of them, dataclasses of
    them)."""
    if isinstance(value, np.ndarray):
        return value.nbytes
    if isinstance(value, (tuple, list)):
        return sum(array_bytes(v) for v in value)
    if isinstance(value, dict):
        return sum(array_bytes(v) for v in value.values())
    fields = getattr(value, "__dataclass_fields__", None)
    if fields:
        return sum(array_bytes(getattr(value, name)) for name in fields)
    return 0


@dataclass
class TaskStats:
    """What went through the adapter: tasks submitted, and the numpy bytes sent with them and
    returned (the data movement of one bake; pickling adds a little)."""

    tasks: int = 0
    sent_bytes: int = 0
    returned_bytes: int = 0


class DaskExecutor:
    """concurrent.futures-style submit over a distributed.Client (module docstring). The Dask
    futures are held until their result is fetched, then released (the workers free them);
    `cancel_all` cancels every one still held."""

    def __init__(self, client):
        self.client = client
        self.stats = TaskStats()
        self._held: dict[str, object] = {}  # Dask key -> Future, until its result is here
        self._lock = threading.Lock()

    def submit(self, fn: Callable, *args, priority: int = 0, **kwargs) -> cf.Future:
        """fn(*args, **kwargs) as a Dask task of `priority` (higher first); the Future of its result."""
        local: cf.Future = cf.Future()
        local.set_running_or_notify_cancel()
        remote = self.client.submit(fn, *args, pure=False, priority=priority, **kwargs)
        with self._lock:
            self._held[remote.key] = remote
            self.stats.tasks += 1
            self.stats.sent_bytes += array_bytes((args, kwargs))
        remote.add_done_callback(lambda done: self._finish(done, local))
        return local

    def _finish(self, remote, local: cf.Future) -> None:
        """Runs on distributed's callback thread when `remote` is finished, failed or cancelled."""
        try:
            result = remote.result()
        except BaseException as exc:  # noqa: BLE001 - the task's own exception, or CancelledError
            local.set_exception(exc)
        else:
            with self._lock:
                self.stats.returned_bytes += array_bytes(result)
            local.set_result(result)
        finally:
            with self._lock:
                self._held.pop(remote.key, None)

    def cancel_all(self) -> None:
        with self._lock:
            held = list(self._held.values())
            self._held.clear()
        if held:
            self.client.cancel(held, force=True)


@dataclass
class Cluster:
    """A bake's use of a cluster: executor, limit (tasks in flight: TASKS_PER_THREAD x the workers'
    threads) and scratch, the bake's own folder inside the shared scratch folder."""

    executor: DaskExecutor
    limit: int
    scratch: str


@contextlib.contextmanager
def on_cluster(scheduler, *, scratch_dir: str | os.PathLike | None,
               release: Callable[[str], None] | None = None, timeout_s: float = CONNECT_TIMEOUT_S):
    """A Cluster for one bake. scheduler: an address (connected here, closed at the end) or a
    distributed.Client (left open); scratch_dir: the shared folder (None: the temporary folder,
    enough for workers on this machine). On exit, however the block exits: the tasks still held are
    cancelled, `release(scratch)` runs on every worker (they drop their memory maps; best effort)
    and the bake's scratch folder is removed."""
    scratch_root = check_scratch(tempfile.gettempdir() if scratch_dir is None else scratch_dir)
    with contextlib.ExitStack() as stack:
        if isinstance(scheduler, str):
            client = connect(scheduler, timeout_s=timeout_s)
            stack.callback(client.close)
        else:
            client = scheduler
        scratch = tempfile.mkdtemp(prefix="hlod-bake-", dir=scratch_root)
        stack.callback(shutil.rmtree, scratch, ignore_errors=True)
        if release is not None:
            stack.callback(_release_on_workers, client, release, scratch)
        threads = check_cluster(client, scratch)
        limit = TASKS_PER_THREAD * threads
        executor = DaskExecutor(client)
        stack.callback(_report, executor, threads)
        stack.callback(executor.cancel_all)
        yield Cluster(executor=executor, limit=limit, scratch=scratch)


def _release_on_workers(client, release: Callable[[str], None], scratch: str) -> None:
    try:
        client.run(release, scratch, wait=True, on_error="ignore")
    except Exception as exc:  # noqa: BLE001 - a worker gone or the scheduler lost: its maps go with it
        log.debug("releasing the shared arrays on the workers: %s", exc)


def _report(executor: DaskExecutor, threads: int) -> None:
    s = executor.stats
    log.info("dask: %d tasks on %d worker threads; %.1f MB of arrays sent with them, %.1f MB returned", s.tasks,
             threads, s.sent_bytes / 1e6, s.returned_bytes / 1e6)
