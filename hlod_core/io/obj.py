"""OBJ files: checked here before pymeshlab reads them (`check_obj`: vertex numbers, face indices
inside their lists, the layouts pymeshlab misreads), or read here when they name a material library
(`read_obj`: triangles, UVs, normals, `usemtl` groups; the MTL in mtl.py).

Data form: a file's bytes in, numpy arrays or counts out, vectorised over the bytes; InputError
naming the file and the line at fault. Why:
docs/how-it-works.md#why-obj-and-stl-files-are-checked-before-pymeshlab-reads-them
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from .text_numbers import parse_numbers

_TOKEN = re.compile(rb"[^ \t\r\n#]+")
#: The line keywords the check reads, as codes (0: any other line).
_V, _VT, _VN, _F = 1, 2, 3, 4
_KEYWORDS = {b"v": _V, b"vt": _VT, b"vn": _VN, b"f": _F}


@dataclass(frozen=True, eq=False)
class _ObjText:
    """An OBJ file's bytes by line: line_start/line_end (lines,) byte positions, keyword (lines,)
    code from _KEYWORDS (0: another line), indented (lines,) bool; body (bytes,) the keyword code
    of each byte after a keyword, up to a '#' or the line's end (0 elsewhere); blank (bytes,)."""

    data: bytes
    buf: np.ndarray
    line_start: np.ndarray
    line_end: np.ndarray
    keyword: np.ndarray
    indented: np.ndarray
    body: np.ndarray
    blank: np.ndarray

    @staticmethod
    def of(data: bytes) -> "_ObjText":
        buf = np.frombuffer(data, np.uint8)
        line_start = np.concatenate([[0], np.flatnonzero(buf == ord("\n")) + 1])
        indented = np.zeros(line_start.size, bool)
        indented[line_start < buf.size] = _blank(buf[line_start[line_start < buf.size]])
        if indented.any():  # read keywords from column 0 (line numbers stay)
            data = re.sub(rb"(?m)^[ \t\r]+", b"", data)
            buf = np.frombuffer(data, np.uint8)
            line_start = np.concatenate([[0], np.flatnonzero(buf == ord("\n")) + 1])
        line_end = np.concatenate([line_start[1:] - 1, [buf.size]])
        padded = np.concatenate([buf, np.frombuffer(b"\n\n\n", np.uint8)])
        keyword = np.zeros(line_start.size, np.uint8)
        for word, code in _KEYWORDS.items():  # the word, then a blank or the line's end
            after = padded[line_start + len(word)]
            match = _blank(after) | (after == ord("\n"))
            for k, letter in enumerate(word):
                match &= padded[line_start + k] == letter
            keyword[match] = code
        body = np.repeat(keyword, line_end - line_start + 1)[:buf.size]  # each byte: its line's keyword
        for word, code in _KEYWORDS.items():  # not the keyword itself
            for k in range(len(word)):
                body[line_start[keyword == code] + k] = 0
        body[line_end[:-1]] = 0  # nor the newlines
        hashes = np.flatnonzero((buf == ord("#")) & (body > 0))
        if hashes.size:  # trailing comments
            lines, first = np.unique(np.searchsorted(line_end, hashes), return_index=True)
            body[_range_mask(buf.size, hashes[first], line_end[lines])] = 0
        return _ObjText(data=data, buf=buf, line_start=line_start, line_end=line_end, keyword=keyword,
                        indented=indented, body=body, blank=_blank(buf))

    def line_of(self, pos) -> np.ndarray:
        """Line index (0-based) of byte positions."""
        return np.searchsorted(self.line_end, pos)

    def fail(self, path: Path, line: int, what: str) -> InputError:
        text = self.data[self.line_start[line]:self.line_end[line]].decode("utf-8", "replace").strip()[:60]
        return InputError(f"{path}: line {line + 1} ('{text}'): {what}")


def check_obj(path: Path, data: bytes) -> tuple[int, int]:
    """Validate an OBJ file's `v` and `f` lines against what pymeshlab's reader does with them:
    every vertex three or more finite numbers; every face three or more corners `v`, `v/t`,
    `v//n` or `v/t/n`, each index inside its list (1..count, or -1..-(count above the line); t and
    n only checked where the file has `vt` / `vn` lines, as pymeshlab ignores them otherwise).
    pymeshlab skips indented `v`/`vt`/`vn` lines and reads a comment after a face as indices
    (out-of-range indices then corrupt its memory), so those are refused too. Returns (vertices
    declared, triangles the faces triangulate to); raises InputError naming the file and line.
    Vectorised over the bytes: measured at 0.7 to 0.9 times pymeshlab's own reading time."""
    text = _ObjText.of(data)
    _check_obj_layout(path, text)
    return _check_obj_vertices(path, text), _check_obj_faces(path, text)


def _check_obj_layout(path: Path, text: _ObjText) -> None:
    """check_obj's line layout checks: the indented vertex lines and face comments pymeshlab misreads."""
    misread = np.flatnonzero(text.indented & np.isin(text.keyword, (_V, _VT, _VN)))
    if misread.size:
        raise text.fail(path, int(misread[0]), "an indented vertex line, which pymeshlab's OBJ reader skips "
                                               "(remove the indentation)")
    commented = np.flatnonzero((text.keyword == _F) & _has_byte(text, ord("#")))
    if commented.size:
        raise text.fail(path, int(commented[0]), "a comment after a face, which pymeshlab's OBJ reader reads as "
                                                 "indices (move it to a line of its own)")


@dataclass(frozen=True, eq=False)
class ObjArrays:
    """An OBJ file's triangles with what they refer to (`read_obj`): positions (v,3) float64,
    faces (f,3) int64 rows of positions, uvs (v,2) float32 or None (the file's `vt`, v up as
    OBJ and Blender have it), normals (v,3) float32 or None (`vn`, where every corner has one),
    face_group (f,) int32 index into `material_names` (the `usemtl` in force; -1 before the
    first), mtllibs: the `mtllib` file names as written. A vertex is one distinct (v, vt, vn)
    corner, so UV seams split vertices."""

    positions: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None
    normals: np.ndarray | None
    face_group: np.ndarray
    material_names: list[str]
    mtllibs: list[str]
    dropped: int


_USEMTL = re.compile(rb"(?m)^[ \t]*(usemtl|mtllib)[ \t]+([^\r\n#]*?)[ \t]*\r?$")


def obj_has_appearance(data: bytes) -> bool:
    """Whether an OBJ file names a material library (then `read_obj` reads it, with its texture
    coordinates; otherwise pymeshlab does: texture coordinates without materials have
    no texture to map, and are left out)."""
    return re.search(rb"(?m)^[ \t]*mtllib[ \t]", data) is not None


def read_obj(path: Path, data: bytes) -> ObjArrays:
    """Read an OBJ file's vertices, texture coordinates, normals, faces and `usemtl` groups
    (validated by `check_obj` first). Polygons are fan-triangulated (exact for convex ones, as
    exporters write them); a triangle that repeats a vertex is dropped (`dropped` counts them,
    as pymeshlab drops them). Raises InputError naming the file and line."""
    text = _ObjText.of(data)
    _check_obj_layout(path, text)
    _, face_sizes, corners = _check_obj_faces(path, text, corners=True)
    v = _line_vectors(path, text, _V, noun="vertex", least=3, width=3)
    vt = _line_vectors(path, text, _VT, noun="texture coordinate", least=1, width=2)
    vn = _line_vectors(path, text, _VN, noun="normal", least=3, width=3)
    first = np.cumsum(face_sizes) - face_sizes  # each face's first corner
    per_face = face_sizes - 2
    face = np.repeat(np.arange(face_sizes.size), per_face)
    step = np.arange(face.size) - np.repeat(np.cumsum(per_face) - per_face, per_face)
    tri = np.stack([first[face], first[face] + step + 1, first[face] + step + 2], axis=1)
    tv = corners[tri, 0]
    keep = (tv[:, 0] != tv[:, 1]) & (tv[:, 1] != tv[:, 2]) & (tv[:, 0] != tv[:, 2])
    tri, face = tri[keep], face[keep]
    if tri.size == 0:
        raise InputError(f"{path}: the mesh has no triangles")
    used = corners[tri.ravel()]
    has_uv = vt.shape[0] > 0 and bool((used[:, 1] >= 0).any())
    has_normal = vn.shape[0] > 0 and bool((used[:, 2] >= 0).all())
    unique, inverse = _unique_corners(used, uv_lists=vt.shape[0] if has_uv else 0,
                                      normal_lists=vn.shape[0] if has_normal else 0)
    uvs = None
    if has_uv:  # a corner without `vt` gets (0, 0), as merge gives a mesh without UVs
        uvs = np.where(unique[:, 1:2] >= 0, vt[np.maximum(unique[:, 1], 0)], 0.0).astype(np.float32)
    normals = vn[unique[:, 2]].astype(np.float32) if has_normal else None
    names, group_at, libs = [], [], []
    for m in _USEMTL.finditer(text.data):
        name = m.group(2).decode("utf-8", "replace")
        if m.group(1) == b"mtllib":
            libs.append(name)
        else:
            names.append(name)
            group_at.append(m.start())
    group_line = text.line_of(np.asarray(group_at, np.int64))
    group = np.searchsorted(group_line, np.flatnonzero(text.keyword == _F)) - 1  # last usemtl above a face
    distinct = {n: i for i, n in enumerate(dict.fromkeys(names))}
    rank = np.array([distinct[n] for n in names] + [-1], np.int32)  # group -1 -> rank[-1] = -1
    return ObjArrays(positions=v[unique[:, 0]], faces=inverse.reshape(-1, 3).astype(np.int64), uvs=uvs,
                     normals=normals, face_group=rank[group[face]], material_names=list(distinct), mtllibs=libs,
                     dropped=int((~keep).sum()))


def _unique_corners(used: np.ndarray, *, uv_lists: int, normal_lists: int) -> tuple[np.ndarray, np.ndarray]:
    """(distinct (u,3) [v, vt, vn] rows, (c,) row of each corner) of corner indices (-1: none),
    ignoring vt (vn) when uv_lists (normal_lists) is 0. One int64 key per corner (sorting rows
    with np.unique(axis=0) takes several times longer)."""
    t_span, n_span = uv_lists + 1, normal_lists + 1
    t = used[:, 1] + 1 if uv_lists else np.zeros(used.shape[0], np.int64)
    n = used[:, 2] + 1 if normal_lists else np.zeros(used.shape[0], np.int64)
    if (int(used[:, 0].max()) + 1) * t_span * n_span >= 2 ** 62:  # no room for one key: sort rows
        unique, inverse = np.unique(np.stack([used[:, 0], t, n], axis=1), axis=0, return_inverse=True)
    else:
        keys, inverse = np.unique((used[:, 0] * t_span + t) * n_span + n, return_inverse=True)
        unique = np.stack([keys // (t_span * n_span), keys // n_span % t_span, keys % n_span], axis=1)
    return unique - np.array([0, 1, 1]), inverse.reshape(-1)


def _line_vectors(path: Path, text: _ObjText, code: int, *, noun: str, least: int, width: int) -> np.ndarray:
    """(lines, width) float64: the first `width` numbers of every line of keyword `code` (a line
    needs `least`; missing ones are 0). InputError naming the line of a token that is no number."""
    lines = text.keyword == code
    if not lines.any():
        return np.zeros((0, width))
    body = (text.body == code) & ~text.blank
    token = _run_starts(body)
    count = _per_line(token, text.line_start)[lines]
    short = np.flatnonzero(lines)[count < least]
    if short.size:
        raise text.fail(path, int(short[0]), "a vertex needs three coordinates" if code == _V
                        else f"a {noun} needs {least} or more numbers")
    values = _body_numbers(body, text, lines=lines, dtype=np.float64, expected=int(token.sum()))
    if values is None or not np.all(np.isfinite(values)):
        pos, word = _first_bad_token(text, token, finite=True)
        raise text.fail(path, int(text.line_of(pos)), f"'{word}' is not a finite number")
    start = np.cumsum(count) - count
    out = np.zeros((count.size, width))
    for k in range(width):
        has = count > k
        out[has, k] = values[start[has] + k]
    return out


def _first_bad_token(text: _ObjText, token: np.ndarray, *, finite: bool) -> tuple[int, str]:
    """(byte position, text) of the first token (token: (bytes,) bool, True at each token's first
    byte) that does not read as a number (with `finite`: as a finite number) the way the bulk
    parse reads it; the caller knows one does not."""
    for pos in np.flatnonzero(token):
        word = _TOKEN.match(text.data, pos).group()
        value = parse_numbers(word, np.float64, 1)
        if value is None or (finite and not np.isfinite(value[0])):
            return int(pos), word.decode("utf-8", "replace")
    raise ValueError("every token reads as a number")  # not reached: the bulk parse failed on one


def _has_byte(text: _ObjText, byte: int) -> np.ndarray:
    """(lines,) bool: lines holding the byte."""
    return np.bincount(text.line_of(np.flatnonzero(text.buf == byte)), minlength=text.line_start.size) > 0


def _check_obj_vertices(path: Path, text: _ObjText) -> int:
    """Every `v` line: three or more finite numbers. Returns the number of `v` lines."""
    is_v = text.keyword == _V
    vertices = int(is_v.sum())
    body = (text.body == _V) & ~text.blank
    token = _run_starts(body)
    short = np.flatnonzero(is_v & (_per_line(token, text.line_start) < 3))
    if short.size:
        raise text.fail(path, int(short[0]), "a vertex needs three coordinates")
    coords = _body_numbers(body, text, lines=is_v, dtype=np.float64, expected=int(token.sum()))
    if coords is None:  # some token is not a number: name the first
        pos, word = _first_bad_token(text, token, finite=False)
        raise text.fail(path, int(text.line_of(pos)), f"'{word}' is not a number")
    if not np.all(np.isfinite(coords)):
        bad_lines = np.unique(text.line_of(np.flatnonzero(token)[~np.isfinite(coords)]))
        raise InputError(f"{path}: {bad_lines.size} of {vertices} vertices could not be read (line "
                         f"{bad_lines[0] + 1}: NaN, infinite or malformed coordinates)")
    return vertices


def _check_obj_faces(path: Path, text: _ObjText, *, corners: bool = False):
    """Every `f` line: three or more corners of integer indices inside their lists. Returns the
    number of triangles the faces triangulate to; with `corners`, also (faces,) corner counts and
    (c,3) int64 0-based [vertex, texture coordinate, normal] indices per corner (-1: none)."""
    buf, is_f = text.buf, text.keyword == _F
    body = (text.body == _F) & ~text.blank
    corner = _run_starts(body)
    per_face = _per_line(corner, text.line_start)
    short = np.flatnonzero(is_f & (per_face < 3))
    if short.size:
        raise text.fail(path, int(short[0]), "a face needs three or more vertices")
    digit = (buf - np.uint8(ord("0"))) < 10  # (uint8 wraps below '0')
    slash, minus = buf == ord("/"), buf == ord("-")
    number = body & (digit | minus)
    number_start = _run_starts(number)
    digit_next = np.concatenate([digit[1:], [False]])
    slash_before = np.concatenate([[False], slash[:-1]])
    bad = body & ~digit & ~slash & ~(minus & (corner | slash_before) & digit_next)  # '-' opens an index
    bad |= corner & ~number_start  # a corner starts with its vertex index
    bad |= body & slash & ~np.concatenate([body[1:], [False]])  # a corner ends in '/'
    bad |= slash & slash_before & np.concatenate([[False], slash_before[:-1]])  # '///'
    starts = np.flatnonzero(number_start)
    # which list each number indexes (0: v, 1: t, 2: n): the corner's first number is its vertex,
    # one after '//' is a normal, and one after '/' a texture coordinate unless one came before it
    first = corner[starts]
    double = slash_before[starts] & slash_before[np.maximum(starts - 1, 0)]
    after_first = np.concatenate([[False], first[:-1]])
    role = np.where(first, 0, np.where(double | ~after_first, 2, 1))
    after_normal = np.concatenate([[False], role[:-1] == 2]) & ~first  # v/t/n/x, v//n/x
    bad[starts[after_normal | (double & ~after_first)]] = True  # and v/t//n
    if bad.any():
        raise text.fail(path, int(text.line_of(np.argmax(bad))),
                        "malformed face (corners are v, v/t, v//n or v/t/n, with integer indices)")
    values = _body_numbers(number, text, lines=is_f, dtype=np.int64, expected=starts.size)
    lists = ((_V, 0, "vertex", "vertices"), (_VT, 1, "texture coordinate", "texture coordinates"),
             (_VN, 2, "normal", "normals"))
    table = np.full((int(corner.sum()) if corners else 0, 3), -1, np.int64)
    corner_of = np.searchsorted(np.flatnonzero(corner), starts, side="right") - 1 if corners else None
    for code, what, noun, nouns in lists:
        listed = text.keyword == code
        count = int(listed.sum())
        if code != _V and count == 0:
            continue  # no such list: pymeshlab ignores these indices, and so does the bake
        index, at = values[role == what], starts[role == what]
        inside = (index >= 1) & (index <= count)
        relative = np.flatnonzero(index < 0)
        above = None
        if relative.size:  # -k: the k-th entry above the face's line
            above = (np.cumsum(listed) - listed)[text.line_of(at[relative])]
            inside[relative] = -index[relative] <= above
        if not inside.all():
            k = int(np.argmin(inside))
            known = f"{count} {nouns}" if index[k] >= 0 else f"fewer {nouns} above this line"
            raise text.fail(path, int(text.line_of(at[k])), f"a face refers to {noun} {index[k]}, but the file has "
                                                            f"{known}")
        if corners:
            zero_based = index - 1
            if above is not None:
                zero_based[relative] = above + index[relative]
            table[corner_of[role == what], what] = zero_based
    triangles = int((per_face[is_f] - 2).sum())
    return (triangles, per_face[is_f], table) if corners else triangles


def _blank(byte: np.ndarray) -> np.ndarray:
    """Space, tab or carriage return."""
    return (byte == ord(" ")) | (byte == ord("\t")) | (byte == ord("\r"))


def _run_starts(mask: np.ndarray) -> np.ndarray:
    """(size,) bool: the first byte of each run of True."""
    return mask & ~np.concatenate([[False], mask[:-1]])


def _per_line(starts: np.ndarray, line_start: np.ndarray) -> np.ndarray:
    """(lines,) int: how many of the True bytes of `starts` each line holds."""
    line = np.searchsorted(line_start, np.flatnonzero(starts), side="right") - 1
    return np.bincount(line, minlength=line_start.size)


def _range_mask(size: int, begin: np.ndarray, end: np.ndarray) -> np.ndarray:
    """(size,) bool: True inside the disjoint ranges [begin, end)."""
    step = np.zeros(size + 1, np.int8)
    step[begin] += 1  # begins are distinct, and so are ends
    step[end] -= 1
    return np.cumsum(step[:-1], dtype=np.int8) > 0


def _body_numbers(body: np.ndarray, text: _ObjText, *, lines: np.ndarray, dtype, expected: int) -> np.ndarray | None:
    """The numbers in the `body` bytes of the selected lines, in order (see text_numbers.parse_numbers)."""
    if expected == 0:
        return np.zeros(0, dtype)
    chosen = np.flatnonzero(lines)
    span = slice(int(text.line_start[chosen[0]]), int(text.line_end[chosen[-1]]))  # only where these lines are
    return parse_numbers(np.where(body[span], text.buf[span], ord(" ")).tobytes(), dtype, expected)

