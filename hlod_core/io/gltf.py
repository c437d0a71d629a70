"""glTF 2.0 / GLB files read as scenes (glTF 2.0 spec 3.5, 3.7): every triangle primitive placed
by every node of the default scene.

Data form: a .gltf / .glb file in; `GltfScene` out: primitives (numpy arrays, each read once),
placements (primitive, (4,4) float64 world matrix, node name) and the material table
(gltf_materials.py); meshes.load_mesh turns it into one TriangleMesh. trimesh (a command-line
dependency, imported here only when a glTF file is read) decodes buffers, accessors and
primitives; the file's JSON gives the rest.

The default scene is `scene`, else the first; a file without scenes places every root node. A
node's world matrix is its `matrix`, or T * R * S, times its parents'. Primitives of modes
TRIANGLES and TRIANGLE_STRIP are read: POSITION, NORMAL, TEXCOORD_0 in Blender/OpenGL convention
(trimesh already stores 1 - v), COLOR_0 (linear; normalized integers divided by their maximum;
RGB gets alpha 1) and the material index. Every world matrix is preceded by Y_UP_TO_Z_UP, glTF's
+Y up to Blender's +Z up (why: docs/how-it-works.md#gltf-scenes-are-turned-z-up). A malformed file:
InputError naming the file and the part at fault.

Extensions: a node with EXT_mesh_gpu_instancing places its mesh once per instance (the instance's
T * R * S, then the node's world matrix). A file that requires an extension outside READ_EXTENSIONS
and APPEARANCE_EXTENSIONS is refused in one line naming it; one that uses such an extension
without requiring it is read with a warning naming it (its geometry, if it has any, is left out).
"""
from __future__ import annotations

import importlib.util
import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..model.appearance import Material
from .gltf_accessors import read_accessor
from .gltf_codes import (
    GLB_CHUNK,
    GLB_HEADER,
    GLB_MAGIC,
    GLB_VERSION,
    Y_UP_TO_Z_UP,
    ChunkType,
    ComponentType,
    PrimitiveMode,
)
from .gltf_materials import read_materials

log = logging.getLogger(__name__)

#: Primitive modes trimesh keeps (in order with the others) and those that are triangles.
TRIMESH_MODES = (PrimitiveMode.POINTS, PrimitiveMode.LINES, PrimitiveMode.TRIANGLES, PrimitiveMode.TRIANGLE_STRIP)
TRIANGLE_MODES = (PrimitiveMode.TRIANGLES, PrimitiveMode.TRIANGLE_STRIP)
#: Deepest node hierarchy read (deeper is taken for a cycle).
MAX_NODE_DEPTH = 1024
#: Extensions that bear geometry and are read: instances (here), Draco (trimesh, with DracoPy).
READ_EXTENSIONS = frozenset({"EXT_mesh_gpu_instancing", "KHR_draco_mesh_compression"})
#: Extensions that change only how a surface looks: the bake's geometry is whole without them (the
#: material's base colour and texture are read as gltf_materials.py says).
APPEARANCE_EXTENSIONS = frozenset({
    "KHR_materials_emissive_strength", "KHR_materials_ior", "KHR_materials_specular", "KHR_materials_clearcoat",
    "KHR_materials_sheen", "KHR_materials_transmission", "KHR_materials_volume", "KHR_materials_iridescence",
    "KHR_materials_anisotropy", "KHR_materials_dispersion", "KHR_materials_unlit", "KHR_materials_variants",
    "KHR_materials_pbrSpecularGlossiness", "KHR_texture_transform", "KHR_texture_basisu", "EXT_texture_webp",
    "EXT_texture_avif", "KHR_lights_punctual", "KHR_animation_pointer", "KHR_xmp_json_ld"})
GPU_INSTANCING = "EXT_mesh_gpu_instancing"


@dataclass(frozen=True, eq=False)
class Primitive:
    """One triangle primitive of a glTF mesh: positions (v,3) float64, faces (f,3) int64,
    normals (v,3) float32 | None, uvs (v,2) float32 | None, colors (v,4) float32 | None,
    material: index into GltfScene.materials, or None (no material)."""

    positions: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None
    uvs: np.ndarray | None
    colors: np.ndarray | None
    material: int | None


@dataclass(frozen=True, eq=False)
class GltfScene:
    """primitives (read once each); placements: (primitive index, (4,4) float64 world matrix,
    node name) per placed copy; materials: the file's material table."""

    primitives: list[Primitive]
    placements: list[tuple[int, np.ndarray, str]]
    materials: tuple[Material, ...]


def read_gltf(path: Path, *, texture_dir: Path | None) -> GltfScene:
    """Read a .gltf or .glb file as a scene (see the module docstring)."""
    header, binary = _gltf_json(path)
    worlds = list(_world_matrices(path, header))  # the node tree checked here, before the decoder
    _check_extensions(path, header)
    gltf = _trimesh_gltf(path)
    try:
        with open(path, "rb") as stream:
            if path.suffix.lower() == ".glb":
                decoded = gltf.load_glb(stream)
            else:
                from trimesh.resolvers import FilePathResolver

                decoded = gltf.load_gltf(stream, resolver=FilePathResolver(str(path)))
    except (OSError, MemoryError):
        raise
    except Exception as exc:  # a malformed file fails anywhere inside the decoder
        raise InputError(f"{path}: not a readable glTF file ({type(exc).__name__}: {_short(exc)})") from exc
    mesh_primitives, primitives = _primitives(path, header, list(decoded["geometry"].values()))
    materials = read_materials(path, header, binary=binary, texture_dir=texture_dir)
    placements = []
    for node, world in worlds:
        mesh = header["nodes"][node].get("mesh")
        if mesh is None:
            continue
        if not isinstance(mesh, int) or not 0 <= mesh < len(mesh_primitives):
            raise InputError(f"{path}: nodes[{node}].mesh {mesh!r} is not a mesh of the file")
        name = str(header["nodes"][node].get("name", f"node {node}"))
        instances = _gpu_instances(path, header, binary, node)
        if instances is None:
            placements.extend((index, Y_UP_TO_Z_UP @ world, name) for index in mesh_primitives[mesh])
        else:
            placements.extend((index, Y_UP_TO_Z_UP @ world @ local, f"{name} #{k}")
                               for k, local in enumerate(instances) for index in mesh_primitives[mesh])
    if not placements:
        raise InputError(f"{path}: the default scene places no triangles")
    return GltfScene(primitives=primitives, placements=placements, materials=materials)


def _check_extensions(path: Path, header: dict) -> None:
    """Refuse geometry compression the decoder cannot undo (it would read placeholder zeros);
    warn about extensions whose effect is left out."""
    prims = [p for m in header.get("meshes", []) if isinstance(m, dict) for p in m.get("primitives", [])
             if isinstance(p, dict)]
    if any("KHR_draco_mesh_compression" in (p.get("extensions") or {}) for p in prims):
        if importlib.util.find_spec("DracoPy") is None:  # trimesh's Draco decoder needs it
            raise InputError(f"{path}: Draco-compressed meshes (KHR_draco_mesh_compression) need the DracoPy "
                             "package, which is not installed")
    if any("EXT_meshopt_compression" in (v.get("extensions") or {}) for v in header.get("bufferViews", [])
           if isinstance(v, dict)):
        raise InputError(f"{path}: meshopt-compressed buffers (EXT_meshopt_compression) are not read; "
                         "decompress the file first")
    used = {str(name) for name in header.get("extensionsUsed", []) or []}
    required = {str(name) for name in header.get("extensionsRequired", []) or []}
    unread = sorted(name for name in required if name not in READ_EXTENSIONS and name not in APPEARANCE_EXTENSIONS)
    if unread:
        raise InputError(f"{path}: requires {', '.join(unread)}, which this reader does not read")
    if "KHR_texture_transform" in used:
        log.warning("%s: uses KHR_texture_transform; texture transforms are not applied", path)
    unknown = sorted(name for name in used - required if name not in READ_EXTENSIONS
                     and name not in APPEARANCE_EXTENSIONS)
    if unknown:
        log.warning("%s: uses %s, which this reader does not read; where it changes geometry, the bake "
                    "leaves that out", path, ", ".join(unknown))


def _gpu_instances(path: Path, header: dict, binary: bytes | None, node: int) -> list[np.ndarray] | None:
    """The (4,4) local matrices T * R * S of a node's EXT_mesh_gpu_instancing instances, each
    applied before the node's world matrix (its mesh drawn once per instance); None for a node
    without the extension. Attributes left out default to no translation, no rotation, scale 1."""
    extension = (header["nodes"][node].get("extensions") or {}).get(GPU_INSTANCING)
    if extension is None:
        return None
    where = f"nodes[{node}].extensions.{GPU_INSTANCING}.attributes"
    attributes = extension.get("attributes") if isinstance(extension, dict) else None
    if not isinstance(attributes, dict) or not attributes:
        raise InputError(f"{path}: {where} must name at least one of TRANSLATION, ROTATION and SCALE")
    shapes = {"TRANSLATION": 3, "ROTATION": 4, "SCALE": 3}
    values = {}
    for key, width in shapes.items():
        if key in attributes:
            values[key] = read_accessor(path, header, binary, index=attributes[key], what=f"{where}.{key}")
            if values[key].shape[1] != width:
                raise InputError(f"{path}: {where}.{key} must be VEC{width}")
    counts = {value.shape[0] for value in values.values()}
    if len(counts) != 1:
        raise InputError(f"{path}: {where} give different instance counts ({sorted(counts)})")
    (count,) = counts
    return list(_trs_matrices(values.get("TRANSLATION", np.zeros((count, 3))),
                              values.get("ROTATION", np.tile([0.0, 0.0, 0.0, 1.0], (count, 1))),
                              values.get("SCALE", np.ones((count, 3))), where=f"{path}: {where}.ROTATION"))


def _trimesh_gltf(path: Path):
    """trimesh's glTF decoder; InputError naming the file when trimesh is not installed."""
    try:
        from trimesh.exchange import gltf
    except ImportError as exc:
        raise InputError(f"{path}: reading glTF needs trimesh, a dependency of the command line "
                         "(pip install -r requirements.txt)") from exc
    return gltf


def _short(exc: Exception) -> str:
    """An exception's message on one line, at most 200 characters."""
    return " ".join(str(exc).split())[:200]


def _gltf_json(path: Path) -> tuple[dict, bytes | None]:
    """(the JSON header, the GLB's BIN chunk or None); InputError for a malformed container."""
    data = path.read_bytes()
    binary = None
    if path.suffix.lower() == ".glb":
        if len(data) < GLB_HEADER.size + GLB_CHUNK.size:
            raise InputError(f"{path}: not a GLB file ({len(data)} bytes)")
        magic, version, length = GLB_HEADER.unpack_from(data)
        if magic != GLB_MAGIC or version != GLB_VERSION:
            raise InputError(f"{path}: not a glTF 2.0 GLB file (magic {magic!r}, version {version})")
        if length > len(data):
            raise InputError(f"{path}: truncated GLB file (header says {length} bytes, file has {len(data)})")
        chunks, at = [], GLB_HEADER.size
        while at + GLB_CHUNK.size <= length:
            size, kind = GLB_CHUNK.unpack_from(data, at)
            if at + GLB_CHUNK.size + size > length:
                raise InputError(f"{path}: truncated GLB chunk at byte {at}")
            chunks.append((kind, data[at + GLB_CHUNK.size:at + GLB_CHUNK.size + size]))
            at += GLB_CHUNK.size + size
        if not chunks or chunks[0][0] != ChunkType.JSON:
            raise InputError(f"{path}: a GLB file must start with a JSON chunk")
        text = chunks[0][1]
        binary = next((c for kind, c in chunks[1:] if kind == ChunkType.BIN), None)
    else:
        text = data
    try:
        header = json.loads(text)
    except (UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"{path}: the glTF JSON cannot be read ({_short(exc)})") from None
    if not isinstance(header, dict):
        raise InputError(f"{path}: the glTF JSON is not an object")
    version = str((header.get("asset") or {}).get("version", ""))
    if not version.startswith("2"):
        raise InputError(f"{path}: glTF version {version or '(none)'}; only glTF 2.0 is read")
    for key in ("nodes", "meshes", "materials", "textures", "images", "scenes", "accessors", "bufferViews"):
        if not isinstance(header.get(key, []), list):
            raise InputError(f"{path}: glTF \"{key}\" must be a list")
    return header, binary


def _primitives(path: Path, header: dict, decoded: list[dict]) -> tuple[list[list[int]], list[Primitive]]:
    """(per mesh: indices into the primitive list, primitives). trimesh's geometry comes in the
    file's order of (mesh, primitive) over the modes it keeps (points, lines, triangles, strips);
    each triangle primitive's vertices are checked against its POSITION accessor's count."""
    accessors = header.get("accessors", [])
    per_mesh, out = [], []
    k = 0
    for i, mesh in enumerate(header.get("meshes", [])):
        prims = mesh.get("primitives") if isinstance(mesh, dict) else None
        if not isinstance(prims, list):
            raise InputError(f"{path}: meshes[{i}] has no \"primitives\" list")
        mine = []
        for j, prim in enumerate(prims):
            mode = prim.get("mode", PrimitiveMode.TRIANGLES) if isinstance(prim, dict) else None
            if mode == PrimitiveMode.TRIANGLE_FAN:
                raise InputError(f"{path}: meshes[{i}].primitives[{j}] is a triangle fan (mode 6), which is not read")
            if mode not in TRIMESH_MODES:
                continue  # line loops and strips: no triangles, and trimesh keeps none
            if k >= len(decoded):
                raise InputError(f"{path}: meshes[{i}].primitives[{j}] could not be decoded")
            kwargs, k = decoded[k], k + 1
            if mode not in TRIANGLE_MODES:
                continue
            where = f"{path}: meshes[{i}].primitives[{j}]"
            position = prim.get("attributes", {}).get("POSITION")
            inside = isinstance(position, int) and 0 <= position < len(accessors)
            count = accessors[position].get("count") if inside else None
            vertices = np.asarray(kwargs.get("vertices"))
            if count is None or vertices.shape != (count, 3):
                raise InputError(f"{where}: POSITION does not hold {count} 3D vertices")
            texcoord = prim.get("attributes", {}).get("TEXCOORD_0")
            texcoord_type = accessors[texcoord].get("componentType") \
                if isinstance(texcoord, int) and 0 <= texcoord < len(accessors) else None
            mine.append(len(out))
            out.append(_primitive(where, kwargs, prim, materials=len(header.get("materials", [])),
                                  texcoord_type=texcoord_type))
        per_mesh.append(mine)
    return per_mesh, out


def _primitive(where: str, kwargs: dict, prim: dict, *, materials: int, texcoord_type) -> Primitive:
    """One primitive's arrays from trimesh's decoding (`texcoord_type`: TEXCOORD_0's component type)."""
    positions = np.asarray(kwargs["vertices"], np.float64)
    faces = np.asarray(kwargs.get("faces"), np.int64).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= positions.shape[0]):
        raise InputError(f"{where}: an index is outside the {positions.shape[0]} vertices")
    normals = kwargs.get("vertex_normals")
    if normals is not None:
        normals = np.asarray(normals, np.float32)
        normals = normals if normals.shape == positions.shape else None
    visual = kwargs.get("visual")
    uvs = getattr(visual, "uv", None)
    if uvs is not None and texcoord_type not in (None, ComponentType.FLOAT):
        log.warning("%s: TEXCOORD_0 is quantized (component type %s), which is not read; no UVs", where,
                    texcoord_type)
        uvs = None
    if uvs is not None:
        uvs = np.asarray(uvs, np.float32)
        if uvs.shape != (positions.shape[0], 2):
            raise InputError(f"{where}: TEXCOORD_0 has shape {list(uvs.shape)}, expected ({positions.shape[0]}, 2)")
    colors = kwargs.get("vertex_colors")
    if visual is not None and "color" in getattr(visual, "vertex_attributes", {}):
        colors = visual.vertex_attributes["color"]
    if colors is not None:
        colors = _unit_values(np.asarray(colors)).astype(np.float32)
        if colors.ndim != 2 or colors.shape[0] != positions.shape[0] or colors.shape[1] not in (3, 4):
            raise InputError(f"{where}: COLOR_0 has shape {list(colors.shape)}")
        if colors.shape[1] == 3:
            colors = np.concatenate([colors, np.ones((colors.shape[0], 1), np.float32)], axis=1)
    material = prim.get("material")
    if material is not None and (not isinstance(material, int) or not 0 <= material < materials):
        raise InputError(f"{where}: material {material!r} is not one of the file's {materials} materials")
    return Primitive(positions=positions, faces=faces, normals=normals, uvs=uvs, colors=colors, material=material)


def _unit_values(values: np.ndarray) -> np.ndarray:
    """Normalized integer accessor values (trimesh returns them raw) to floats: unsigned c / max,
    signed max(c / max, -1), as glTF defines them; floats unchanged."""
    if np.issubdtype(values.dtype, np.integer):
        top = float(np.iinfo(values.dtype).max)
        return np.maximum(values.astype(np.float64) / top, -1.0)
    return values.astype(np.float64)


def _world_matrices(path: Path, header: dict):
    """(node index, (4,4) world matrix) of every node of the default scene, parents first."""
    nodes = header.get("nodes", [])
    scenes = header.get("scenes", [])
    if scenes:
        index = header.get("scene", 0)
        if not isinstance(index, int) or not 0 <= index < len(scenes) or not isinstance(scenes[index], dict):
            raise InputError(f"{path}: \"scene\" {index!r} is not one of the {len(scenes)} scenes")
        roots = scenes[index].get("nodes", [])
    else:  # no scene: every node that is no node's child
        children = {c for n in nodes if isinstance(n, dict) for c in n.get("children", [])}
        roots = [i for i in range(len(nodes)) if i not in children]
    stack = [(root, np.eye(4), 0) for root in reversed(roots)]
    while stack:
        node, parent, depth = stack.pop()
        if not isinstance(node, int) or not 0 <= node < len(nodes) or not isinstance(nodes[node], dict):
            raise InputError(f"{path}: node {node!r} is not one of the file's {len(nodes)} nodes")
        if depth > MAX_NODE_DEPTH:
            raise InputError(f"{path}: the node hierarchy is deeper than {MAX_NODE_DEPTH} (a cycle?) at node {node}")
        world = parent @ _local_matrix(path, node, nodes[node])
        yield node, world
        children = nodes[node].get("children", [])
        if not isinstance(children, list):
            raise InputError(f"{path}: nodes[{node}].children must be a list")
        stack.extend((child, world, depth + 1) for child in reversed(children))


def _local_matrix(path: Path, index: int, node: dict) -> np.ndarray:
    """A node's matrix (16 numbers, column-major) or T * R * S (rotation a unit quaternion x, y, z, w)."""
    def numbers(key: str, size: int, default) -> np.ndarray:
        value = node.get(key, default)
        try:
            out = np.asarray(value, np.float64)
        except (TypeError, ValueError):
            out = np.zeros(0)
        if out.shape != (size,) or not np.all(np.isfinite(out)):
            raise InputError(f"{path}: nodes[{index}].{key} must be {size} finite numbers")
        return out

    if "matrix" in node:
        return numbers("matrix", 16, None).reshape(4, 4).T
    t = numbers("translation", 3, (0.0, 0.0, 0.0))
    q = numbers("rotation", 4, (0.0, 0.0, 0.0, 1.0))
    s = numbers("scale", 3, (1.0, 1.0, 1.0))
    return _trs_matrices(t[None], q[None], s[None], where=f"{path}: nodes[{index}].rotation")[0]


def _trs_matrices(t: np.ndarray, q: np.ndarray, s: np.ndarray, *, where: str) -> np.ndarray:
    """(k,4,4) matrices T * R * S of k translations (k,3), rotations (k,4) as quaternions x, y, z,
    w (normalised here) and scales (k,3); InputError `where` for a zero quaternion."""
    norm = np.sqrt(q[:, 0] * q[:, 0] + q[:, 1] * q[:, 1] + q[:, 2] * q[:, 2] + q[:, 3] * q[:, 3])
    zero = np.flatnonzero(norm == 0)
    if zero.size:
        raise InputError(f"{where} is a zero quaternion" + (f" (instance {zero[0]})" if q.shape[0] > 1 else ""))
    x, y, z, w = (q[:, i] / norm for i in range(4))
    m = np.zeros((q.shape[0], 4, 4))
    m[:, 0, 0], m[:, 0, 1], m[:, 0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)
    m[:, 1, 0], m[:, 1, 1], m[:, 1, 2] = 2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)
    m[:, 2, 0], m[:, 2, 1], m[:, 2, 2] = 2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)
    m[:, :3, :3] *= s[:, None, :]  # R @ diag(s)
    m[:, :3, 3] = t
    m[:, 3, 3] = 1.0
    return m
