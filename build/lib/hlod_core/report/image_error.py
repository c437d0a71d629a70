"""Image error between two renders of one view (DESIGN §9, dissertation Table 8.1).

Data form: images are (H, W, 3) uint8 RGB arrays of one size, top row first; colours convert to
YCbCr of ITU-R BT.601, full range (as JPEG), float64 0..255. PSNR uses peak 255 per channel;
identical images count as PSNR_CAP_DB (the MSE is floored at 255^2 * 10^(-PSNR_CAP_DB / 10)) so
means and deviations over frames stay finite.
"""
from __future__ import annotations

import numpy as np

PSNR_CAP_DB = 100.0
PEAK = 255.0  # 8-bit full range
CHROMA_OFFSET = 128.0  # Cb and Cr are centred on it
# rows Y, Cb, Cr of BT.601 full range, applied to RGB columns
_RGB_TO_YCBCR = np.array([[0.299, 0.587, 0.114], [-0.168736, -0.331264, 0.5], [0.5, -0.418688, -0.081312]])


def ycbcr(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) uint8 RGB -> float64 Y, Cb, Cr (BT.601 full range, 0..255)."""
    out = rgb.astype(np.float64) @ _RGB_TO_YCBCR.T
    out[..., 1:] += CHROMA_OFFSET
    return out


def psnr(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3,) PSNR in dB of Y, Cb, Cr between two RGB images of one size; PSNR_CAP_DB where identical."""
    if a.shape != b.shape:
        raise ValueError(f"images differ in size: {a.shape} vs {b.shape}")
    mse = np.mean((ycbcr(a) - ycbcr(b)) ** 2, axis=(0, 1))
    return 10.0 * np.log10(PEAK ** 2 / np.maximum(mse, PEAK ** 2 * 10 ** (-PSNR_CAP_DB / 10)))


def rmse_y(a: np.ndarray, b: np.ndarray) -> float:
    """Root mean square difference of luminance Y (0..255) between two RGB images of one size."""
    return float(np.sqrt(np.mean((ycbcr(a)[..., 0] - ycbcr(b)[..., 0]) ** 2)))
