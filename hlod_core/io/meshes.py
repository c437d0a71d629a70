"""Bake input: triangle meshes as numpy arrays, read from mesh files or scene specs, merged into one.

Data form: `TriangleMesh` = positions (v,3) float64 model units, faces (f,3) int64 rows of
positions, optional normals (v,3) float32, and optional appearance (model/appearance.py): uvs (v,2)
float32, colors (v,4) float32 linear RGBA, material_ids (f,) int32 rows of `materials`. Several
meshes merge into one scene by concatenation (material tables appended, ids shifted).

A scene spec is a JSON file
    {"models": [{"path": "relative/or/absolute.obj",
                 "transforms": [[16 numbers, row-major 4x4], ...]}]}
Every transform places one instance, baked as its own geometry; paths are relative to the JSON
file; a model without "transforms" is placed once, untransformed. A transform must be affine and
invertible (a singular one would flatten every triangle).

Readers: STL in stl.py; OBJ checked (or, with a material library, read) in obj.py, its MTL in
mtl.py; glTF/GLB scenes in gltf.py; the rest by pymeshlab. PLY vertex colours are decoded from sRGB
(docs/how-it-works.md#colours-in-the-renderer-linear-in-srgb-out). Other files carry no appearance.
"""
from __future__ import annotations

import dataclasses
import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import jsonutil
from ..core.arrays import concat_indexed
from ..core.colour import srgb_to_linear
from ..core.errors import InputError
from ..model.appearance import DEFAULT_BASE_COLOR, Material, check_material_ids, check_vertex_attributes
from . import gltf, mtl, obj, stl

log = logging.getLogger(__name__)

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
GLTF_SUFFIXES = (".glb", ".gltf")

#: A scene transform whose linear part has |det| <= SINGULAR_TRANSFORM_RATIO * (product of its
#: row lengths) flattens space (Hadamard: the ratio is 1 for orthogonal rows, 0 for singular ones);
#: unit-free, so a millimetre scale (det 1e-9) is fine and a projection (det ~1e-17) is not.
SINGULAR_TRANSFORM_RATIO = 1e-12


@dataclass(frozen=True, eq=False)
class TriangleMesh:
    """positions (v,3) float64; faces (f,3) int64; normals (v,3) float32 or None; name for messages;
    appearance (all optional, see model/appearance.py): uvs (v,2) float32, colors (v,4) float32,
    material_ids (f,) int32 into `materials` (a tuple of appearance.Material)."""

    positions: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None = None
    name: str = "mesh"
    uvs: np.ndarray | None = None
    colors: np.ndarray | None = None
    material_ids: np.ndarray | None = None
    materials: tuple = ()

    @property
    def tri_count(self) -> int:
        return int(self.faces.shape[0])

    @property
    def has_appearance(self) -> bool:
        return self.uvs is not None or self.colors is not None or self.material_ids is not None


def from_arrays(positions, faces, normals=None, *, name: str = "mesh", uvs=None, colors=None,
                material_ids=None, materials=()) -> TriangleMesh:
    """Validate and wrap caller arrays (appearance: see TriangleMesh). Raises InputError naming `name`."""
    try:
        p = np.asarray(positions, dtype=np.float64)
        f = np.asarray(faces)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: positions/faces are not numeric arrays ({exc})") from exc
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"{name}: positions must have shape (v, 3), got {list(p.shape)}")
    if f.size == 0:
        raise InputError(f"{name}: the mesh has no triangles")
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise InputError(f"{name}: faces must be integer triangles of shape (f, 3), got {f.dtype}{list(f.shape)}")
    f = f.astype(np.int64, copy=False)
    if f.min() < 0 or f.max() >= p.shape[0]:
        raise InputError(f"{name}: a face refers to a vertex outside 0..{p.shape[0] - 1}")
    used = np.zeros(p.shape[0], bool)
    used[f.ravel()] = True
    bad = used & ~np.all(np.isfinite(p), axis=1)
    if bad.any():
        raise InputError(f"{name}: {int(bad.sum())} vertices used by faces have NaN or infinite coordinates "
                         f"(first: vertex {int(np.flatnonzero(bad)[0])})")
    n = None
    if normals is not None:
        n = np.asarray(normals, dtype=np.float32)
        if n.shape != p.shape:
            raise InputError(f"{name}: normals must have the shape of positions {list(p.shape)}, got {list(n.shape)}")
        n = np.where(np.isfinite(n), n, 0.0).astype(np.float32)
    uv, col = check_vertex_attributes(name, p.shape[0], uvs=uvs, colors=colors)
    materials = tuple(materials)
    if not all(isinstance(m, Material) for m in materials):
        raise InputError(f"{name}: materials must be appearance.Material rows")
    ids = check_material_ids(name, f.shape[0], material_ids=material_ids, materials=materials)
    return TriangleMesh(positions=p, faces=f, normals=n, name=name, uvs=uv, colors=col, material_ids=ids,
                        materials=materials)


def load_mesh(path: str | os.PathLike, *, texture_dir: str | os.PathLike | None = None) -> TriangleMesh:
    """Read a mesh file: STL (stl.py); glTF/GLB as a scene with its materials, UVs and colours
    (gltf.py), and an OBJ with a material library with its materials and UVs (obj.py, mtl.py); the rest
    through pymeshlab (polygons are triangulated by the reader, OBJ text validated first; PLY
    vertex colours kept). Images embedded in a glTF file are written into `texture_dir` (made
    when needed; None: such textures are left out, with a warning). Raises InputError naming the
    file (and line) at fault."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise InputError(f"{path}: unsupported file type '{path.suffix}' (expected one of {', '.join(MESH_SUFFIXES)} "
                         "or a .json scene spec)")
    if suffix == ".stl":
        positions, faces = stl.read_stl(path)
        return from_arrays(positions, faces, name=str(path))
    if suffix in GLTF_SUFFIXES:
        return _load_gltf(path, texture_dir)
    data = path.read_bytes() if suffix == ".obj" else None
    if data is not None and obj.obj_has_appearance(data):
        return _load_obj(path, data)
    declared = obj.check_obj(path, data) if data is not None else None
    import pymeshlab

    ms = pymeshlab.MeshSet()
    try:
        ms.load_new_mesh(str(path))
    except pymeshlab.PyMeshLabException as exc:
        raise InputError(f"{path}: cannot read mesh ({_one_line(str(exc)) or type(exc).__name__})") from exc
    m = ms.current_mesh()
    if declared is not None:
        vertices, tris = declared
        if m.vertex_number() < vertices:  # check_obj read them all: pymeshlab should have too
            raise InputError(f"{path}: {vertices - m.vertex_number()} of {vertices} vertices could not be read")
        _warn_dropped(path, tris - m.face_number(), tris)
    colors = None
    if suffix == ".ply" and m.has_vertex_color():
        colors = srgb_to_linear(m.vertex_color_matrix())
    return from_arrays(m.vertex_matrix(), m.face_matrix(), name=str(path), colors=colors)


def _warn_dropped(path: Path, dropped: int, tris: int) -> None:
    if dropped > 0:
        log.warning("%s: the reader dropped %d of %d triangles (degenerate faces, such as ones that "
                    "repeat a vertex)", path, dropped, tris)


def _load_gltf(path: Path, texture_dir) -> TriangleMesh:
    """A glTF scene: each primitive read once, placed once per node that uses it (transform_mesh:
    a mirroring node flips the winding), all merged into one mesh named after the file."""
    scene = gltf.read_gltf(path, texture_dir=None if texture_dir is None else Path(texture_dir))
    base: dict[int, TriangleMesh] = {}
    for i, prim in enumerate(scene.primitives):
        if prim.faces.shape[0] == 0:
            continue
        material = () if prim.material is None else (scene.materials[prim.material],)
        base[i] = from_arrays(prim.positions, prim.faces, prim.normals, name=f"{path}: primitive {i}", uvs=prim.uvs,
                              colors=prim.colors, materials=material,
                              material_ids=np.zeros(prim.faces.shape[0], np.int32) if material else None)
    placed = []
    for index, world, node in scene.placements:
        if index not in base:
            continue
        with np.errstate(over="ignore", invalid="ignore"):
            mesh = transform_mesh(base[index], world, name=f"{path}: node {node}")
        if not np.all(np.isfinite(mesh.positions[mesh.faces])):
            raise InputError(f"{path}: node {node}'s transform moves its mesh out of the floating-point range")
        placed.append(mesh)
    if not placed:
        raise InputError(f"{path}: the mesh has no triangles")
    return dataclasses.replace(merge(placed, name=str(path)), name=str(path))


def _load_obj(path: Path, data: bytes) -> TriangleMesh:
    """An OBJ with a material library: obj.read_obj, and its MTL (mtl.py)."""
    arrays = obj.read_obj(path, data)
    _warn_dropped(path, arrays.dropped, arrays.dropped + arrays.faces.shape[0])
    materials, ids = (), None
    if arrays.material_names:
        materials = mtl.obj_materials(path, arrays.mtllibs, arrays.material_names)
        ids = arrays.face_group
        if (ids < 0).any():  # faces above the first usemtl
            ids = np.where(ids < 0, len(materials), ids)
            materials = materials + (Material("default", DEFAULT_BASE_COLOR),)
    return from_arrays(arrays.positions, arrays.faces, arrays.normals, name=str(path), uvs=arrays.uvs,
                       material_ids=ids, materials=materials)


def _one_line(message: str) -> str:
    """pymeshlab's messages span several lines; keep the details, on one line."""
    details = message.split("Error details:")[-1]
    return " ".join(details.split())


def transform_mesh(mesh: TriangleMesh, matrix: np.ndarray, *, name: str) -> TriangleMesh:
    """Apply a row-major 4x4 affine transform (float64); a mirroring transform flips the winding."""
    m = np.asarray(matrix, dtype=np.float64)
    p = mesh.positions @ m[:3, :3].T + m[:3, 3]
    faces = mesh.faces
    det = float(np.linalg.det(m[:3, :3]))
    if det < 0:
        faces = faces[:, ::-1].copy()
    normals = None
    if mesh.normals is not None and det != 0:
        nrm = mesh.normals.astype(np.float64) @ np.linalg.inv(m[:3, :3])
        length = np.linalg.norm(nrm, axis=1, keepdims=True)
        normals = (nrm / np.where(length > 0, length, 1.0)).astype(np.float32)
    return dataclasses.replace(mesh, positions=p, faces=faces, normals=normals, name=name)


def merge(meshes: list[TriangleMesh], *, name: str = "scene") -> TriangleMesh:
    """Concatenate meshes into one; normals kept only if every mesh has them. Appearance is kept if
    any mesh has it: a mesh without UVs gets (0, 0), without colours white, without materials a
    default material (one for all such meshes); material tables are appended, equal rows shared."""
    if not meshes:
        raise InputError(f"{name}: nothing to bake (no meshes)")
    if len(meshes) == 1:
        return meshes[0]
    positions, faces = concat_indexed((m.positions, m.faces) for m in meshes)
    normals = None
    if all(m.normals is not None for m in meshes):
        normals = np.concatenate([m.normals for m in meshes])
    uvs = colors = material_ids = None
    materials: tuple = ()
    if any(m.uvs is not None for m in meshes):
        uvs = np.concatenate([m.uvs if m.uvs is not None else np.zeros((m.positions.shape[0], 2), np.float32)
                              for m in meshes])
    if any(m.colors is not None for m in meshes):
        colors = np.concatenate([m.colors if m.colors is not None else np.ones((m.positions.shape[0], 4), np.float32)
                                 for m in meshes])
    if any(m.material_ids is not None for m in meshes):
        table: dict[Material, int] = {}
        ids = []
        for m in meshes:
            rows = m.materials if m.material_ids is not None else (Material("default", DEFAULT_BASE_COLOR),)
            remap = np.array([table.setdefault(row, len(table)) for row in rows], np.int32)
            ids.append(remap[m.material_ids] if m.material_ids is not None
                       else np.full(m.tri_count, remap[0], np.int32))
        material_ids = np.concatenate(ids)
        materials = tuple(table)
        check_material_ids(name, material_ids.shape[0], material_ids=material_ids, materials=materials)
    return TriangleMesh(positions=positions, faces=faces, normals=normals, name=name, uvs=uvs, colors=colors,
                        material_ids=material_ids, materials=materials)


def load_scene_spec(path: str | os.PathLike, *, texture_dir: str | os.PathLike | None = None) -> list[TriangleMesh]:
    """Read a JSON scene spec; one TriangleMesh per placed instance. Each model file is read once
    (texture_dir: see load_mesh)."""
    path = Path(path)
    cache: dict[Path, TriangleMesh] = {}
    out = []
    for i, (model_path, transforms) in enumerate(scene_spec_models(path)):
        if model_path not in cache:
            cache[model_path] = load_mesh(model_path, texture_dir=texture_dir)
        for j, matrix in enumerate(transforms):
            out.append(place(cache[model_path], matrix, name=f"{model_path}#{j}",
                             where=f"{path}: models[{i}].transforms[{j}]", what=model_path))
    return out


def scene_spec_models(path: str | os.PathLike) -> list[tuple[Path, list[np.ndarray]]]:
    """(model file, its checked (4,4) transforms) per model of a JSON scene spec, in order, the
    models not read (load_scene_spec reads them; an out-of-core bake streams them)."""
    path = Path(path)
    spec = jsonutil.read(path, what="scene spec")
    models = spec.get("models") if isinstance(spec, dict) else None
    if not isinstance(models, list) or not models:
        raise InputError(f"{path}: scene spec needs a non-empty list \"models\"")
    out = []
    for i, model in enumerate(models):
        if not isinstance(model, dict) or not isinstance(model.get("path"), str):
            raise InputError(f"{path}: models[{i}] needs a \"path\" string")
        model_path = Path(model["path"])
        if not model_path.is_absolute():
            model_path = (path.parent / model_path).resolve()
        if model_path.suffix.lower() == ".json":
            raise InputError(f"{path}: models[{i}] refers to another scene spec ({model_path}); "
                             "nesting is not supported")
        transforms = model.get("transforms", [np.eye(4).ravel().tolist()])
        if not isinstance(transforms, list) or not transforms:
            raise InputError(f"{path}: models[{i}].transforms must be a non-empty list of 16-number lists")
        out.append((model_path, [_parse_transform(path, t, model=i, row=j) for j, t in enumerate(transforms)]))
    return out


def place(mesh: TriangleMesh, matrix: np.ndarray, *, name: str, where: str, what) -> TriangleMesh:
    """transform_mesh(mesh, matrix), refused (InputError "{where} moves {what} out of the
    floating-point range") where it turns a finite coordinate infinite."""
    with np.errstate(over="ignore", invalid="ignore"):  # overflow is refused just below
        placed = transform_mesh(mesh, matrix, name=name)
    if np.any(~np.isfinite(placed.positions) & np.isfinite(mesh.positions)):
        raise InputError(f"{where} moves {what} out of the floating-point range (infinite coordinates)")
    return placed


def _parse_transform(spec: Path, t, *, model: int, row: int) -> np.ndarray:
    """Transform `row` of model `model` of the scene spec `spec`: a checked (4,4) float64 affine,
    invertible matrix; InputError naming where it stands otherwise."""
    where = f"{spec}: models[{model}].transforms[{row}]"
    try:
        m = np.asarray(t, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where} is not a list of numbers") from None
    if m.shape != (16,):
        raise InputError(f"{where} must have 16 numbers (row-major 4x4), got shape {list(m.shape)}")
    m = m.reshape(4, 4)
    if not np.all(np.isfinite(m)):
        raise InputError(f"{where} has NaN or infinite entries")
    if not np.allclose(m[3], [0, 0, 0, 1]):
        raise InputError(f"{where} is not affine (last row must be 0 0 0 1)")
    linear = m[:3, :3]
    largest = np.abs(linear).max(axis=1, keepdims=True)
    if np.all(largest > 0):  # compare scale-free: rows divided by their largest entry
        unit = linear / largest
        ratio = abs(np.linalg.det(unit)) / float(np.prod(np.linalg.norm(unit, axis=1)))
    else:
        ratio = 0.0
    if ratio <= SINGULAR_TRANSFORM_RATIO:
        raise InputError(f"{where} is singular (determinant {np.linalg.det(linear):.3g} of its 3x3 part): it "
                         "would flatten the model, every triangle to zero area")
    return m


def load_inputs(paths: list[str | os.PathLike], *, texture_dir: str | os.PathLike | None = None) -> TriangleMesh:
    """Read every INPUT (mesh file or scene spec) and merge them into one scene (texture_dir: the
    folder for images embedded in glTF files, see load_mesh)."""
    meshes: list[TriangleMesh] = []
    for p in paths:
        if Path(p).suffix.lower() == ".json":
            meshes.extend(load_scene_spec(p, texture_dir=texture_dir))
        else:
            meshes.append(load_mesh(p, texture_dir=texture_dir))
    log.info("loaded %d meshes, %d triangles", len(meshes), sum(m.tri_count for m in meshes))
    return merge(meshes, name=", ".join(str(p) for p in paths))
