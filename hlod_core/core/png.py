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
