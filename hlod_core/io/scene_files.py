"""Scene files with appearance (issue 13): glTF 2.0 / GLB scenes, an OBJ's MTL, PLY colours.

Data form: a file in, numpy arrays and an appearance.Material table out; meshio.load_mesh turns
them into one TriangleMesh (this module does not import meshio, which the Blender extension imports).

- glTF / GLB (`read_gltf`): trimesh (a command-line dependency, imported here only when a glTF
  file is read) decodes buffers, accessors and primitives; the file's JSON gives the rest. A glTF
  file is a scene: every node of the default scene (`scene`, else the first; a file without
  scenes: every root node) is placed with its world transform (its `matrix`, or T * R * S, times
  its parents'), every triangle primitive (modes TRIANGLES and TRIANGLE_STRIP) of its mesh once
  per node, in Blender's axes: glTF defines +Y up and +Z forward, so every world matrix is
  preceded by GLTF_TO_BLENDER, (x, y, z) -> (x, -z, y), the rotation Blender's glTF importer
  applies; a scene baked from its GLB then lies where the same scene baked in Blender does (and
  3D Tiles, which take model space as Z up, export it upright). OBJ, PLY, STL and OFF have no
  defined up axis and keep their file axes, as before.
  Per primitive: POSITION, NORMAL, TEXCOORD_0 in Blender/OpenGL convention (trimesh already
  stores 1 - v), COLOR_0 (linear, as glTF defines it; normalized integers divided by their
  maximum; RGB gets alpha 1) and the material: baseColorFactor (linear RGBA), metallicFactor,
  roughnessFactor (glTF's defaults 1, 1, 1) and baseColorTexture as an image file: an image
  given by URI is the file itself; one embedded in the file (a bufferView or a data: URI) is
  written once, with its original bytes, into the caller's texture folder as
  NAME-<sha256 prefix>.png/.jpg (content-named, so equal images are one file) and referenced
  there. No folder given: the texture is left out with a warning.
- OBJ: geometry in meshfiles.read_obj; its MTL here (`read_mtl`): Kd (linear RGB, as Blender
  reads and writes it), d (alpha; or 1 - Tr), Pr / Pm (roughness, metallic), else roughness from
  Ns as Blender's exporter writes it (Ns = 1000 (1 - roughness)^2), map_Kd (options skipped; path
  relative to the MTL). With map_Kd the base colour is white (Blender's importer ignores Kd then).
- PLY vertex colours (core.colour.srgb_to_linear): read by pymeshlab as 8-bit values over 255; taken as
  sRGB-encoded, as Blender's PLY importer takes them by default and as scanners and MeshLab write
  them, and decoded to linear (alpha stays linear).

A missing texture image or MTL file: a warning naming the file, and the bake goes on without it.
A malformed file: InputError naming the file.
"""
from __future__ import annotations

import base64
import binascii
import hashlib
import importlib.util
import json
import logging
import math
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from ..model.appearance import DEFAULT_BASE_COLOR, Material
from ..core.errors import InputError

log = logging.getLogger(__name__)

# glTF 2.0 codes, named once.
GLB_MAGIC = b"glTF"
GLB_HEADER = struct.Struct("<4sII")  # magic, version, total length
GLB_CHUNK = struct.Struct("<II")  # chunk length, chunk type
GLB_JSON_CHUNK = 0x4E4F534A
GLB_BIN_CHUNK = 0x004E4942
MODE_POINTS, MODE_LINES, MODE_TRIANGLES, MODE_TRIANGLE_STRIP, MODE_TRIANGLE_FAN = 0, 1, 4, 5, 6
#: Primitive modes trimesh keeps (in order with the others) and those that are triangles.
TRIMESH_MODES = (MODE_POINTS, MODE_LINES, MODE_TRIANGLES, MODE_TRIANGLE_STRIP)
TRIANGLE_MODES = (MODE_TRIANGLES, MODE_TRIANGLE_STRIP)
FLOAT = 5126  # accessor componentType
IMAGE_SUFFIXES = {"image/png": ".png", "image/jpeg": ".jpg", "image/webp": ".webp"}
#: glTF's default material (spec 3.9.1): white, fully metallic, fully rough.
GLTF_DEFAULT_FACTORS = {"baseColorFactor": (1.0, 1.0, 1.0, 1.0), "metallicFactor": 1.0, "roughnessFactor": 1.0}
#: Deepest node hierarchy read (deeper is taken for a cycle).
MAX_NODE_DEPTH = 1024


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


# --- glTF / GLB ----------------------------------------------------------------------------------

#: glTF's +Y-up axes to Blender's +Z-up ones: (x, y, z) -> (x, -z, y), a rotation (no mirror).
GLTF_TO_BLENDER = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


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
    materials = _materials(_Images(path=path, header=header, binary=binary, texture_dir=texture_dir))
    placements = []
    for node, world in worlds:
        mesh = header["nodes"][node].get("mesh")
        if mesh is None:
            continue
        if not isinstance(mesh, int) or not 0 <= mesh < len(mesh_primitives):
            raise InputError(f"{path}: nodes[{node}].mesh {mesh!r} is not a mesh of the file")
        name = str(header["nodes"][node].get("name", f"node {node}"))
        placements.extend((index, GLTF_TO_BLENDER @ world, name) for index in mesh_primitives[mesh])
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
    used = set(header.get("extensionsUsed", []) or [])
    for name, effect in (("KHR_texture_transform", "texture transforms are not applied"),
                         ("EXT_mesh_gpu_instancing", "GPU instances are not expanded (each node placed once)")):
        if name in used:
            log.warning("%s: uses %s; %s", path, name, effect)


def _trimesh_gltf(path: Path):
    try:
        from trimesh.exchange import gltf
    except ImportError as exc:
        raise InputError(f"{path}: reading glTF needs trimesh, a dependency of the command line "
                         "(pip install -r requirements.txt)") from exc
    return gltf


def _short(exc: Exception) -> str:
    return " ".join(str(exc).split())[:200]


def _gltf_json(path: Path) -> tuple[dict, bytes | None]:
    """(the JSON header, the GLB's BIN chunk or None); InputError for a malformed container."""
    data = path.read_bytes()
    binary = None
    if path.suffix.lower() == ".glb":
        if len(data) < GLB_HEADER.size + GLB_CHUNK.size:
            raise InputError(f"{path}: not a GLB file ({len(data)} bytes)")
        magic, version, length = GLB_HEADER.unpack_from(data)
        if magic != GLB_MAGIC or version != 2:
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
        if not chunks or chunks[0][0] != GLB_JSON_CHUNK:
            raise InputError(f"{path}: a GLB file must start with a JSON chunk")
        text = chunks[0][1]
        binary = next((c for kind, c in chunks[1:] if kind == GLB_BIN_CHUNK), None)
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
            mode = prim.get("mode", MODE_TRIANGLES) if isinstance(prim, dict) else None
            if mode == MODE_TRIANGLE_FAN:
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
    if uvs is not None and texcoord_type not in (None, FLOAT):
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
    x, y, z, w = numbers("rotation", 4, (0.0, 0.0, 0.0, 1.0))
    s = numbers("scale", 3, (1.0, 1.0, 1.0))
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if norm == 0:
        raise InputError(f"{path}: nodes[{index}].rotation is a zero quaternion")
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    rotation = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                         [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                         [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    m = np.eye(4)
    m[:3, :3] = rotation * s  # R @ diag(s)
    m[:3, 3] = t
    return m


@dataclass
class _Images:
    """A glTF file's images as files (see the module docstring), each resolved once."""

    path: Path
    header: dict
    binary: bytes | None
    texture_dir: Path | None
    files: dict = field(default_factory=dict)

    def of_texture(self, info, where: str) -> str | None:
        """The image file of a baseColorTexture, or None with a warning."""
        textures = self.header.get("textures", [])
        index = info.get("index") if isinstance(info, dict) else None
        if not isinstance(index, int) or not 0 <= index < len(textures) or not isinstance(textures[index], dict):
            raise InputError(f"{where}.baseColorTexture.index {index!r} is not one of the {len(textures)} textures")
        if info.get("texCoord", 0) != 0:
            log.warning("%s: baseColorTexture uses TEXCOORD_%s; only TEXCOORD_0 is read", where, info.get("texCoord"))
        texture = textures[index]
        source = texture.get("source")
        for extension in (texture.get("extensions") or {}).values():  # EXT_texture_webp and the like
            if isinstance(extension, dict) and isinstance(extension.get("source"), int) and source is None:
                source = extension["source"]
        images = self.header.get("images", [])
        if not isinstance(source, int) or not 0 <= source < len(images) or not isinstance(images[source], dict):
            log.warning("%s: textures[%d] has no image; the material is read without it", where, index)
            return None
        if source not in self.files:
            self.files[source] = self._file(source)
        return self.files[source]

    def _file(self, index: int) -> str | None:
        path, image = self.path, self.header["images"][index]
        uri, mime = image.get("uri"), image.get("mimeType")
        name = image.get("name") if isinstance(image.get("name"), str) else f"image{index}"
        if isinstance(uri, str) and not uri.startswith("data:"):
            file = (path.parent / unquote(uri)).resolve()
            if not file.is_file():
                log.warning("%s: texture image %s is missing; the material is read without it", path, file)
                return None
            return str(file)
        if isinstance(uri, str):  # data:[mime][;base64],payload
            head, _, payload = uri.partition(",")
            mime = head[5:].split(";")[0] or mime
            try:
                data = base64.b64decode(payload, validate=True) if head.endswith(";base64") \
                    else unquote(payload).encode()
            except (binascii.Error, ValueError):
                raise InputError(f"{path}: images[{index}] has a malformed data URI") from None
        else:
            data = _buffer_view(path, self.header, self.binary, view=image.get("bufferView"), what=f"images[{index}]")
        suffix = IMAGE_SUFFIXES.get(mime) or _sniff_suffix(data)
        if suffix is None:
            log.warning("%s: images[%d] (%s) is not PNG, JPEG or WebP; the material is read without it", path, index,
                        mime)
            return None
        if self.texture_dir is None:
            log.warning("%s: images[%d] (%s) is embedded and no texture folder was given; the material is read "
                        "without it", path, index, name)
            return None
        stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("._")[:60] or "image"
        file = Path(self.texture_dir) / f"{stem}-{hashlib.sha256(data).hexdigest()[:12]}{suffix}"
        if not file.is_file():
            file.parent.mkdir(parents=True, exist_ok=True)
            file.write_bytes(data)
        return str(file.resolve())


def _materials(images: _Images) -> tuple[Material, ...]:
    """The file's material table (factors clipped to [0, 1]; a non-number is refused)."""
    out = []
    for i, mat in enumerate(images.header.get("materials", [])):
        where = f"{images.path}: materials[{i}]"
        if not isinstance(mat, dict):
            raise InputError(f"{where} is not an object")
        pbr = mat.get("pbrMetallicRoughness", {})
        if not isinstance(pbr, dict):
            raise InputError(f"{where}.pbrMetallicRoughness is not an object")
        color = _factor(where, pbr, "baseColorFactor", 4)
        metallic = _factor(where, pbr, "metallicFactor", 1)
        roughness = _factor(where, pbr, "roughnessFactor", 1)
        info = pbr.get("baseColorTexture")
        texture = None if info is None else images.of_texture(info, where)
        name = mat.get("name")
        out.append(Material(name=name if isinstance(name, str) and name else f"material.{i}",
                            base_color=tuple(float(c) for c in color), metallic=float(metallic[0]),
                            roughness=float(roughness[0]), texture=texture))
    return tuple(out)


def _factor(where: str, pbr: dict, key: str, size: int) -> np.ndarray:
    value = pbr.get(key, GLTF_DEFAULT_FACTORS[key])
    try:
        out = np.atleast_1d(np.asarray(value, np.float64))
    except (TypeError, ValueError):
        out = np.zeros(0)
    if out.shape != (size,) or not np.all(np.isfinite(out)):
        raise InputError(f"{where}.pbrMetallicRoughness.{key} must be {size} finite number(s)")
    return np.clip(out, 0.0, 1.0)


def _sniff_suffix(data: bytes) -> str | None:
    if data.startswith(b"\x89PNG\r\n\x1a\n"):
        return ".png"
    if data.startswith(b"\xff\xd8\xff"):
        return ".jpg"
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        return ".webp"
    return None


def _buffer_view(path: Path, header: dict, binary: bytes | None, *, view, what: str) -> bytes:
    """The bytes of a buffer view (the GLB's BIN chunk, a data: URI or a file beside the .gltf)."""
    views, buffers = header.get("bufferViews", []), header.get("buffers", [])
    if not isinstance(view, int) or not 0 <= view < len(views) or not isinstance(views[view], dict):
        raise InputError(f"{path}: {what}.bufferView {view!r} is not one of the {len(views)} buffer views")
    v = views[view]
    buffer, offset, length = v.get("buffer"), v.get("byteOffset", 0), v.get("byteLength")
    if not isinstance(buffer, int) or not 0 <= buffer < len(buffers) or not isinstance(buffers[buffer], dict):
        raise InputError(f"{path}: bufferViews[{view}].buffer {buffer!r} is not one of the {len(buffers)} buffers")
    uri = buffers[buffer].get("uri")
    if uri is None:
        data = binary or b""
    elif uri.startswith("data:"):
        try:
            data = base64.b64decode(uri.partition(",")[2])
        except (binascii.Error, ValueError):
            raise InputError(f"{path}: buffers[{buffer}] has a malformed data URI") from None
    else:
        file = path.parent / unquote(uri)
        try:
            data = file.read_bytes()
        except OSError as exc:
            raise InputError(f"{path}: buffers[{buffer}] file {file}: {exc.strerror or exc}") from None
    if not isinstance(offset, int) or not isinstance(length, int) or offset < 0 or length < 0 \
            or offset + length > len(data):
        raise InputError(f"{path}: bufferViews[{view}] lies outside its buffer of {len(data)} bytes")
    return data[offset:offset + length]


# --- OBJ's MTL ----------------------------------------------------------------------------------

#: map_Kd options and how many arguments each takes (-o/-s/-t/-mm: up to that many numbers).
_MAP_OPTIONS = {"-blendu": 1, "-blendv": 1, "-bm": 1, "-boost": 1, "-cc": 1, "-clamp": 1, "-imfchan": 1,
                "-texres": 1, "-type": 1, "-mm": 2, "-o": 3, "-s": 3, "-t": 3}
_NUMERIC_OPTIONS = ("-mm", "-o", "-s", "-t")


def read_mtl(path: Path) -> dict[str, Material]:
    """The materials of an MTL file by name (see the module docstring). A missing file: a warning
    and no materials; a malformed line: InputError naming the file and line."""
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        log.warning("%s: material library missing; the OBJ is read without its materials", path)
        return {}
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, expected a material library") from None
    out: dict[str, Material] = {}
    current, fields = None, {}
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        key, _, rest = line.partition(" ")
        rest = rest.strip()
        if key == "newmtl":
            if current is not None:
                out[current] = _mtl_material(path, current, fields)
            current, fields = rest, {}
        elif key in ("Kd", "d", "Tr", "Pr", "Pm", "Ns"):
            try:
                values = [float(x) for x in rest.split()]
            except ValueError:
                values = []
            if not values or not all(math.isfinite(v) for v in values):
                raise InputError(f"{path}: line {number} ('{line[:60]}'): {key} needs numbers")
            fields[key] = values
        elif key == "map_Kd":
            fields[key] = _map_file(rest)
    if current is not None:
        out[current] = _mtl_material(path, current, fields)
    return out


def _map_file(rest: str) -> str:
    """The file name of a map_Kd line: what follows its options (the name may hold spaces)."""
    tokens = rest.split()
    at = 0
    while at < len(tokens) - 1 and tokens[at] in _MAP_OPTIONS:
        option, at = tokens[at], at + 1
        for _ in range(_MAP_OPTIONS[option]):
            if at < len(tokens) - 1 and (option not in _NUMERIC_OPTIONS or _is_number(tokens[at])):
                at += 1
    return " ".join(tokens[at:]).replace("\\", "/")


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _mtl_material(path: Path, name: str, fields: dict) -> Material:
    texture = None
    if fields.get("map_Kd"):
        file = (path.parent / fields["map_Kd"]).resolve()
        if file.is_file():
            texture = str(file)
        else:
            log.warning("%s: texture image %s of material %s is missing; the material is read without it",
                        path, file, name)
    kd = fields.get("Kd", DEFAULT_BASE_COLOR[:3])
    rgb = [1.0, 1.0, 1.0] if texture is not None else (list(kd) * 3 if len(kd) == 1 else list(kd[:3]))
    alpha = fields["d"][0] if "d" in fields else (1.0 - fields["Tr"][0] if "Tr" in fields else 1.0)
    if "Pr" in fields:
        roughness = fields["Pr"][0]
    elif "Ns" in fields:
        roughness = 1.0 - math.sqrt(max(fields["Ns"][0], 0.0) / 1000.0)
    else:
        roughness = 0.5
    metallic = fields["Pm"][0] if "Pm" in fields else 0.0
    return Material(name=name, base_color=tuple(min(max(float(c), 0.0), 1.0) for c in (*rgb, alpha)),
                    metallic=min(max(metallic, 0.0), 1.0), roughness=min(max(roughness, 0.0), 1.0), texture=texture)


def obj_materials(path: Path, mtllibs: list[str], names: list[str]) -> tuple[Material, ...]:
    """One Material per `usemtl` name (in first-use order), from the OBJ's material libraries
    (relative to the OBJ); a name no library defines: a warning and Blender's default colour."""
    library: dict[str, Material] = {}
    missing_library = False
    for lib in mtllibs:
        file = path.parent / lib
        if not file.is_file() and " " in lib and all((path.parent / part).is_file() for part in lib.split()):
            parts = lib.split()  # `mtllib a.mtl b.mtl`
        else:
            parts = [lib]
        for part in parts:
            found = read_mtl(path.parent / part)
            missing_library |= not (path.parent / part).is_file()
            library.update({k: v for k, v in found.items() if k not in library})
    out = []
    for name in names:
        if name not in library and not missing_library:
            log.warning("%s: material %s is not in its material library; read with the default colour", path, name)
        out.append(library.get(name, Material(name=name, base_color=DEFAULT_BASE_COLOR)))
    return tuple(out)
