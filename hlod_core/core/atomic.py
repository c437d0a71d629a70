"""Atomic writes: the one helper every output of the project goes through.

A file is written to a temporary name in its target folder, flushed and fsynced, given the mode an
ordinary `open(path, "w")` would give it (0o666 less the process umask; `tempfile` would leave
0o600), then renamed over the target (`replace`: retried for a moment on Windows). A failure or an interrupt (Ctrl-C,
SIGTERM turned into an exception by the command line) removes the temporary file and leaves any earlier file untouched.
A write that fails names the target file in its OSError.

Folders: `replace_folder` puts a folder written beside its target in the target's place (the
earlier one renamed aside, then removed), and `remove_tree` removes a folder, retried on Windows
while a process that is ending still holds a file in it. Why: docs/how-it-works.md#what-differs-by-platform
"""
from __future__ import annotations

import contextlib
import os
import re
import secrets
import shutil
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


#: Windows: how long `remove_tree` retries files a process still holds; a worker killed a moment
#: ago (TerminateProcess returns before the process has gone) keeps its mapped arrays until it has gone.
REMOVE_RETRY_SECONDS = 5.0


def remove_tree(path: str | os.PathLike, *, platform: str | None = None) -> bool:
    """Remove the folder `path` and everything in it; whether it is gone (True when it was not
    there). POSIX deletes files others have open or mapped: one pass. Windows refuses to delete a
    file another process has mapped or open without sharing deletion (PermissionError, WinError 5
    or 32): there what is left is removed again every REPLACE_RETRY_EVERY_SECONDS for
    REMOVE_RETRY_SECONDS. What stays is the caller's to name."""
    if (sys.platform if platform is None else platform) != "win32":
        shutil.rmtree(path, ignore_errors=True)
        return not os.path.lexists(path)
    deadline = time.monotonic() + REMOVE_RETRY_SECONDS
    while True:
        shutil.rmtree(path, ignore_errors=True)
        if not os.path.lexists(path):
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(REPLACE_RETRY_EVERY_SECONDS)


def replace_folder(staging: str | os.PathLike, target: str | os.PathLike, *,
                   platform: str | None = None) -> list[str]:
    """Put the folder `staging` (written beside `target`) in `target`'s place, so that `target` is
    at every moment the earlier folder or the new one, whole (absent only between two renames):
    the earlier one is renamed aside to `.NAME.old-XXXXXXXX`, `staging` renamed to `target`, and
    the aside folder removed. Each rename is `replace`'s (retried on Windows while a process holds
    a file in the folder open: a viewer serving a tile). When `staging` cannot take the place, the
    earlier folder is renamed back and the error raised. Aside folders of `target` that cannot be
    removed (`remove_tree`), this one's or earlier ones', stay until the next call; returns their paths."""
    staging, target = Path(staging), Path(target)
    if not target.exists():
        replace(staging, target, platform=platform)
        return _remove_asides(target, platform=platform)
    aside = target.with_name(f".{target.name}.old-{secrets.token_hex(4)}")
    replace(target, aside, platform=platform)
    try:
        replace(staging, target, platform=platform)
    except BaseException as exc:
        try:
            replace(aside, target, platform=platform)
        except OSError as back:
            raise OSError(back.errno, f"{target}: not replaced, and the earlier folder could not be put back "
                          f"({back.strerror or back}); it is {aside}", str(target)) from exc
        raise
    return _remove_asides(target, platform=platform)


def _remove_asides(target: Path, *, platform: str | None) -> list[str]:
    """Remove the folders `replace_folder` renamed aside from `target` (`.NAME.old` too, the name an
    earlier version used); the paths of those that stay."""
    aside = re.compile(rf"\.{re.escape(target.name)}\.old(-[0-9a-f]{{8}})?")
    try:
        names = sorted(n for n in os.listdir(target.parent) if aside.fullmatch(n))
    except OSError:
        return []
    return [str(target.parent / n) for n in names if not remove_tree(target.parent / n, platform=platform)]


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
