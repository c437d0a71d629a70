"""Hostile input to the command line: signals mid-bake leave nothing behind, argument and
path errors are one line, outputs named with a trailing slash are refused, a failed write names
its file, and a far/near of 1e20 still draws (with nothing on stderr under -q)."""
import json
import os
import resource
import signal
import subprocess
import sys

import pytest

from helpers import ROOT, model
from hlod_core.cli.main import main
from processes import group_is_gone, hlod, last_json, one_line_error, wait_for


@pytest.mark.parametrize("sig, status, last_line", [
    (signal.SIGTERM, 128 + signal.SIGTERM, "hlod_core: terminated by SIGTERM"),
    (signal.SIGHUP, 128 + signal.SIGHUP, "hlod_core: terminated by SIGHUP"),
    (signal.SIGINT, 130, "hlod_core: interrupted"),
])
def test_signal_mid_bake_removes_scratch_and_output(tmp_path, sig, status, last_line):
    """A real `--jobs 2` bake, signalled once its worker scratch folder exists. SIGTERM and SIGHUP
    used to kill the process outright: the hlod-bake-* folder stayed in TMPDIR and the workers
    lived on as orphans; Ctrl-C printed a KeyboardInterrupt traceback. The bake runs in its own
    process group so that the test can check no worker outlives it (and reap any that would)."""
    scratch, out, log = tmp_path / "tmp", tmp_path / "statue.hlod", tmp_path / "stderr.txt"
    scratch.mkdir()
    with open(log, "w") as stderr:
        proc = subprocess.Popen([sys.executable, "-m", "hlod_core", "bake", str(model("statue")), "-o", str(out),
                                 "--jobs", "2"], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=stderr,
                                start_new_session=True,
                                env={**os.environ, "PYTHONPATH": str(ROOT), "TMPDIR": str(scratch)})
    try:
        wait_for(lambda: "bake simplify" in log.read_text(), 120, "a progress line")
        wait_for(lambda: any(p.name.startswith("hlod-bake-") for p in scratch.iterdir()), 60, "the scratch folder")
        proc.send_signal(sig)
        assert proc.wait(timeout=120) == status, log.read_text()[-2000:]
        wait_for(lambda: group_is_gone(proc.pid), 60, "the workers to exit")
    finally:
        if not group_is_gone(proc.pid):
            os.killpg(proc.pid, signal.SIGKILL)
    text = log.read_text()
    assert text.strip().splitlines()[-1] == last_line and "Traceback" not in text, text[-2000:]
    assert list(scratch.iterdir()) == [] and not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["stderr.txt", "tmp"]


@pytest.mark.parametrize("args, expect", [
    (["run", "x.hlod", "--method", "nope"], "argument --method: invalid choice: 'nope'"),
    (["run", "x.hlod", "--method", "coh", "--seed", "-1"], "argument --seed: expected a whole number >= 0, got -1"),
    (["scene", "low", "-o", "x.hlod", "--seed", "-1"], "argument --seed: expected a whole number >= 0, got -1"),
    (["run", "x.hlod", "--method", "coh", "--frames", "0"], "argument --frames: expected a whole number >= 1, got 0"),
    (["bake", "a.obj", "-o", "x.hlod", "--jobs", "-2"], "argument --jobs: expected a whole number >= 0, got -2"),
    (["bake", "a.obj", "-o", "x.hlod", "--target-tris", "many"],
     "argument --target-tris: expected a whole number, got 'many'"),
    (["bake"], "the following arguments are required: INPUT, -o/--output"),
    ([], "the following arguments are required: command"),
])
def test_argument_errors_are_one_line(capsys, args, expect):
    """argparse printed its whole usage before the error; a negative --seed reached numpy's
    default_rng as a ValueError traceback (run, evaluate, scene). In process: the real parser."""
    with pytest.raises(SystemExit) as exit_info:
        main(args)
    out, err = capsys.readouterr()
    assert exit_info.value.code == 2 and out == ""
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("hlod_core: error: ") and expect in lines[0], err


def test_output_with_a_trailing_slash_is_refused(tmp_path):
    """`-o old.hlod/` overwrote the file old.hlod and `-o new/` created a file named new: pathlib
    drops the slash. Both name a folder and are refused before baking; nothing is written."""
    old = tmp_path / "old.hlod"
    old.write_bytes(b"previous result")
    line = one_line_error(hlod("bake", model("cow"), "-o", f"{old}/", check=False))
    assert f"-o {old}/: names a folder, but {old} is a file" in line
    line = one_line_error(hlod("bake", model("cow"), "-o", f"{tmp_path}/new/", check=False))
    assert f"-o {tmp_path}/new/: names a folder; give a file name such as {tmp_path}/new/scene.hlod" in line
    line = one_line_error(hlod("run", old, "--method", "vfc", "--save-path", f"{tmp_path}/p.json/", check=False))
    assert "--save-path" in line and "names a folder" in line
    assert old.read_bytes() == b"previous result"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.hlod"]


def _file_size_limit(limit_bytes: int):
    def apply():  # in the child: writes past the limit fail with EFBIG (Python ignores SIGXFSZ)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))
    return apply


def test_failed_write_names_the_output(tmp_path):
    """A write error carries no file name: the line said `output: File too large`."""
    src = tmp_path / "cow.hlod"
    hlod("-q", "bake", model("cow"), "-o", src, "--target-tris", "400")
    for args, named in ((["bake", model("cow"), "-o", tmp_path / "big.hlod"], tmp_path / "big.hlod"),
                        (["export", src, "-o", tmp_path / "tiles"], tmp_path / "tiles")):
        proc = subprocess.run([sys.executable, "-m", "hlod_core", "-q", *map(str, args)], cwd=ROOT,
                              capture_output=True, text=True, timeout=300, preexec_fn=_file_size_limit(4000),
                              env={**os.environ, "PYTHONPATH": str(ROOT)})
        assert proc.returncode == 2 and proc.stderr == f"hlod_core: error: {named}: File too large\n", proc.stderr
    # no .hlod and no temporary file; the cache of the failed bake's finished nodes stays for the next
    # attempt (bake_cache.py: entries are whole files, renamed into place)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["big.hlod.cache", "cow.hlod", "cow.hlod.cache"]


def _path_file(folder, name, **fields):
    frames = [{"eye": [2.5, -3.0, 1.0], "target": [0.2, 0.0, 0.3], "up": [0, 0, 1]},
              {"eye": [0.5, -3.5, 0.8], "target": [0.2, 0.0, 0.3], "up": [0, 0, 1]}]
    path = folder / name
    path.write_text(json.dumps({"fovy_deg": 60, "near": 0.01, "far": 100, "frames": frames, **fields}))
    return path


@pytest.mark.gl
@pytest.mark.parametrize("far_over_near", [1e17, 1e20])
def test_huge_far_over_near_draws_what_a_normal_far_draws(cow_file, tmp_path, far_over_near):
    """The frustum's far plane cancelled to a zero normal: every node was culled, the run drew
    nothing, exited 0 and printed numpy's RuntimeWarning even under -q."""
    normal = last_json(hlod("-q", "run", cow_file, "--method", "vfc", "--size", "96x72",
                            "--path", _path_file(tmp_path, "a.json")))
    proc = hlod("-q", "run", cow_file, "--method", "vfc", "--size", "96x72",
                "--path", _path_file(tmp_path, "b.json", near=0.01, far=0.01 * far_over_near))
    assert proc.stderr == ""
    huge = last_json(proc)
    assert normal["dn"] > 0 and huge["dn"] == normal["dn"] and huge["tris"] == normal["tris"]


@pytest.mark.parametrize("document, expect", [
    ('{"frames": ' + "[" * 50_000 + "]" * 50_000 + "}", "camera path is not valid JSON (nested 50001 levels deep"),
    ('{"near": 0.01, "far": Infinity, "frames": []}', "Infinity is not a JSON number"),
    ('{"fovy_deg": null, "frames": [{"eye": [0, -3, 1], "target": [0, 0, 0]}]}', "fovy_deg must be a number, got null"),
    ('{"ortho_height": "2", "frames": [{"eye": [0, -3, 1], "target": [0, 0, 0]}]}',
     'ortho_height must be a number, got the string "2"'),
])
def test_bad_path_files_are_one_line(cow_file, tmp_path, document, expect):
    """These were RecursionError / TypeError / ValueError tracebacks (or accepted)."""
    path = tmp_path / "p.json"
    path.write_text(document)
    line = one_line_error(hlod("run", cow_file, "--method", "coh", "--path", path, check=False))
    assert line.startswith(f"hlod_core: error: {path}: ") and expect in line
