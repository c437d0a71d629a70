"""Copy a zip archive with its members renamed, without decompressing them.

scripts/build_extension.py rewrites pymeshlab's wheels for Blender 4.2 (`blender_ready`): the same
files under other names, and one member (RECORD) with new content. Python's zipfile can only write a
member by compressing it again, which took about 15 s for each 100 MB wheel (six of them per build of
every platform). Here each member's compressed bytes are copied as they are and only the headers that
carry the name are written anew, following PKWARE's APPNOTE.TXT (section 4.3: local file header,
central directory header, end of central directory record). No ZIP64, encryption or multi-disk archive
is written: a member that would need one stops the copy with ValueError (a wheel of a few hundred MB
has none).
"""
from __future__ import annotations

import struct
import zipfile
import zlib
from collections.abc import Callable
from typing import BinaryIO

_LOCAL = struct.Struct("<4s5H3L2H")  # signature, version needed, flags, method, time, date, crc, sizes, name/extra len
_CENTRAL = struct.Struct("<4s6H3L5H2L")
_END = struct.Struct("<4s4H2LH")
_LOCAL_SIGNATURE, _CENTRAL_SIGNATURE, _END_SIGNATURE = b"PK\x03\x04", b"PK\x01\x02", b"PK\x05\x06"
_DATA_DESCRIPTOR = 0x08  # flag bit 3: sizes and CRC follow the data (they are written in the header here)
_ENCRYPTED, _UTF8 = 0x01, 0x800
_LIMIT = 0xFFFFFFFF  # at or above it a size or offset needs ZIP64


def _dos_time(date_time: tuple[int, ...]) -> tuple[int, int]:
    year, month, day, hour, minute, second = date_time
    return (hour << 11) | (minute << 5) | (second // 2), ((year - 1980) << 9) | (month << 5) | day


def _raw_data(source: BinaryIO, info: zipfile.ZipInfo) -> bytes:
    """The compressed bytes of `info` as stored in `source` (the archive's file object)."""
    source.seek(info.header_offset)
    header = _LOCAL.unpack(source.read(_LOCAL.size))
    if header[0] != _LOCAL_SIGNATURE:
        raise ValueError(f"{info.filename}: no local file header at offset {info.header_offset}")
    source.seek(header[9] + header[10], 1)  # the local name and extra field
    return source.read(info.compress_size)


def copy_renamed(source_path, target: BinaryIO, rename: Callable[[str], str],
                 rewrite: Callable[[str], Callable[[bytes], bytes] | None] = lambda name: None) -> None:
    """Write to `target` the zip `source_path` with each member named rename(name). Members keep
    their compressed bytes, dates and attributes, except where rewrite(name) gives a function: that
    member's content becomes function(its decompressed content), deflated."""
    central: list[bytes] = []
    with zipfile.ZipFile(source_path) as archive, open(source_path, "rb") as source:
        for info in archive.infolist():
            if info.flag_bits & _ENCRYPTED or info.compress_size >= _LIMIT or info.file_size >= _LIMIT:
                raise ValueError(f"{source_path}: {info.filename}: encrypted or ZIP64 members are not copied")
            name = rename(info.filename)
            method, crc, size, data = info.compress_type, info.CRC, info.file_size, None
            change = rewrite(info.filename)
            if change is not None:
                new = change(archive.read(info))
                compressor = zlib.compressobj(6, zlib.DEFLATED, -15)  # raw deflate, as zip stores it
                data = compressor.compress(new) + compressor.flush()
                method, crc, size = zipfile.ZIP_DEFLATED, zlib.crc32(new), len(new)
            if data is None:
                data = _raw_data(source, info)
            encoded = name.encode("utf-8")
            flags = (info.flag_bits & ~_DATA_DESCRIPTOR) | (_UTF8 if not name.isascii() else 0)
            offset = target.tell()
            if offset >= _LIMIT:
                raise ValueError(f"{source_path}: the copy passes 4 GB at {info.filename} (ZIP64 is not written)")
            dos_time, dos_date = _dos_time(info.date_time)
            target.write(_LOCAL.pack(_LOCAL_SIGNATURE, 20, flags, method, dos_time, dos_date, crc, len(data), size,
                                     len(encoded), 0))
            target.write(encoded)
            target.write(data)
            central.append(_CENTRAL.pack(_CENTRAL_SIGNATURE, info.create_version | (info.create_system << 8), 20,
                                         flags, method, dos_time, dos_date, crc, len(data), size, len(encoded), 0, 0,
                                         0, info.internal_attr, info.external_attr, offset) + encoded)
    start = target.tell()
    for entry in central:
        target.write(entry)
    end = target.tell()
    if len(central) >= 0xFFFF or end >= _LIMIT:
        raise ValueError(f"{source_path}: too many members or bytes for a zip without ZIP64")
    target.write(_END.pack(_END_SIGNATURE, 0, 0, len(central), len(central), end - start, start, 0))
