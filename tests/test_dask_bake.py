"""Bakes on a Dask cluster (hlod_core/bake/run/dask_cluster.py): a real distributed.LocalCluster of
two worker processes on this machine (localhost only, no dashboard) bakes the file a local bake
writes, byte for byte, with the exact and the bound error; a worker killed in the middle of a bake
has its tasks retried and the file is still the same; the command line's --scheduler and --scratch,
their faults (one line, exit 2, nothing written) and a SIGTERM mid-bake (the scratch subfolder
removed). The adapter's checks and the workers' shared-array cache are tested on literal input."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading

import distributed  # requirements.txt installs it (command line only): its absence is a failure, not a skip
import numpy as np
import pytest

import sample_meshes
from helpers import ROOT, file_bytes, load_model, model
from hlod_core.bake.pipeline import bake, bake_stream
from hlod_core.bake.run import dask_cluster, tasks
from hlod_core.bake.settings import BakeSettings
from hlod_core.bake.space.partition import MeshSource
from hlod_core.core.errors import BakeCancelled
from hlod_core.io import hlod_file
from processes import group_is_gone, hlod, last_json, one_line_error, wait_for
from sample_meshes import HERD_SPACING

HERD_TRIS = 600  # nine cows at 600 triangles a node: 321 nodes, 4 levels, about 2 s a bake here
#: Clusters listen on localhost only, on free ports; distributed's HTTP server (its health and metrics
#: routes: there is no dashboard without bokeh, which is not installed) too, not on the usual 8787,
#: which another cluster on this machine may hold.
LOCALHOST = {"host": "127.0.0.1", "dashboard_address": "127.0.0.1:0"}


@pytest.fixture(scope="module")
def cluster():
    """Two worker processes of one thread each, as `dask worker --nworkers 2 --nthreads 1` starts them."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, **LOCALHOST) as local, \
            distributed.Client(local, set_as_default=False) as client:
        yield client


@pytest.fixture(scope="module")
def herd():
    """sample_meshes.herd's nine cows, none moved."""
    return sample_meshes.herd()[0]


def _both_workers(client) -> dict[str, int]:
    client.wait_for_workers(2, timeout=60)
    return client.run(os.getpid)


# the bound measure on a cluster is slow: the quick set has the bound's own checks (test_error_bound)
# and this cluster path with the exact measure
@pytest.mark.parametrize("error", ["exact", pytest.param("bound", marks=pytest.mark.slow)])
def test_a_cluster_bake_writes_the_file_a_local_bake_writes(cluster, herd, error, tmp_path):
    settings = BakeSettings(target_tris=HERD_TRIS, error=error)
    local = bake(herd, settings)
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    remote = bake(herd, settings, scheduler=cluster, scratch_dir=scratch)
    assert int((~local.is_leaf).sum()) > 50 and int(local.depth.max()) >= 3
    assert file_bytes(remote, tmp_path / "remote.hlod") == file_bytes(local, tmp_path / "local.hlod")
    assert list(scratch.iterdir()) == []  # the bake's subfolder is gone


def test_the_cell_seams_as_tasks_on_the_cluster_are_the_serial_seams_and_file(cluster, monkeypatch, tmp_path):
    """The cow at 500 triangles a node: its cell seams found in buckets of 500 leaf vertices as tasks
    on the cluster's workers (cell_seams.build runs them from PARALLEL_FROM_VERTICES on: the test's
    scenes are smaller), which read the leaves' positions from the bake's scratch subfolder, are
    the seams found inline in one bucket, array for array; and a cluster bake that finds them so
    writes the serial bake's file."""
    from hlod_core.bake import prepare
    from hlod_core.bake.decimate import cell_seams
    from hlod_core.bake.run.workers import open_workers
    from hlod_core.bake.space.octree import build_octree

    cow, settings = load_model("cow"), BakeSettings(target_tris=500)
    prepared = prepare.prepare(cow)
    layout = build_octree(prepared.centroids, target_tris=500, max_depth=12, counted=prepared.counted,
                          root=prepared.root_cell)
    lods = prepare.leaf_lods(layout, prepared)
    inline = cell_seams.build(layout, lods)
    serial = file_bytes(bake(cow, settings), tmp_path / "serial.hlod")
    monkeypatch.setattr(cell_seams, "BUCKET_VERTICES", 500)
    monkeypatch.setattr(cell_seams, "PARALLEL_FROM_VERTICES", 0)
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    with open_workers(1, scheduler=cluster, scratch_dir=scratch) as workers:
        remote = cell_seams.build(layout, lods, workers=workers)
    assert inline.positions.shape[0] > 500
    for name in ("positions", "first_leaf", "last_leaf", "pair_leaf", "pair_position", "pair_start"):
        assert np.array_equal(getattr(remote, name), getattr(inline, name)), name
    assert file_bytes(bake(cow, settings, scheduler=cluster, scratch_dir=scratch), tmp_path / "dask.hlod") == serial
    assert list(scratch.iterdir()) == []


@pytest.mark.slow  # robustness beside the cluster bake's path (above), a bake and a worker restart
def test_prepare_octree_and_leaves_as_chunk_tasks_on_the_cluster_write_the_serial_file(cluster, monkeypatch,
                                                                                          tmp_path):
    """The cow at 500 triangles a node, its prepare, octree and leaves as tasks over regions of 700
    triangles (bake/space/chunk_store.py) on the cluster's workers, through mapped files in the
    bake's scratch subfolder: the file of a bake in this process, and the scratch folder empty after."""
    from hlod_core.bake.space import chunk_store

    cow, settings = load_model("cow"), BakeSettings(target_tris=500)
    serial = file_bytes(bake(cow, settings), tmp_path / "serial.hlod")
    monkeypatch.setattr(chunk_store, "TASK_ROWS", 700)
    monkeypatch.setattr(chunk_store, "WORKERS_FROM_ROWS", 0)
    where, run = [], chunk_store.ChunkStore.run

    def spied(store, fn, calls):
        where.append((store.folder, fn.__name__))
        return run(store, fn, calls)

    monkeypatch.setattr(chunk_store.ChunkStore, "run", spied)
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    assert file_bytes(bake(cow, settings, scheduler=cluster, scratch_dir=scratch), tmp_path / "dask.hlod") == serial
    assert {name for _, name in where} >= {"centroid_task", "octant_task", "advance_task", "leaf_task"}
    assert all(folder.startswith(str(scratch)) for folder, _ in where)
    assert list(scratch.iterdir()) == []


def test_a_worker_killed_mid_bake_has_its_tasks_retried(cluster, herd, tmp_path):
    """SIGKILL of a worker process that is running a task, a third of the way through the inner
    nodes: the scheduler gives its tasks to the other worker (and to the one its nanny restarts),
    and the file is the same."""
    settings = BakeSettings(target_tris=HERD_TRIS)
    local = bake(herd, settings)
    pids = _both_workers(cluster)
    inner = int((~local.is_leaf).sum())
    killed: dict[str, object] = {}

    def progress(done: int, total: int, phase: str) -> None:
        if phase != "simplify" or killed or done < total - inner + inner // 3:
            return
        busy = {w: keys for w, keys in cluster.processing().items() if keys}
        if busy:
            worker = sorted(busy)[0]
            killed.update(worker=worker, keys=list(busy[worker]))
            os.kill(pids[worker], signal.SIGKILL)

    remote = bake(herd, settings, progress=progress, scheduler=cluster, scratch_dir=tmp_path)
    assert killed, "no worker was busy to kill"
    assert file_bytes(remote, tmp_path / "remote.hlod") == file_bytes(local, tmp_path / "local.hlod")
    assert pids[killed["worker"]] not in _both_workers(cluster).values()  # it died; the nanny started another


def test_a_cancelled_bake_leaves_no_task_and_no_scratch(cluster, herd, tmp_path):
    _both_workers(cluster)
    calls = 0

    def cancel() -> bool:
        nonlocal calls
        calls += 1
        return calls > 8

    with pytest.raises(BakeCancelled):
        bake(herd, BakeSettings(target_tris=HERD_TRIS), cancel=cancel, scheduler=cluster, scratch_dir=tmp_path)
    assert list(tmp_path.iterdir()) == []
    wait_for(lambda: not cluster.who_has(), 30, "the cancelled tasks' results to be released")


def test_the_command_line_bakes_on_a_cluster(cluster, tmp_path):
    """--scheduler ADDRESS --scratch DIR: the file of a local bake of the same spec (nine cows)."""
    spec = tmp_path / "herd.json"
    translations = [[1, 0, 0, HERD_SPACING * (k % 3), 0, 1, 0, HERD_SPACING * (k // 3), 0, 0, 1, 0, 0, 0, 0, 1]
                    for k in range(9)]
    spec.write_text(json.dumps({"models": [{"path": str(model("cow")), "transforms": translations}]}))
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    common = ("-q", "bake", spec, "--target-tris", HERD_TRIS, "--no-cache")
    hlod(*common, "-o", tmp_path / "local.hlod")
    proc = hlod(*common, "-o", tmp_path / "remote.hlod", "--scheduler", cluster.scheduler.address, "--scratch", scratch)
    summary = last_json(proc)
    assert summary["scheduler"] == {"address": cluster.scheduler.address, "worker_threads": 2}
    assert proc.stderr == ""  # -q: distributed's own log lines are kept off stderr too
    files = [hlod_file.load(tmp_path / f"{name}.hlod") for name in ("local", "remote")]
    assert file_bytes(files[1], tmp_path / "b.hlod") == file_bytes(files[0], tmp_path / "a.hlod")
    assert list(scratch.iterdir()) == []


def test_sigterm_mid_bake_cancels_and_removes_the_scratch_subfolder(cluster, tmp_path):
    """As a local bake (test_cli_hostile): exit 143 with one line, no output, and here the bake's
    folder in --scratch removed; the cluster goes on working."""
    scratch, out, log = tmp_path / "scratch", tmp_path / "statue.hlod", tmp_path / "stderr.txt"
    scratch.mkdir()
    with open(log, "w") as stderr:
        proc = subprocess.Popen([sys.executable, "-m", "hlod_core", "bake", str(model("statue")), "-o", str(out),
                                 "--no-cache", "--scheduler", cluster.scheduler.address, "--scratch", str(scratch)],
                                cwd=ROOT, stdout=subprocess.DEVNULL, stderr=stderr, start_new_session=True,
                                env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        wait_for(lambda: "bake simplify" in log.read_text(), 120, "a progress line")
        wait_for(lambda: any(p.name.startswith("hlod-bake-") for p in scratch.iterdir()), 60, "the scratch folder")
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=120) == 128 + signal.SIGTERM, log.read_text()[-2000:]
    finally:
        if not group_is_gone(proc.pid):
            os.killpg(proc.pid, signal.SIGKILL)
    text = log.read_text()
    assert text.strip().splitlines()[-1] == "hlod_core: terminated by SIGTERM" and "Traceback" not in text, text
    assert list(scratch.iterdir()) == [] and not out.exists()
    wait_for(lambda: not cluster.who_has(), 30, "the cancelled tasks' results to be released")
    assert cluster.submit(sum, [1, 2], pure=False).result(timeout=30) == 3


# --- faults: one line naming the option, exit 2, nothing written ----------------------------------

@pytest.fixture(scope="module")
def empty_scheduler():
    """A scheduler without workers."""
    with distributed.LocalCluster(n_workers=0, **LOCALHOST) as local:
        yield local.scheduler_address


def _refused(tmp_path, *args, prelude: str = "") -> str:
    """Run a bake of the cow with `args` (prelude: Python run first, in the same process); returns
    its one error line after checking exit 2 and that nothing was written next to the output."""
    before = sorted(p.name for p in tmp_path.iterdir())
    code = f"{prelude}\nimport sys\nfrom hlod_core.cli.main import main\nsys.exit(main(sys.argv[1:]))"
    proc = subprocess.run([sys.executable, "-c", code, "bake", str(model("cow")), "-o", str(tmp_path / "x.hlod"),
                           *map(str, args)], cwd=ROOT, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 2 and proc.stdout == "", proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    return one_line_error(proc)


def test_faults_of_the_scheduler_and_scratch_options(cluster, empty_scheduler, tmp_path):
    sub = tmp_path / "sub"
    sub.mkdir()
    file = tmp_path / "file"
    file.write_text("")
    address = cluster.scheduler.address
    cases = [
        (["--scheduler", "node1"], "--scheduler node1: not a scheduler address; expected tcp://HOST:PORT"),
        (["--scheduler", "http://node1:8786"], "--scheduler http://node1:8786: not a scheduler address"),
        (["--scheduler", "tcp://node1:99999"], "--scheduler tcp://node1:99999: not a scheduler address"),
        (["--scheduler", "tcp://127.0.0.1:9", "--scheduler-timeout", "0.5"],
         "--scheduler tcp://127.0.0.1:9: no Dask scheduler answered within 0.5 s"),
        # the timeout covers connecting too: long enough for a loaded machine to connect in, so
        # the case fails for want of workers, not of time
        (["--scheduler", empty_scheduler, "--scheduler-timeout", "2"],
         f"--scheduler {empty_scheduler}: the scheduler has no workers (none joined within 2 s)"),
        (["--scheduler", address, "--scratch", sub / "missing"],
         f"--scratch {sub / 'missing'}: no such folder; it must be an existing folder"),
        (["--scheduler", address, "--scratch", file], f"--scratch {file}: not a folder"),
        (["--scratch", sub], "--scratch: only with --scheduler"),
        (["--scheduler-timeout", "3"], "--scheduler-timeout: only with --scheduler"),
        (["--scheduler", address, "--scheduler-timeout", "-1"],
         "argument --scheduler-timeout: expected a number of seconds > 0, got -1"),
    ]
    if os.geteuid() == 0:  # root writes into any folder it may enter: sysfs refuses new files even to root
        cases.append((["--scheduler", address, "--scratch", "/sys"], "--scratch /sys: cannot write there"))
    else:
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o555)
        cases.append((["--scheduler", address, "--scratch", locked], f"--scratch {locked}: cannot write there"))
    for args, expect in cases:
        line = _refused(sub, *args)
        assert line.startswith("hlod_core: error: ") and expect in line, (args, line)
    assert list(sub.iterdir()) == []


def test_without_dask_the_option_says_what_to_install(tmp_path):
    line = _refused(tmp_path, "--scheduler", "tcp://127.0.0.1:8786",
                    prelude="import sys; sys.modules['distributed'] = None")
    assert line == ("hlod_core: error: --scheduler tcp://127.0.0.1:8786: Dask is not installed; it needs the "
                    "dask[distributed] package (pip install -r requirements.txt: a command-line-only dependency)")


class _FakeClient:
    """What check_cluster asks of a distributed.Client, answering as given per function name."""

    def __init__(self, answers: dict):
        self.answers = answers
        self.scheduler = type("Scheduler", (), {"address": "tcp://fake:8786"})()

    def run(self, function, *args):
        answer = self.answers[function.__name__]
        return answer(*args) if callable(answer) else answer

    def nthreads(self):
        return {"tcp://w1:1": 3, "tcp://w2:1": 1}


def test_check_cluster_refuses_other_code_and_an_unshared_scratch_folder(tmp_path):
    ours = dask_cluster.fingerprint()

    def reads(path):
        return {"tcp://w1:1": dask_cluster.read_probe(path), "tcp://w2:1": dask_cluster.read_probe(path)}

    good = {"fingerprint": {"tcp://w1:1": ours, "tcp://w2:1": ours}, "read_probe": reads}
    assert dask_cluster.check_cluster(_FakeClient(good), str(tmp_path)) == 4  # the threads: the task limit
    assert list(tmp_path.iterdir()) == []  # the probe is removed
    other = {**good, "fingerprint": {"tcp://w1:1": ours, "tcp://w2:1": "python 3.11 0123"}}
    with pytest.raises(dask_cluster.ClusterError, match="worker tcp://w2:1 runs other code or versions") as info:
        dask_cluster.check_cluster(_FakeClient(other), str(tmp_path))
    assert info.value.about == "scheduler"
    elsewhere = {**good, "read_probe": {"tcp://w1:1": "cannot read /x/probe: No such file or directory"}}
    (tmp_path / "bake").mkdir()
    with pytest.raises(dask_cluster.ClusterError, match="Dask worker tcp://w1:1 does not see it") as info:
        dask_cluster.check_cluster(_FakeClient(elsewhere), str(tmp_path / "bake"))
    assert info.value.about == "scratch" and info.value.value == str(tmp_path)


def test_the_workers_shared_arrays_follow_the_folder_and_are_thread_safe(tmp_path):
    """A Dask worker outlives bakes: a folder made again under the same name (other files) is
    loaded anew, and threads loading one folder at once all get the same arrays."""
    names = tasks.SHARED_ARRAYS

    def write(value: int) -> None:
        for name in names:
            np.save(tmp_path / f"{name}.npy", np.full(3, value, np.int64))

    write(1)
    try:
        assert int(tasks.shared(str(tmp_path))["positions"][0]) == 1
        before = (tmp_path / f"{names[0]}.npy").stat().st_mtime_ns
        for name in names:
            (tmp_path / f"{name}.npy").unlink()
        write(2)  # the same size, maybe the same inode: written a second later, as a later bake would be
        os.utime(tmp_path / f"{names[0]}.npy", ns=(before + 10**9, before + 10**9))
        assert int(tasks.shared(str(tmp_path))["positions"][0]) == 2
        tasks.release_shared(str(tmp_path))
        got, start = [], threading.Barrier(8)

        def load():
            start.wait()
            got.append(tasks.shared(str(tmp_path)))

        threads = [threading.Thread(target=load) for _ in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert len(got) == 8 and all(g is got[0] for g in got)
    finally:
        tasks.release_shared(str(tmp_path))


@pytest.mark.slow  # out of core and on a cluster each have their quick checks: together, two more bakes
def test_an_out_of_core_bake_on_a_cluster_writes_the_local_file(cluster, herd, tmp_path):
    """--out-of-core with --scheduler: the partition's cell files and memory-mapped leaves in the
    scratch folder, the simplify phase on the cluster's workers; the file of a local bake."""
    settings = BakeSettings(target_tris=HERD_TRIS)
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    remote = bake_stream(MeshSource(herd), settings, scheduler=cluster, scratch_dir=scratch, chunk_tris=5000)
    assert file_bytes(remote, tmp_path / "remote.hlod") == file_bytes(bake(herd, settings), tmp_path / "local.hlod")
    assert list(scratch.iterdir()) == []
