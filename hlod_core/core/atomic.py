"""Atomic writes: the one helper every output of the project goes through.

A file is written to a temporary name in its target folder, flushed and fsynced, given the mode an
ordinary `open(path, "w")` would give it (0o666 less the process umask; `tempfile` would leave
0o600), then renamed over the target (`replace`: retried for a moment on Windows). A failure or an interrupt (Ctrl-C,
SIGTERM turned into an exception by the command line) removes the temporary file and leaves any earlier file untouched.
A write that fails names the target file in its OSError.
"""
from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import BinaryIO, Iterator


def umask_mode(base: int) -> int:
    """`base` (0o666 for files, 0o777 for folders) less the process umask."""
    mask = os.umask(0)
    os.umask(mask)
    return base & ~mask


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """Yield a binary file object; on a clean exit it replaces `path` atomically (fsync, rename)."""
    path = Path(path)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        try:  # around the `with` too: closing flushes the buffer, and that write can fail again
            with os.fdopen(fd, "wb") as f:
                yield f
                f.flush()
                os.fsync(f.fileno())
        except OSError as exc:
            raise _named(exc, path) from None
        os.chmod(tmp_name, umask_mode(0o666))
        replace(tmp_name, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp_name)
        raise


#: Windows: how long `replace` retries a target another process holds open, and how often.
REPLACE_RETRY_SECONDS, REPLACE_RETRY_EVERY_SECONDS = 2.0, 0.05


def replace(source: str | os.PathLike, target: str | os.PathLike, *, platform: str | None = None) -> None:
    """os.replace(source, target). POSIX renames over a file others have open or mapped. Windows
    refuses (PermissionError) while another process has the target open without sharing deletion,
    which a reader's brief open, a virus scanner or the search indexer does for a moment: there the
    rename is retried for REPLACE_RETRY_SECONDS before the error is raised. A file kept mapped
    stays refused: the .hlod reader does not map files on Windows (io.hlod_file.maps_files)."""
    if (sys.platform if platform is None else platform) != "win32":
        os.replace(source, target)
        return
    deadline = time.monotonic() + REPLACE_RETRY_SECONDS
    while True:
        try:
            os.replace(source, target)
            return
        except PermissionError:
            if time.monotonic() >= deadline:
                raise
            time.sleep(REPLACE_RETRY_EVERY_SECONDS)


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> Path:
    """Write `data` to `path` atomically (atomic_file); returns the path."""
    with atomic_file(path) as f:
        f.write(data)
    return Path(path)


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write `text` as UTF-8 to `path` atomically (atomic_file); returns the path."""
    return write_bytes_atomic(path, text.encode("utf-8"))


def _named(exc: OSError, path: Path) -> OSError:
    """The same error with the target file as its filename (a write error has none)."""
    if exc.filename is not None:
        return exc
    return type(exc)(exc.errno, exc.strerror or str(exc), str(path))
