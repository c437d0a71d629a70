"""The native .hlod container: exact round trip, clear errors for truncated/foreign/corrupt
files, atomic writes that never leave a half-written file or lose the old one."""
import json
import os
import struct

import numpy as np
import pytest

from hlod_core import fileformat
from hlod_core.errors import FormatError

from helpers import baked


@pytest.fixture(scope="module")
def bunny():
    return baked("stanford-bunny.obj")[1]


@pytest.fixture
def saved(bunny, tmp_path):
    return fileformat.save(bunny, tmp_path / "bunny.hlod")


def test_round_trip_is_exact(bunny, saved):
    loaded = fileformat.load(saved)
    for name, arr in bunny.node_arrays().items():
        got = getattr(loaded, name)
        assert got.dtype == np.dtype(fileformat.NODE_ARRAYS[name][0]) and np.array_equal(got, arr), name
    for name in ("origin", "positions", "indices"):
        assert np.array_equal(getattr(loaded, name), getattr(bunny, name)), name
    assert loaded.normals is None
    assert loaded.meta == json.loads(json.dumps(bunny.meta))


def test_round_trip_with_normals(tmp_path, bunny):
    with_normals = bunny.replace(normals=np.tile(np.float32([0, 0, 1]), (bunny.positions.shape[0], 1)))
    loaded = fileformat.load(fileformat.save(with_normals, tmp_path / "n.hlod"))
    assert np.array_equal(loaded.normals, with_normals.normals)


def test_geometry_is_memory_mapped(saved):
    loaded = fileformat.load(saved)
    assert isinstance(loaded.positions, np.memmap) and isinstance(loaded.indices, np.memmap)
    assert not loaded.positions.flags.writeable


@pytest.mark.parametrize("keep", [0, 5, 24, 100, "half", "minus1"])
def test_truncated_file_is_rejected_clearly(saved, keep):
    data = saved.read_bytes()
    n = {"half": len(data) // 2, "minus1": len(data) - 1}.get(keep, keep)
    saved.write_bytes(data[:n])
    with pytest.raises(FormatError, match=rf"{saved.name}: (truncated|not a \.hlod)"):
        fileformat.load(saved)


@pytest.mark.parametrize("content", [b"", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", b"PK\x03\x04" + bytes(200),
                                     bytes(range(256)) * 4])
def test_foreign_file_is_rejected_clearly(tmp_path, content):
    path = tmp_path / "foreign.hlod"
    path.write_bytes(content)
    with pytest.raises(FormatError, match=r"foreign\.hlod: not a \.hlod file"):
        fileformat.load(path)


def test_missing_file_is_a_format_error(tmp_path):
    with pytest.raises(FormatError, match="nothing.hlod: cannot read"):
        fileformat.load(tmp_path / "nothing.hlod")


def test_future_version_is_rejected(saved):
    data = bytearray(saved.read_bytes())
    data[8:12] = struct.pack("<I", 99)
    saved.write_bytes(bytes(data))
    with pytest.raises(FormatError, match="version 99 is not supported"):
        fileformat.load(saved)


def _rewrite_array(path, name, mutate):
    """Change one stored array in place (same size), as a corrupt file would have it."""
    loaded = fileformat.load(path, mmap=False)
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
    ("tri_count", lambda a: a.__setitem__(-1, 10**9), "triangle ranges"),
    ("error", lambda a: a.__setitem__(0, np.nan), "non-finite"),
    ("sphere_radius", lambda a: a.__setitem__(0, -1.0), "negative error or radius"),
])
def test_corrupt_arrays_are_rejected(saved, name, mutate, message):
    _rewrite_array(saved, name, mutate)
    with pytest.raises(FormatError, match=message):
        fileformat.load(saved)


def test_wrong_dtype_in_header_is_rejected(saved):
    data = saved.read_bytes()
    header_len = struct.unpack("<Q", data[16:24])[0]
    header = data[24:24 + header_len].replace(b'"dtype": "<f8", "nbytes": ', b'"dtype": "<f4", "nbytes": ', 1)
    saved.write_bytes(data[:24] + header + data[24 + header_len:])
    with pytest.raises(FormatError, match="inconsistent dtype/shape/size|expected"):
        fileformat.load(saved)


def test_failed_write_keeps_the_old_file_and_leaves_no_temp(bunny, saved, monkeypatch):
    before = saved.read_bytes()

    def disk_full(fd):  # a write that fails half way, as on a full disk
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", disk_full)
    with pytest.raises(OSError):
        fileformat.save(bunny.replace(meta={**bunny.meta, "note": "new"}), saved)
    assert saved.read_bytes() == before
    assert sorted(p.name for p in saved.parent.iterdir()) == [saved.name]


def test_save_creates_missing_folders(bunny, tmp_path):
    path = fileformat.save(bunny, tmp_path / "a" / "b" / "x.hlod")
    assert fileformat.load(path).node_count == bunny.node_count
