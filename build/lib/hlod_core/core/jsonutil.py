"""JSON read with a nesting limit, for every JSON the project reads from users and files (.hlod
headers, scene specs, camera paths).

Python's `json` recurses once per nesting level: a few thousand `[` raise RecursionError (or worse,
exhaust the C stack) instead of a clear message. The depth is checked first, vectorised over the
text with strings blanked out, so the parser never sees a document nested deeper than MAX_DEPTH.
"""
from __future__ import annotations

import json
import math
import os
import re

import numpy as np

from .errors import InputError

#: Deepest nesting of arrays/objects accepted; our documents need 4.
MAX_DEPTH = 64

# A string, or an unterminated one up to the end of the text, in one linear pass ("unrolled loop":
# runs of plain characters between escapes). The closing quote is optional: required, it would make
# the search restart at every quote of a text like `"\"\"\"...` (quadratic: minutes for 64 KB).
_STRING = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"?', re.DOTALL)


class JsonError(ValueError):
    """Not JSON, or nested deeper than the limit; the message says which."""


def nesting_depth(text: str) -> int:
    """Deepest bracket nesting of a JSON text (brackets inside strings do not count)."""
    bare = _STRING.sub("", text).encode("utf-8", "surrogatepass")
    codes = np.frombuffer(bare, np.uint8)
    step = np.zeros(codes.shape[0], np.int64)
    step[(codes == ord("[")) | (codes == ord("{"))] = 1
    step[(codes == ord("]")) | (codes == ord("}"))] = -1
    return int(np.cumsum(step).max(initial=0))


def loads(text: str | bytes, *, max_depth: int = MAX_DEPTH):
    """json.loads that refuses documents nested deeper than `max_depth`, NaN/Infinity literals
    (not JSON; Python accepts them) and numbers that overflow float64 (1e999). Raises JsonError."""
    if isinstance(text, (bytes, bytearray)):
        try:
            text = bytes(text).decode("utf-8")
        except UnicodeDecodeError as exc:
            raise JsonError(f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    depth = nesting_depth(text)
    if depth > max_depth:
        raise JsonError(f"nested {depth} levels deep (at most {max_depth})")
    try:
        return json.loads(text, parse_constant=_refuse_constant, parse_float=_finite_float)
    except (ValueError, RecursionError) as exc:
        raise JsonError(str(exc)) from None


def read(path: str | os.PathLike, *, what: str):
    """Load the JSON file `path` (with `loads`' limits). Raises InputError naming the file and
    `what` it should be ("camera path", "scene spec", ...) when it cannot be read or parsed."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as exc:
        raise InputError(f"{path}: cannot read {what} ({exc.strerror or exc})") from None
    try:
        return loads(data)
    except JsonError as exc:
        raise InputError(f"{path}: {what} is not valid JSON ({exc})") from None


def _refuse_constant(name: str):
    raise ValueError(f"{name} is not a JSON number")


def _finite_float(text: str) -> float:
    """A JSON number with a fraction or exponent; refuses those that overflow to infinity (1e999)."""
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"number {text[:40]} is out of the float64 range")
    return value
