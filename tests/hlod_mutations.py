"""The mutated .hlod files of the reader's fuzz run (tests/hlod_fuzz.py): a small baked base file
and seeded mutations of it.

Data form: a case is (index i, mutation description, file bytes); case i of seed S depends on
(S, i) alone. The base file is a UV sphere of 1,840 triangles with normals, baked with target_tris
64 (97 nodes, 2,928 triangles with the LODs, 130 KB), saved, and rewritten with the header padded
by HEADER_SLACK bytes of spaces (JSON whitespace), so a mutated header usually still fits before
the arrays and the mutation under test is the one that matters.

Mutation kinds (MUTATIONS; case i gets kind i mod 8, plus up to two more at random): `flip` bytes
in the header, node table or anywhere; `truncate`; `header` values (Infinity, 1e999, null, wrong
types, shapes whose product wraps int64, dtype strings numpy accepts but we do not: '>f8', 'O',
'V8', 'U4', offsets into the header or past the end, unknown arrays, deep nesting, the preamble's
header length); `meta` (null, not an object, missing, non-numeric or huge counts); `node_value`
(-1, n, int32/int64 limits, NaN/inf in any node array); `overflow` (range pairs whose sum wraps:
tri_offset = 0x5555555555555556 with tri_count = tri_offset + 10**7, int64 max vertex ranges,
int32 child/depth wrap); `geometry` (NaN/inf/huge positions and normals, in-range indices: the
reader accepts them, the renderer must cope); `bounds` (finite extremes, 1e-300 to 1.8e308, in
boxes, spheres, errors, cube sides, origin: mostly accepted, the traversal's arithmetic meets them).
"""
from __future__ import annotations

import json
import struct
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hlod_core.io import hlod_file

HEADER_SLACK = 16384  # spaces after the base file's header JSON (bytes)
MUTATIONS = ("flip", "truncate", "header", "meta", "node_value", "overflow", "geometry", "bounds")

_PREAMBLE = struct.Struct("<8sIIQ")
_RAW = "__raw_json_{}__"  # placeholder strings replaced by raw JSON text (Infinity, 1e999, ...)
_WRAP_OFFSET = 0x5555555555555556  # with count = offset + 10**7, offset + count wraps int64 negative


# --- base file -------------------------------------------------------------------------------------

def uv_sphere(rings: int = 24, segments: int = 40):
    """Closed UV sphere of radius 1: positions (v,3) float64, faces (2 * segments * (rings - 1),3)
    int64 (1,840 triangles by default)."""
    theta = np.linspace(0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    positions = np.vstack([[0, 0, 1], ring, [0, 0, -1]])
    s = np.arange(segments)
    a = (1 + np.arange(rings - 2)[:, None] * segments + s).ravel()  # ring r, segment s
    b = (1 + np.arange(rings - 2)[:, None] * segments + (s + 1) % segments).ravel()  # ring r, segment s + 1
    body = np.concatenate([np.stack([a, a + segments, b + segments], -1), np.stack([a, b + segments, b], -1)])
    top = np.stack([np.zeros(segments, np.int64), 1 + s, 1 + (s + 1) % segments], -1)
    last = positions.shape[0] - 1
    first_of_last_ring = last - segments
    bottom = np.stack([np.full(segments, last), first_of_last_ring + (s + 1) % segments, first_of_last_ring + s], -1)
    return positions, np.vstack([top, body, bottom]).astype(np.int64)


def base_file(folder: Path) -> bytes:
    """Bake the sphere, save it, and return the file with HEADER_SLACK spaces after the header."""
    from hlod_core.bake.pipeline import bake
    from hlod_core.bake.settings import BakeSettings
    from hlod_core.io import meshes

    positions, faces = uv_sphere()
    mesh = meshes.from_arrays(positions, faces, positions.astype(np.float32), name="fuzz_sphere")  # unit normals
    hlod = bake(mesh, BakeSettings(target_tris=64, max_depth=6))
    data = hlod_file.save(hlod, folder / "base.hlod").read_bytes()
    header, table_start = _header(data)
    shift = -(-HEADER_SLACK // 64) * 64  # keeps every array on its 64-byte boundary
    for entry in header["arrays"].values():
        entry["offset"] += shift
    return _with_header(data, header, old_data_start=table_start, new_data_start=table_start + shift)


def _header(data: bytes) -> tuple[dict, int]:
    """(header dict, first array offset) of a well-formed file."""
    _, _, _, length = _PREAMBLE.unpack_from(data)
    header = json.loads(data[_PREAMBLE.size:_PREAMBLE.size + length])
    return header, min(e["offset"] for e in header["arrays"].values())


def _with_header(data: bytes, header: dict, *, old_data_start: int, new_data_start: int, raw=()) -> bytes:
    """`data` with `header` (placeholders replaced by `raw` texts) padded with spaces to end at
    new_data_start; the arrays from old_data_start follow. A header too long overwrites them."""
    text = json.dumps(header, sort_keys=True)
    for k, r in enumerate(raw):
        text = text.replace(json.dumps(_RAW.format(k)), r)
    blob = text.encode("utf-8")
    blob += b" " * max(0, new_data_start - _PREAMBLE.size - len(blob))
    out = _PREAMBLE.pack(hlod_file.MAGIC, hlod_file.FORMAT_VERSION, 0, len(blob)) + blob
    return out + data[old_data_start + len(out) - new_data_start:] if len(out) > new_data_start \
        else out + data[old_data_start:]


# --- mutations -----------------------------------------------------------------------------------

@dataclass
class Base:
    data: bytes
    header: dict
    data_start: int
    nodes: int
    vertices: int
    tris: int


def base_of(data: bytes) -> Base:
    header, start = _header(data)
    arrays = header["arrays"]
    return Base(data=data, header=header, data_start=start, nodes=arrays["parent"]["shape"][0],
                vertices=arrays["positions"]["shape"][0], tris=arrays["indices"]["shape"][0])


def make_case(base: Base, seed: int, index: int) -> tuple[str, bytes]:
    """(description, bytes) of case `index`: one to three mutations, drawn from (seed, index) alone."""
    rng = np.random.default_rng([seed, index])
    kinds = [MUTATIONS[index % len(MUTATIONS)]]  # every kind equally often; extras at random
    kinds += [_pick(rng, MUTATIONS) for _ in range(_pick(rng, [0, 0, 0, 1, 2]))]
    kinds.sort(key=lambda k: k == "truncate")  # a cut comes last, so the others still find their bytes
    data, steps = base.data, []
    for kind in kinds:
        data, what = _MUTATORS[kind](base, data, rng)
        steps.append(f"{kind}: {what}")
    return "; ".join(steps), data


def _pick(rng, options):
    """One element of a Python sequence (rng.choice would turn large ints into floats)."""
    return options[int(rng.integers(len(options)))]


def _flip(base: Base, data: bytes, rng) -> tuple[bytes, str]:
    buf = bytearray(data)
    node_end = max(e["offset"] + e["nbytes"] for n, e in base.header["arrays"].items()
                   if n not in ("positions", "indices", "normals", "origin"))
    where = rng.choice(["header", "table", "anywhere"], p=[0.4, 0.4, 0.2])
    lo, hi = {"header": (0, _PREAMBLE.size + len(json.dumps(base.header))),
              "table": (base.data_start, node_end), "anywhere": (0, len(buf))}[str(where)]
    spots = rng.integers(lo, min(hi, len(buf)), size=int(rng.integers(1, 9)))
    for spot in spots:
        buf[spot] ^= int(rng.integers(1, 256))
    return bytes(buf), f"{len(spots)} byte(s) flipped in the {where} at {sorted(int(s) for s in spots)[:8]}"


def _truncate(base: Base, data: bytes, rng) -> tuple[bytes, str]:
    keep = int(rng.integers(0, len(data)))
    return data[:keep], f"cut to {keep} of {len(data)} bytes"


_HOSTILE_NUMBERS = [-1, 0, 1, 3, 63, 64, 2**31 - 1, 2**31, 2**32, 2**53 + 1, 2**62, 2**63 - 1, 2**63, 2**64,
                    10**30, 10**4000, 1.5, -0.0, 1e308]
_HOSTILE_RAW = ["Infinity", "-Infinity", "NaN", "1e999", "-1e999", "[" * 200 + "]" * 200, "[" * 5000 + "]" * 5000,
                '"' + '\\"' * 3000 + '"']
_HOSTILE_OTHER = [None, True, False, "12", "", [], {}, [1, 2], {"a": 1}]
_DTYPES = [">f8", ">i8", "<f4", "<f8", "<i4", "<i8", "<u4", "O", "V8", "U4", "S1", "|b1", "<c16", "<M8", "float64",
           "", [["a", "<f8"]], {"names": ["a"], "formats": ["<f8"]}]


def _hostile_value(rng) -> tuple[object, list[str]]:
    """(value or placeholder, raw texts) for a header field."""
    pool = rng.choice(["number", "raw", "other"], p=[0.5, 0.25, 0.25])
    if pool == "number":
        return _pick(rng, _HOSTILE_NUMBERS), []
    if pool == "raw":
        return _RAW.format(0), [_pick(rng, _HOSTILE_RAW)]
    return _pick(rng, _HOSTILE_OTHER), []


def _header_mutation(base: Base, data: bytes, rng) -> tuple[bytes, str]:
    header = json.loads(json.dumps(base.header))
    arrays = header["arrays"]
    name = _pick(rng, sorted(arrays) + ["(new)"])
    field = _pick(rng, ["dtype", "shape", "offset", "nbytes", "entry", "preamble"])
    raw: list[str] = []
    if name == "(new)":
        extra = _pick(rng, ["uvs", "two\nlines", "x" * 300])  # refused in one line, name shortened
        arrays[extra] = dict(arrays["positions"])
        what = f"unknown array {extra[:20]!r} added"
    elif field == "dtype" and rng.uniform() < 0.7:
        arrays[name]["dtype"] = _pick(rng, _DTYPES)
        what = f"{name}.dtype = {arrays[name]['dtype']!r}"
    elif field == "shape" and rng.uniform() < 0.7:
        shape = list(arrays[name]["shape"])
        choice = int(rng.integers(5))
        if choice == 0:  # product wraps int64, nbytes set to the wrapped product
            shape = [2**33, 2**31] + shape[1:]
        elif choice == 1:
            shape = shape + [1]
        elif choice == 2:
            shape = shape[:-1] if shape else [1]
        elif choice == 3:
            shape[0] = _pick(rng, [0, shape[0] - 1, shape[0] + 1, 2 * shape[0]])
        else:
            shape[int(rng.integers(len(shape)))], raw = _hostile_value(rng)
        arrays[name]["shape"] = shape
        what = f"{name}.shape = {json.dumps(shape)[:60]} {raw[0][:20] if raw else ''}"
    elif field in ("offset", "nbytes") and rng.uniform() < 0.5:
        entry = arrays[name]
        entry[field] = _pick(rng, [0, 24, 64, entry[field] - 64, entry[field] + 64, entry[field] + 1,
                                   len(base.data), entry[field] + 2**64])
        what = f"{name}.{field} = {entry[field]}"
    elif field == "entry":
        arrays[name] = _pick(rng, _HOSTILE_OTHER)
        what = f"{name} entry = {json.dumps(arrays[name])}"
    elif field == "preamble":
        length = _pick(rng, [0, 1, 2**63, 2**64 - 1, 64 * 1024 * 1024 + 1, len(base.data)])
        buf = bytearray(data)
        struct.pack_into("<Q", buf, 16, length)
        return bytes(buf), f"header length = {length}"
    else:
        key = field if field != "entry" else "dtype"
        arrays[name][key], raw = _hostile_value(rng)
        what = f"{name}.{key} = {raw[0][:20] if raw else json.dumps(arrays[name][key])[:40]}"
    return _mutated_header(base, data, header=header, raw=raw), what


def _meta_mutation(base: Base, data: bytes, rng) -> tuple[bytes, str]:
    header = json.loads(json.dumps(base.header))
    raw: list[str] = []
    choice = int(rng.integers(4))
    if choice == 0:
        header["meta"] = _pick(rng, _HOSTILE_OTHER)
        what = f"meta = {json.dumps(header['meta'])}"
    elif choice == 1:
        del header[_pick(rng, ["meta", "arrays"])]
        what = f"header keys left: {sorted(header)}"
    else:
        key = _pick(rng, ["input_tris", "target_tris", "max_depth", "input_vertices", "bake_seconds",
                              "phase_seconds", "sources", "log", "leaves_over_budget", "settings"])
        header["meta"][key], raw = _hostile_value(rng)
        what = f"meta.{key} = {raw[0][:20] if raw else json.dumps(header['meta'][key])[:40]}"
    return _mutated_header(base, data, header=header, raw=raw), what


def _mutated_header(base: Base, data: bytes, *, header: dict, raw: list[str]) -> bytes:
    return _with_header(data, header, old_data_start=base.data_start, new_data_start=base.data_start, raw=raw)


def _int_values(base: Base, bits: int) -> list[int]:
    n, t, v = base.nodes, base.tris, base.vertices
    common = [-1, 0, 1, n - 1, n, n + 1, t - 1, t, t + 1, v - 1, v, v + 1, 2**31 - 1, -2**31]
    return common + ([2**32, 2**62, 2**63 - 1, -2**63, _WRAP_OFFSET] if bits == 64 else [])


_FLOAT_VALUES = [np.nan, np.inf, -np.inf, -1.0, 0.0, -0.0, 1e-300, 1e300, 3.5e38, 1e38, -1e300, 5e-324]


def _node_value(base: Base, data: bytes, rng) -> tuple[bytes, str]:
    arrays = base.header["arrays"]
    name = _pick(rng, sorted(arrays))
    entry = arrays[name]
    dtype = np.dtype(entry["dtype"])
    count = entry["nbytes"] // dtype.itemsize
    if count == 0:
        return data, f"{name} is empty, unchanged"
    element = int(rng.integers(count))
    if dtype.kind == "f":
        value = _pick(rng, _FLOAT_VALUES)
    elif dtype.kind == "u":
        value = _pick(rng, [base.vertices - 1, base.vertices, base.vertices + 1, 2**31, 2**32 - 1])
    else:
        values = _int_values(base, dtype.itemsize * 8)
        value = _pick(rng, values)
    return _poke(data, entry, element=element, value=value), f"{name}[{element}] = {value}"


def _poke(data: bytes, entry: dict, *, element: int, value) -> bytes:
    dtype = np.dtype(entry["dtype"])
    buf = bytearray(data)
    cell = np.frombuffer(buf, dtype=dtype, count=1, offset=entry["offset"] + element * dtype.itemsize)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cell[0] = np.array(value).astype(dtype) if dtype.kind == "f" else value
    return bytes(buf)


def _overflow(base: Base, data: bytes, rng) -> tuple[bytes, str]:
    """Range pairs whose int64 (or int32) sum wraps: the reader must compare without overflow."""
    a = base.header["arrays"]
    node = int(rng.integers(base.nodes))
    pairs = {
        "tri_wrap": ("tri_offset", _WRAP_OFFSET, "tri_count", _WRAP_OFFSET + 10**7),
        "tri_max": ("tri_offset", 2**63 - 1, "tri_count", 2),
        "tri_neg": ("tri_offset", 10, "tri_count", -2**63),
        "vertex_max": ("vertex_offset", 2**63 - 1, "vertex_count", 2**63 - 1),
        "vertex_count_max": ("vertex_offset", 0, "vertex_count", 2**63 - 1),
        "vertex_wrap": ("vertex_offset", _WRAP_OFFSET, "vertex_count", _WRAP_OFFSET + 10**7),
        "child_wrap": ("child_offset", 2**31 - 1, "child_count", 1),
        "child_count_max": ("child_offset", 1, "child_count", 2**31 - 1),
        "depth_wrap": ("depth", 2**31 - 1, "depth", -2**31),
    }
    label = _pick(rng, sorted(pairs))
    first, v1, second, v2 = pairs[label]
    data = _poke(data, a[first], element=node, value=v1)
    other = min(node + 1, base.nodes - 1) if first == second else node
    data = _poke(data, a[second], element=other, value=v2)
    return data, f"{label} at node {node}: {first}={v1}, {second}[{other}]={v2}"


def _geometry(base: Base, data: bytes, rng) -> tuple[bytes, str]:
    """Values the reader accepts (it does not read the geometry): what the renderer must survive."""
    arrays = base.header["arrays"]
    steps = []
    for _ in range(int(rng.integers(1, 9))):
        name = _pick(rng, [n for n in ("positions", "normals", "indices") if n in arrays])
        entry = arrays[name]
        element = int(rng.integers(entry["nbytes"] // np.dtype(entry["dtype"]).itemsize))
        value = _pick(rng, _FLOAT_VALUES) if name != "indices" else int(rng.integers(base.vertices))
        data = _poke(data, entry, element=element, value=value)
        steps.append(f"{name}[{element}] = {value}")
    return data, ", ".join(steps)


def _bounds(base: Base, data: bytes, rng) -> tuple[bytes, str]:
    """Finite extremes in the node table's floats (boxes, spheres, errors, cube sides, origin):
    mostly accepted, so the traversal's arithmetic meets them."""
    arrays = base.header["arrays"]
    name = _pick(rng, ["lod_box_min", "lod_box_max", "box_min", "box_max", "sphere_center", "sphere_radius",
                       "error", "cube_side", "origin"])
    entry = arrays[name]
    count = entry["nbytes"] // 8
    element = int(rng.integers(count))
    value = _pick(rng, [0.0, -0.0, 5e-324, 1e-300, 1e-9, 1e9, 1e150, 1e300, 1.7976931348623157e308, -1e300])
    if name.endswith("_max") or name in ("sphere_radius", "error", "cube_side"):
        value = abs(value)
    if rng.uniform() < 0.3:  # the whole column: every node, or one coordinate of every node
        step = 3 if name not in ("sphere_radius", "error", "cube_side") else 1
        for k in range(element % step, count, step):
            data = _poke(data, entry, element=k, value=value)
        return data, f"{name}[every {step}th from {element % step}] = {value}"
    return _poke(data, entry, element=element, value=value), f"{name}[{element}] = {value}"


_MUTATORS = {"flip": _flip, "truncate": _truncate, "header": _header_mutation, "meta": _meta_mutation,
             "node_value": _node_value, "overflow": _overflow, "geometry": _geometry, "bounds": _bounds}
