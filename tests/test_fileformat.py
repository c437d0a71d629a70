"""The native .hlod container: exact round trip, clear errors for truncated/foreign/corrupt
files and hostile values (ranges that wrap int64, Infinity, wrong types, deep nesting), atomic
writes that never leave a half-written file or lose the old one, with the umask's mode."""
import json
import os
import re
import stat
import struct
import subprocess
import sys
import time

import numpy as np
import pytest

from helpers import ROOT
from hlod_core.core import jsonutil
from hlod_core.core.errors import FormatError
from hlod_core.io import hlod_file


@pytest.fixture(scope="module")
def bunny(bakes):
    return bakes.baked("bunny")[1]


@pytest.fixture
def saved(bunny, tmp_path):
    return hlod_file.save(bunny, tmp_path / "bunny.hlod")


def test_round_trip_is_exact(bunny, saved):
    loaded = hlod_file.load(saved)
    for name, arr in bunny.node_arrays().items():
        got = getattr(loaded, name)
        assert got.dtype == np.dtype(hlod_file.NODE_ARRAYS[name][0]) and np.array_equal(got, arr), name
    for name in ("origin", "positions", "indices"):
        assert np.array_equal(getattr(loaded, name), getattr(bunny, name)), name
    assert loaded.normals is None
    assert loaded.meta == json.loads(json.dumps(bunny.meta))


def test_round_trip_with_normals(tmp_path, bunny):
    with_normals = bunny.replace(normals=np.tile(np.float32([0, 0, 1]), (bunny.positions.shape[0], 1)))
    loaded = hlod_file.load(hlod_file.save(with_normals, tmp_path / "n.hlod"))
    assert np.array_equal(loaded.normals, with_normals.normals)


def test_geometry_is_memory_mapped(saved):
    loaded = hlod_file.load(saved)
    assert isinstance(loaded.positions, np.memmap) and isinstance(loaded.indices, np.memmap)
    assert not loaded.positions.flags.writeable


@pytest.mark.parametrize("keep", [0, 5, 24, 100, "half", "minus1"])
def test_truncated_file_is_rejected_clearly(saved, keep):
    data = saved.read_bytes()
    n = {"half": len(data) // 2, "minus1": len(data) - 1}.get(keep, keep)
    saved.write_bytes(data[:n])
    with pytest.raises(FormatError, match=rf"{saved.name}: (truncated|not a \.hlod)"):
        hlod_file.load(saved)


@pytest.mark.parametrize("content", [b"", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", b"PK\x03\x04" + bytes(200),
                                     bytes(range(256)) * 4])
def test_foreign_file_is_rejected_clearly(tmp_path, content):
    path = tmp_path / "foreign.hlod"
    path.write_bytes(content)
    with pytest.raises(FormatError, match=r"foreign\.hlod: not a \.hlod file"):
        hlod_file.load(path)


def test_missing_file_is_a_format_error(tmp_path):
    with pytest.raises(FormatError, match="nothing.hlod: cannot read"):
        hlod_file.load(tmp_path / "nothing.hlod")


def test_future_version_is_rejected(saved):
    data = bytearray(saved.read_bytes())
    data[8:12] = struct.pack("<I", 99)
    saved.write_bytes(bytes(data))
    with pytest.raises(FormatError, match="version 99 is not supported"):
        hlod_file.load(saved)


def test_version_1_files_load_without_appearance(bunny, saved):
    """Version 2 only added optional parts: a version 1 file (positions only, as the previous
    release wrote them: the same layout and header) loads as an HLOD without appearance."""
    data = bytearray(saved.read_bytes())
    assert struct.unpack("<I", data[8:12])[0] == hlod_file.FORMAT_VERSION == 2
    data[8:12] = struct.pack("<I", 1)
    saved.write_bytes(bytes(data))
    loaded = hlod_file.load(saved)
    assert not loaded.has_appearance and loaded.materials == ()
    assert np.array_equal(loaded.indices, bunny.indices) and np.array_equal(loaded.error, bunny.error)


def test_appearance_round_trip_and_its_checks(bunny, tmp_path):
    """uvs, colors, tri_material and the material table come back as written, the texture path
    relative to the file in it and absolute in memory; bad ids, NaN UVs and colours outside [0, 1]
    are refused with one line."""
    from hlod_core.model.appearance import Material

    v, t = bunny.positions.shape[0], bunny.indices.shape[0]
    texture = tmp_path / "textures" / "a.png"
    textured = bunny.replace(uvs=np.asarray(bunny.positions[:, :2], np.float32),
                             colors=np.full((v, 4), 0.5, np.float32),
                             tri_material=(np.arange(t) % 2).astype(np.uint16),
                             materials=(Material("A", (1, 0, 0, 1), texture=str(texture)), Material("B")))
    path = hlod_file.save(textured, tmp_path / "t.hlod")
    header = json.loads(path.read_bytes()[24:24 + struct.unpack("<Q", path.read_bytes()[16:24])[0]])
    assert header["materials"][0]["texture"] == "textures/a.png"
    loaded = hlod_file.load(path)
    assert loaded.materials == textured.materials and loaded.materials[0].texture == str(texture)
    for name in ("uvs", "colors", "tri_material"):
        assert np.array_equal(getattr(loaded, name), getattr(textured, name)), name
    for bad, match in ((dict(tri_material=np.full(t, 2, np.uint16)), "past the 2 materials"),
                       (dict(uvs=np.full((v, 2), np.nan, np.float32)), "non-finite UVs"),
                       (dict(colors=np.full((v, 4), 1.5, np.float32)), "outside \\[0, 1\\]"),
                       (dict(tri_material=None), "no per-triangle material ids")):
        with pytest.raises(FormatError, match=match):
            hlod_file.validate(textured.replace(**bad))


def _rewrite_array(path, name, mutate):
    """Change one stored array in place (same size), as a corrupt file would have it."""
    loaded = hlod_file.load(path, mmap=False)
    arr = np.array(getattr(loaded, name))
    mutate(arr)
    with open(path, "rb") as f:
        _, _, _, header_len = struct.unpack("<8sIIQ", f.read(24))
        header = json.loads(f.read(header_len))
    with open(path, "r+b") as f:
        f.seek(header["arrays"][name]["offset"])
        f.write(arr.tobytes())


@pytest.mark.parametrize("name, mutate, message", [
    ("indices", lambda a: a.__setitem__((0, 0), 2**31), "index points past"),
    ("parent", lambda a: a.__setitem__(1, 5), "parent and child links disagree"),
    ("tri_count", lambda a: a.__setitem__(-1, 10**9), "triangle range"),
    ("error", lambda a: a.__setitem__(0, np.nan), "non-finite"),
    ("sphere_radius", lambda a: a.__setitem__(0, -1.0), "negative error or radius"),
    # finite but beyond MAX_COORDINATE: the renderer's float32 query boxes would overflow to inf
    ("box_max", lambda a: a.__setitem__((0, 0), 1e200), "beyond 1e\\+30 model units"),
    ("origin", lambda a: a.__setitem__(2, -3e30), "beyond 1e\\+30 model units"),
])
def test_corrupt_arrays_are_rejected(saved, name, mutate, message):
    _rewrite_array(saved, name, mutate)
    with pytest.raises(FormatError, match=message):
        hlod_file.load(saved)


def test_wrong_dtype_in_header_is_rejected(saved):
    data = saved.read_bytes()
    header_len = struct.unpack("<Q", data[16:24])[0]
    header = data[24:24 + header_len].replace(b'"dtype": "<f8", "nbytes": ', b'"dtype": "<f4", "nbytes": ', 1)
    saved.write_bytes(data[:24] + header + data[24 + header_len:])
    with pytest.raises(FormatError, match="inconsistent dtype/shape/size|expected"):
        hlod_file.load(saved)


def test_failed_write_keeps_the_old_file_and_leaves_no_temp(bunny, saved, monkeypatch):
    before = saved.read_bytes()

    def disk_full(fd):  # a write that fails half way, as on a full disk
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", disk_full)
    with pytest.raises(OSError):
        hlod_file.save(bunny.replace(meta={**bunny.meta, "note": "new"}), saved)
    assert saved.read_bytes() == before
    assert sorted(p.name for p in saved.parent.iterdir()) == [saved.name]


def test_save_creates_missing_folders(bunny, tmp_path):
    path = hlod_file.save(bunny, tmp_path / "a" / "b" / "x.hlod")
    assert hlod_file.load(path).node_count == bunny.node_count


# --- hostile input: what load accepts, the renderer can draw -------------------------

WRAP_OFFSET = 0x5555555555555556  # the reported file: with tri_count = WRAP_OFFSET + 10**7 the
# int64 sum tri_offset + tri_count wraps negative, so "offset + count > total" let it through


def _refused(path, match):
    """load raises one FormatError line that starts with the file and says `match` after it (the
    test's folder name is not searched: it could contain the words)."""
    with pytest.raises(FormatError) as info:
        hlod_file.load(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and "\n" not in message, message
    assert re.search(match, message[len(str(path)) + 2:]), message
    return message


def _set_node_values(path, **rows):
    """Set node-table cells in place, without loading first: name=(row, value), row -1 the last."""
    data = bytearray(path.read_bytes())
    length = struct.unpack_from("<Q", data, 16)[0]
    table = json.loads(data[24:24 + length])["arrays"]
    for name, (row, value) in rows.items():
        entry = table[name]
        column = np.frombuffer(data, np.dtype(entry["dtype"]), count=entry["shape"][0], offset=entry["offset"])
        column[row] = value
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("rows, match", [
    ({"tri_offset": (-1, WRAP_OFFSET), "tri_count": (-1, WRAP_OFFSET + 10**7)}, "triangle range"),
    ({"tri_offset": (3, 2**63 - 1), "tri_count": (3, 2)}, "triangle range"),
    ({"vertex_offset": (-1, 2**63 - 1), "vertex_count": (-1, 2**63 - 1)}, "vertex range"),
    ({"vertex_count": (0, 2**63 - 1)}, "vertex range"),
    ({"vertex_offset": (2, WRAP_OFFSET), "vertex_count": (2, WRAP_OFFSET + 10**7)}, "vertex range"),
    ({"tri_offset": (2, 0)}, "triangle ranges of nodes 0 and 2 overlap"),
    ({"child_offset": (0, 2**31 - 1), "child_count": (0, 1)}, "child ranges"),
])
def test_ranges_that_wrap_int64_are_refused(saved, rows, match):
    """Before: the first three loaded (the first one then crashed `run` with SIGSEGV drawing 30M
    indices out of a small buffer), the fourth made `info` run out of memory."""
    _set_node_values(saved, **rows)
    _refused(saved, match)


ROOM = 16384  # bytes, a multiple of 64 (arrays stay aligned)


def _rewrite_header(path, mutate, raw=None):
    """Rewrite the JSON header through `mutate(header)`, with ROOM bytes of room before the arrays (their
    offsets shifted to match) so a longer header still fits. Strings "RAW" become the text `raw`."""
    data = path.read_bytes()
    length = struct.unpack_from("<Q", data, 16)[0]
    header = json.loads(data[24:24 + length])
    start = min(e["offset"] for e in header["arrays"].values())
    for entry in header["arrays"].values():
        entry["offset"] += ROOM
    mutate(header)
    text = json.dumps(header)
    if raw is not None:
        text = text.replace('"RAW"', raw)
    blob = text.encode().ljust(start + ROOM - 24)
    assert len(blob) == start + ROOM - 24, "mutated header does not fit"
    path.write_bytes(data[:16] + struct.pack("<Q", len(blob)) + blob + data[start:])


def _set(*keys, value="RAW"):
    def mutate(header):
        node = header
        for k in keys[:-1]:
            node = node[k]
        node[keys[-1]] = value
    return mutate


@pytest.mark.parametrize("mutate, raw, match", [
    (_set("arrays", "positions", "shape", 0), "Infinity", "Infinity is not a JSON number"),
    (_set("arrays", "positions", "shape", 0), "1e999", "out of the float64 range"),
    (_set("arrays", "indices", "offset"), "-Infinity", "not a JSON number"),
    (_set("arrays", "error", "nbytes"), "NaN", "not a JSON number"),
    (_set("arrays", "error", "nbytes", value=1.5e3), None, "offset and nbytes must be non-negative integers"),
    (_set("arrays", "error", "shape", value=[2**33, 2**31]), None, "shape must be a list of 1"),
    (_set("arrays", "positions", "shape", value=[2**62, 3]), None, r"bytes do not hold <f4\[4611686018427387904, 3\]"),
    (_set("arrays", "positions", "shape", value=[True, 3]), None, "non-negative integers"),
    (_set("arrays", "positions", "shape", value=None), None, "shape must be a list"),
    (_set("arrays", "parent", value=[]), None, "not an object"),
    (_set("arrays", "positions", "dtype", value=">f4"), None, "dtype '>f4', expected '<f4'"),
    (_set("arrays", "error", "dtype", value="O"), None, "dtype 'O'"),
    (_set("arrays", "error", "dtype", value="V8"), None, "dtype 'V8'"),
    (_set("arrays", "indices", "dtype", value="U4"), None, "dtype 'U4'"),
    (_set("arrays", "error", "dtype", value={"names": ["a"], "formats": ["<f8"]}), None, "dtype"),
    (_set("arrays", "parent", "offset", value=64), None, "after the header"),
    (_set("arrays", "positions", "offset", value=2**64), None, "truncated"),
    (_set("arrays", "tangents", value={"dtype": "<f4", "shape": [1, 2], "offset": 0, "nbytes": 8}), None,
     "unknown array 'tangents'"),
    (_set("meta", value=None), None, "'meta' and 'arrays'"),
    (_set("meta", value=[1, 2]), None, "'meta' and 'arrays'"),
    (_set("meta", "input_tris", value="abc"), None, "meta field 'input_tris' is \"abc\""),
    (_set("meta", "target_tris", value=-5), None, "meta field 'target_tris'"),
    (_set("meta", "max_depth", value=1e300), None, "meta field 'max_depth'"),
    (_set("meta", "input_tris", value=10**30), None, "meta field 'input_tris'"),
    (_set("meta", "phase_seconds", value=[1]), None, "phase_seconds"),
    (_set("meta", "sources", value=[None]), None, "sources"),
    (_set("meta", "note"), "[" * 5000 + "]" * 5000, "nested 5002 levels deep"),
    (_set("meta", "note"), '"' + '\\"' * 1200, "Unterminated string"),
])
def test_hostile_header_values_give_one_clear_line(saved, mutate, raw, match):
    """Before: Infinity/1e999 and null or non-object meta, non-numeric meta counts and deep nesting
    raised OverflowError/TypeError/ValueError/RecursionError tracebacks, and '>f4' or an offset
    inside the header loaded."""
    _rewrite_header(saved, mutate, raw)
    _refused(saved, match)


def test_overlapping_arrays_are_refused(saved):
    """Before: loaded (cube_side read sphere_radius's bytes, which pass every value check)."""
    def mutate(header):
        header["arrays"]["cube_side"]["offset"] = header["arrays"]["sphere_radius"]["offset"]
    _rewrite_header(saved, mutate)
    _refused(saved, "arrays '(sphere_radius|cube_side)' and '(sphere_radius|cube_side)' overlap")


def test_header_padding_and_extra_meta_still_load(saved, bunny):
    """The checks above refuse what is wrong, not what is merely unusual."""
    _rewrite_header(saved, _set("meta", "note", value={"free": ["form", 1.5, None]}))
    assert hlod_file.load(saved).node_count == bunny.node_count


def test_json_string_scan_is_linear():
    """Timing is the subject: a string search that restarts at every quote of a header of escaped
    quotes is quadratic (23 s for these 40 KB, minutes for the 64 MB a header may have); the linear
    one takes about 2 ms (measured). Measured in this thread's CPU seconds, which other processes
    on a loaded machine do not inflate (nor the numeric library's idle threads), against a limit
    a thousand times the linear scan's and a tenth of the quadratic one's."""
    started = time.thread_time()
    with pytest.raises(jsonutil.JsonError, match="Unterminated string"):
        jsonutil.loads('"' + '\\"' * 20_000)
    assert time.thread_time() - started < 2.0


def test_saved_file_mode_follows_the_umask(bunny, tmp_path):
    """Before: 0600 whatever the umask (tempfile.mkstemp's mode survived the rename)."""
    for umask, mode in ((0o022, 0o644), (0o002, 0o664)):
        old = os.umask(umask)
        try:
            path = hlod_file.save(bunny, tmp_path / f"u{umask:o}.hlod")
        finally:
            os.umask(old)
        assert stat.S_IMODE(path.stat().st_mode) == mode


def test_a_write_past_the_file_size_limit_names_the_file(saved, tmp_path):
    """A real EFBIG (RLIMIT_FSIZE in a child): before, the CLI said "output: File too large"."""
    out = tmp_path / "out"
    script = ("import resource, signal, sys\n"
              "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
              "resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))\n"
              "from hlod_core.cli.main import main\n"
              f"sys.exit(main(['-q', 'export', {str(saved)!r}, '--format', 'hlod', '-o', {str(out)!r}]))\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONDONTWRITEBYTECODE": "1"}
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip() == f"hlod_core: error: {out / 'bunny.hlod'}: File too large"
    assert list(out.iterdir()) == []  # no temporary file left behind


@pytest.mark.parametrize("command", [["info"], ["run", "--method", "coh", "--frames", "2", "--size", "64x48"]])
def test_cli_refuses_the_wrapping_file_in_one_line(saved, command):
    """The reported file: `info` exited 0 and `run` died with SIGSEGV."""
    _set_node_values(saved, tri_offset=(-1, WRAP_OFFSET), tri_count=(-1, WRAP_OFFSET + 10**7))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-m", "hlod_core", command[0], str(saved), *command[1:]], env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and "triangle range" in proc.stderr and saved.name in proc.stderr


def test_save_refuses_meta_that_would_not_load(bunny, tmp_path):
    """NaN is not JSON: before, save wrote it (json.dumps allows it) into a file load refuses."""
    path = tmp_path / "nan.hlod"
    with pytest.raises(FormatError, match=r"nan\.hlod: cannot write the HLOD's meta as JSON"):
        hlod_file.save(bunny.replace(meta={**bunny.meta, "note": float("nan")}), path)
    assert list(tmp_path.iterdir()) == []
