"""Minimal PNG writer (8-bit RGB or RGBA), so saving frames and textures needs no imaging library."""
from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import numpy as np


def write_png(path: str | os.PathLike, rgb: np.ndarray) -> Path:
    """rgb: (H, W, 3) uint8 RGB or (H, W, 4) uint8 RGBA (straight alpha), top row first."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(png_bytes(rgb))
    return path


def png_bytes(rgb: np.ndarray, *, level: int = 6) -> bytes:
    """The PNG file of (H, W, 3 or 4) uint8 pixels, top row first; level: zlib's compression level
    (0 to 9)."""
    rgb = np.ascontiguousarray(rgb, np.uint8)
    h, w, channels = rgb.shape
    raw = np.concatenate([np.zeros((h, 1), np.uint8), rgb.reshape(h, w * channels)], axis=1).tobytes()

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    colour_type = {3: 2, 4: 6}[channels]  # PNG's truecolour, truecolour with alpha
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, colour_type, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw, level)) + chunk(b"IEND", b""))


def png_pixels(data: bytes) -> np.ndarray:
    """The (H, W, 3 or 4) uint8 pixels, top row first, of a PNG that `png_bytes` wrote (8-bit RGB or
    RGBA, not interlaced, every row unfiltered); ValueError for any other PNG."""
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError("not a PNG")
    at, header, idat = 8, None, []
    while at + 8 <= len(data):
        length, tag = struct.unpack(">I4s", data[at:at + 8])
        header = data[at + 8:at + 8 + length] if tag == b"IHDR" else header
        if tag == b"IDAT":
            idat.append(data[at + 8:at + 8 + length])
        at += 12 + length
    if header is None or len(header) != 13:
        raise ValueError("a PNG without its header")
    w, h, depth, colour_type, _, _, interlace = struct.unpack(">IIBBBBB", header)
    channels = {2: 3, 6: 4}.get(colour_type)
    if depth != 8 or channels is None or interlace:
        raise ValueError(f"PNG of depth {depth}, colour type {colour_type}, interlace {interlace}")
    try:
        raw = zlib.decompress(b"".join(idat))
    except zlib.error as exc:
        raise ValueError(f"PNG data: {exc}") from None
    if len(raw) != h * (1 + w * channels):
        raise ValueError(f"PNG data of {len(raw)} bytes for {w}x{h}")
    rows = np.frombuffer(raw, np.uint8).reshape(h, 1 + w * channels)
    if np.any(rows[:, 0]):
        raise ValueError("a filtered PNG row")
    return rows[:, 1:].reshape(h, w, channels).copy()
