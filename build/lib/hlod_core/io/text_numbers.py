"""Numbers in a text file's bytes, parsed by numpy in one call (the OBJ and ASCII STL readers).

Data form: bytes of whitespace-separated numbers in; a (k,) array of `dtype` out, or None when
the bytes are not exactly the numbers expected (something else stood between the spaces).
"""
from __future__ import annotations

import warnings

import numpy as np


def parse_numbers(text: bytes, dtype, expected: int) -> np.ndarray | None:
    """The whitespace-separated numbers of `text`; None unless they are exactly `expected`
    numbers (something else stood between the spaces)."""
    if expected == 0:
        return np.zeros(0, dtype)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # numpy's "unmatched data" warning
        try:
            values = np.fromstring(text, dtype=dtype, sep=" ")
        except (ValueError, DeprecationWarning):
            return None
    return values if values.size == expected else None
