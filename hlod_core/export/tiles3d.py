"""3D Tiles 1.1 export of a baked hierarchy: one tile per node, one GLB per node (`glb`); with
`merge_leaves`, a node's leaf children share one tile and one GLB (`tile_name`).

Specification: OGC 3D Tiles 1.1 (tileset JSON, bounding volumes, geometricError, REPLACE
refinement, glTF content). The tileset is in the bake's model space (Z up, metres), translated by
the bake's float64 origin in the root's `transform`; a tile's geometricError is its node's
model-space error; its box the node's subtree box; attributes and materials only where the bake has
them; texture files copied once into `textures/` and referred to by every GLB; empty nodes left out.
A tileset bigger than ONE_FILE_MAX_BYTES as one document is split into external tilesets
(`tileset_files`), so that the tileset.json a viewer reads first stays small.
Why: docs/how-it-works.md#3d-tiles-export

Data form: in, an Hlod; out, a folder tileset.json, tiles/<node>.glb, tiles/<node>.json (external
tilesets of a big tileset), textures/ (when textured), written into a temporary folder and put in
place of an earlier export (`replace_export`).
"""
from __future__ import annotations

import json
import logging
import os
import shutil
import tempfile
from pathlib import Path
from urllib.parse import quote

import numpy as np

from ..core.atomic import replace_folder, umask_mode
from ..core.errors import InputError
from ..io.texture_folder import unique_file_name
from ..model.hierarchy import Hlod, nodes_geometry
from . import texture_codec
from .draco import require_dracopy
from .glb import GENERATOR, TileImage, glb_bytes, triangle_count
from .place import Place

log = logging.getLogger(__name__)

TILE_FOLDER, TEXTURE_FOLDER = "tiles", "textures"
#: The image formats of glTF 2.0 core, told by their first bytes: signature -> (mime type, suffix).
IMAGE_SIGNATURES = {b"\x89PNG\r\n\x1a\n": ("image/png", ".png"), b"\xff\xd8\xff": ("image/jpeg", ".jpg")}
#: Half sizes of the tiles' boxes are at least this fraction of the root diagonal (flat nodes), and
#: at least MIN_HALF_SIZE model units (a scene without extent).
MIN_HALF_SIZE_OF_DIAGONAL, MIN_HALF_SIZE = 1e-6, 1e-9
#: A tileset written as one tileset.json (indented, as it always was) while that text is at most this
#: many bytes; a bigger one is split into external tilesets of at most MAX_TILES_PER_FILE tiles each
#: (compact JSON: at most about 450 bytes a tile, so the first file stays under 64 KB).
ONE_FILE_MAX_BYTES, MAX_TILES_PER_FILE = 64_000, 128
#: The tiles' vertices: float32, positions and normals quantized (KHR_mesh_quantization), or Draco
#: compressed (KHR_draco_mesh_compression, DracoPy on the command line only); glb module notes.
MESH_ENCODINGS = ("plain", "quantized", "draco")


def copy_textures(hlod: Hlod, folder: Path, textures: str = "original") -> tuple[dict[str, TileImage], list[str]]:
    """Copy each distinct texture of the materials the HLOD's triangles use into `folder` (made
    here), once, under a unique name, re-encoded as `textures` asks (texture_codec.encode). Returns
    ({texture path: TileImage}, warnings); a texture that cannot be read or decoded or is not
    PNG/JPEG is left out with one warning naming it and its materials."""
    users = _texture_users(hlod)
    if not users:
        return {}, []
    if hlod.uvs is None:
        return {}, [f"3D Tiles export: the HLOD has no UVs; the textures of materials "
                    f"{', '.join(repr(n) for names in users.values() for n in names)} are left out"]
    images, warnings, names, by_file = {}, [], set(), {}
    for path, material_names in users.items():
        real = os.path.realpath(path)
        if real in by_file:  # the same file under another spelling
            images[path] = by_file[real]
            continue
        image = _copy_texture(path, folder, names=names, warnings=warnings, materials=material_names,
                              textures=textures)
        if image is not None:
            images[path] = by_file[real] = image
    for line in warnings:
        log.warning("%s", line)
    return images, warnings


def _texture_users(hlod: Hlod) -> dict[str, list[str]]:
    """Texture path -> the names of the materials that use it, among the materials of the triangles."""
    if hlod.tri_material is None or not hlod.materials:
        return {}
    used = [hlod.materials[m] for m in np.unique(np.asarray(hlod.tri_material)).tolist()]
    users: dict[str, list[str]] = {}
    for material in used:
        if material.texture is not None:
            users.setdefault(material.texture, []).append(material.name)
    return users


def _copy_texture(path: str, folder: Path, *, names: set, warnings: list, materials: list[str],
                  textures: str = "original") -> TileImage | None:
    """Copy one texture file into `folder` under a name not in `names` (added to it), re-encoded as
    `textures` asks; None, with a line in `warnings` naming it and its `materials`, when it cannot be
    read or decoded or is neither PNG nor JPEG."""
    which = f"material{'s' if len(materials) > 1 else ''} {', '.join(repr(n) for n in materials)}"
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        warnings.append(f"{path}: texture of {which} cannot be read ({exc.strerror or exc}); "
                        "exported without texture")
        return None
    kind = next((v for sig, v in IMAGE_SIGNATURES.items() if data.startswith(sig)), None)
    if kind is None:
        warnings.append(f"{path}: texture of {which} is neither PNG nor JPEG (glTF 2.0 has only those); "
                        "exported without texture")
        return None
    try:
        data, mime_type, suffix = texture_codec.encode(data, *kind, textures)
    except (OSError, ValueError) as exc:  # Pillow: a damaged file behind a PNG/JPEG signature
        warnings.append(f"{path}: texture of {which} cannot be decoded ({exc}); exported without texture")
        return None
    name = unique_file_name(Path(path).stem, suffix, names)
    folder.mkdir(exist_ok=True)
    (folder / name).write_bytes(data)
    return TileImage(uri=f"../{TEXTURE_FOLDER}/{quote(name)}", mime_type=mime_type)


def _box(lo: np.ndarray, hi: np.ndarray, floor: float) -> list[float]:
    """3D Tiles' boundingVolume.box of an axis-aligned box: centre, then three half axes (columns),
    each half size at least `floor`."""
    centre, half = 0.5 * (lo + hi), np.maximum(0.5 * (hi - lo), floor)
    return [*centre.tolist(), half[0], 0.0, 0.0, 0.0, half[1], 0.0, 0.0, 0.0, half[2]]


def tile_name(tile: int) -> str:
    """A tile's file name without suffix: its node's number, or for a tile of a node's leaf children
    (a negative id, -1 - node) `<node>-leaves`."""
    return str(tile) if tile >= 0 else f"{-1 - tile}-leaves"


class _Tiles:
    """The tiles of an HLOD: a tile per node with triangles or with a tile below it (an empty node is
    absent), each with its box (model space less the bake's origin) and its node's error. With
    `merge_leaves`, the leaf children of a node that has two or more are one tile instead, id
    -1 - node (`members` lists its leaves): the union of their boxes, error 0, their triangles."""

    def __init__(self, hlod: Hlod, merge_leaves: bool = False):
        self.hlod = hlod
        origin = np.asarray(hlod.origin, np.float64)
        self.lo, self.hi = hlod.box_min - origin, hlod.box_max - origin
        self.diagonal = float(np.linalg.norm(self.hi[0] - self.lo[0]))
        self.floor = max(MIN_HALF_SIZE_OF_DIAGONAL * self.diagonal, MIN_HALF_SIZE)
        self.children: dict[int, list[int]] = {}
        self.members: dict[int, list[int]] = {}
        self.present = self._present(0)
        if merge_leaves:
            self._merge_leaves()

    def _merge_leaves(self) -> None:
        """Each node's two or more leaf children (with triangles) become one tile, placed where the
        first of them was among the node's children."""
        merges = (self.hlod.child_count == 0) & (self.hlod.tri_count > 0)  # (n,) leaves with triangles
        for node, kids in list(self.children.items()):
            leaves = [c for c in kids if merges[c]]
            if len(leaves) < 2:
                continue
            group, first = -1 - node, kids.index(leaves[0])
            self.members[group], self.children[group] = leaves, []
            self.children[node] = kids[:first] + [group] + [c for c in kids[first:] if not merges[c]]
            for leaf in leaves:
                del self.children[leaf]

    def content(self) -> list[int]:
        """The tiles with content, in node order, a tile of leaves where its first leaf was."""
        first_of = {members[0]: group for group, members in self.members.items()}
        merged = {leaf for members in self.members.values() for leaf in members}
        return [first_of.get(n, n) for n in np.flatnonzero(self.hlod.tri_count > 0).tolist()
                if n not in merged or n in first_of]

    def nodes_of(self, tile: int) -> list[int]:
        """The nodes whose triangles a tile holds."""
        return self.members.get(tile, [tile])

    def _present(self, node: int) -> bool:
        """Whether `node` is a tile; fills self.children (its tiles' children) on the way."""
        first, count = int(self.hlod.child_offset[node]), int(self.hlod.child_count[node])
        kept = [c for c in range(first, first + count) if self._present(c)] if count else []
        self.children[node] = kept
        return bool(kept) or self.hlod.tri_count[node] > 0

    def fields(self, node: int) -> dict:
        """A tile's boundingVolume and geometricError (a tile of leaves: their boxes' union, error 0)."""
        nodes = self.nodes_of(node)
        lo, hi = self.lo[nodes].min(axis=0), self.hi[nodes].max(axis=0)
        return {"boundingVolume": {"box": _box(lo, hi, self.floor)},
                "geometricError": float(self.hlod.error[nodes].max())}

    def tile(self, node: int, content_uri, external=None) -> dict:
        """The tile of `node` with its subtree; content_uri(node) names a GLB. `external(child)`, when
        given, names the external tileset of a child written in another file (None: in this one)."""
        out = self.fields(node)
        if self.hlod.tri_count[self.nodes_of(node)].sum() > 0:
            out["content"] = {"uri": content_uri(node)}
        children = []
        for child in self.children[node]:
            uri = None if external is None else external(child)
            children.append(self.tile(child, content_uri, external) if uri is None
                            else {**self.fields(child), "content": {"uri": uri}})
        if children:
            out["children"] = children
        return out

    def document(self, root: dict, transform: np.ndarray | None, extras: dict | None = None) -> dict:
        """The tileset JSON of the whole tree around its `root` tile: REPLACE refinement, the root's
        `transform` (4x4, float64, row-major here, written column-major) when given."""
        root["refine"] = "REPLACE"
        if transform is not None:
            root["transform"] = np.asarray(transform, np.float64).T.ravel().tolist()  # column-major
        document = {"asset": {"version": "1.1", "generator": GENERATOR},
                    "geometricError": max(self.diagonal, float(self.hlod.error[0])), "root": root}
        if extras:
            document["extras"] = extras
        return document

    def chunks(self, max_tiles: int) -> dict[int, set[int]]:
        """The tree cut into files: {a file's root node: the nodes it holds}, each file at most
        `max_tiles` tiles counting its references to other files (breadth first from its root, a
        node joining while the count allows its children's references; a child left out roots a
        file of its own; a file's root and its children are always in it, which an octree's 9 never
        exceed here). The first file is node 0's."""
        size = self._sizes()
        files, queue = {}, [0]
        while queue:
            top = queue.pop(0)
            held, count, frontier = {top}, 1 + len(self.children[top]), list(self.children[top])
            for node in frontier:  # grows as nodes join: breadth first
                if count - 1 + size[node] <= max_tiles:  # the whole subtree fits: no file of its own
                    held.update(self._subtree(node))
                    count += size[node] - 1
                elif count + len(self.children[node]) <= max_tiles:
                    held.add(node)
                    count += len(self.children[node])
                    frontier.extend(self.children[node])
            files[top] = held
            queue.extend(c for node in held for c in self.children[node] if c not in held)
        return files

    def _sizes(self) -> dict[int, int]:
        """{node: the number of tiles of its subtree}, for the tiles."""
        size: dict[int, int] = {}

        def count(node: int) -> int:
            size[node] = 1 + sum(count(c) for c in self.children[node])
            return size[node]

        count(0)
        return size

    def _subtree(self, node: int) -> list[int]:
        return [node, *(n for c in self.children[node] for n in self._subtree(c))]


def tileset(hlod: Hlod, content_uri, *, place: Place | None = None, mesh: str = "plain",
            merge_leaves: bool = False) -> dict:
    """The tileset JSON of the whole tree in one document; content_uri(tile) names each tile's GLB
    (a tile is a node, or with `merge_leaves` a node's leaves: `tile_name`).
    The root's transform is `root_transform` (on the globe at `place` when given, which the
    document's extras.place also names; `_extras`). InputError without triangles."""
    tiles = _tiles(hlod, merge_leaves)
    return tiles.document(tiles.tile(0, content_uri), root_transform(hlod, place), _extras(place, mesh))


def _extras(place: Place | None, mesh: str) -> dict | None:
    """The first tileset's extras: `place` (where it stands on the globe) and `mesh` (the tiles'
    encoding, where it is not plain: a viewer that knows its tiles are Draco starts its decoder
    while it loads the tileset); None when there is neither."""
    extras = {} if place is None else {"place": place.as_dict()}
    if mesh != "plain":
        extras["mesh"] = mesh
    return extras or None


def content_tiles(hlod: Hlod, *, merge_leaves: bool = False) -> dict[str, list[int]]:
    """{a tile's GLB name without suffix (`tile_name`): the nodes whose triangles it holds}."""
    tiles = _tiles(hlod, merge_leaves)
    return {tile_name(t): tiles.nodes_of(t) for t in tiles.content()}


def _tiles(hlod: Hlod, merge_leaves: bool = False) -> _Tiles:
    tiles = _Tiles(hlod, merge_leaves)
    if not tiles.present:
        raise InputError("3D Tiles export: the hierarchy has no triangles")
    return tiles


def root_transform(hlod: Hlod, place: Place | None = None) -> np.ndarray:
    """The root tile's transform (4x4 float64): the translation by the bake's origin (model space),
    then, for a `place`, its east-north-up frame turned by its heading (place.Place.frame: the scene's
    origin at that point of the WGS84 ellipsoid, ECEF metres)."""
    transform = np.eye(4)
    transform[:3, 3] = np.asarray(hlod.origin, np.float64)
    return transform if place is None else place.frame() @ transform


def tileset_files(hlod: Hlod, *, place: Place | None = None, max_tiles: int = MAX_TILES_PER_FILE,
                  mesh: str = "plain", merge_leaves: bool = False) -> dict[str, dict]:
    """The tileset split into external tilesets: {path in the export: tileset JSON}. "tileset.json"
    holds the top of the tree (at most `max_tiles` tiles, `chunks`); a subtree cut off is
    tiles/<node>.json, referred to by a tile with its node's box and error whose content is that
    file (3D Tiles 1.1 "external tileset"; the referring tile's transform applies to it). GLBs are
    tiles/<node>.glb as in one document. Boxes, errors, the root's transform and extras are tileset()'s."""
    tiles = _tiles(hlod, merge_leaves)
    transform, extras = root_transform(hlod, place), _extras(place, mesh)
    files = {}
    for top, held in tiles.chunks(max_tiles).items():
        prefix = f"{TILE_FOLDER}/" if top == 0 else ""  # URIs are relative to the file that holds them

        def glb_uri(node, prefix=prefix):
            return f"{prefix}{tile_name(node)}.glb"

        def external(node, prefix=prefix, held=held):
            return None if node in held else f"{prefix}{tile_name(node)}.json"

        root = tiles.tile(top, glb_uri, external)
        if top == 0:
            files["tileset.json"] = tiles.document(root, transform, extras)
        else:
            root["refine"] = "REPLACE"
            files[f"{TILE_FOLDER}/{tile_name(top)}.json"] = {"asset": {"version": "1.1", "generator": GENERATOR},
                                                  "geometricError": root["geometricError"], "root": root}
    return files


def export(hlod: Hlod, out_dir: str | os.PathLike, *, platform: str | None = None,
           place: Place | None = None, mesh: str = "plain", textures: str = "original",
           merge_leaves: bool = False) -> dict:
    """Write tileset.json, tiles/<node>.glb and, for textured materials, textures/ into out_dir,
    atomically: everything is written into a temporary folder beside it and renamed into place,
    replacing an earlier export (`replace_export`). Folders and files get the modes of ordinary
    ones (0o777 / 0o666 less the umask). `platform`: a sys.platform string (default this
    machine's) for replace_export. `place`: where the scene's origin stands on the globe (None: the
    local frame, as the bake's model space). `mesh`: the tiles' vertices, "plain" float32,
    "quantized" (KHR_mesh_quantization) or "draco" (KHR_draco_mesh_compression; glb module notes).
    `textures`: the texture files as they are, or re-encoded as JPEG or WebP (texture_codec).
    `merge_leaves`: a node's leaf children share one tile (fewer, bigger tiles: `_Tiles`).
    Returns a summary (tiles, glb files, triangles stored and held by the GLBs, bytes, image files,
    warnings)."""
    if mesh not in MESH_ENCODINGS:
        raise InputError(f"3D Tiles export: mesh {mesh!r} is not one of {', '.join(MESH_ENCODINGS)}")
    if textures not in texture_codec.TEXTURE_ENCODINGS:
        raise InputError(f"3D Tiles export: textures {textures!r} is not one of "
                         f"{', '.join(texture_codec.TEXTURE_ENCODINGS)}")
    if mesh == "draco":
        require_dracopy()  # before anything is written
    if textures != "original":
        texture_codec.require_pillow()
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    try:
        os.chmod(staging, umask_mode(0o777))  # mkdtemp makes it 0700; the export is an ordinary folder
        images, warnings = copy_textures(hlod, staging / TEXTURE_FOLDER, textures)
        tiles = _tiles(hlod, merge_leaves)
        written, tris, held, size = _write_tiles(tiles, staging / TILE_FOLDER, images=images, mesh=mesh)
        document = tileset(hlod, lambda tile: f"{TILE_FOLDER}/{tile_name(tile)}.glb", place=place, mesh=mesh,
                           merge_leaves=merge_leaves)
        files = write_tileset(hlod, staging, document, place=place, mesh=mesh, merge_leaves=merge_leaves)
        warnings = warnings + replace_export(out_dir, staging, platform=platform)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return {"format": "3dtiles", "output": str(out_dir), "tiles": _count(document["root"]), "glb_files": written,
            "triangles": tris, "glb_triangles": held, "bytes": size,
            "tileset_geometric_error": document["geometricError"],
            "image_files": len(set(images.values())), "tileset_files": len(files),
            "tileset_json_bytes": files["tileset.json"], "mesh": mesh, "textures": textures,
            "place": None if place is None else place.as_dict(),
            "warnings": warnings}


def write_tileset(hlod: Hlod, folder: Path, document: dict, *, place: Place | None = None,
                  mesh: str = "plain", merge_leaves: bool = False) -> dict[str, int]:
    """Write the tileset JSON into `folder` (its tiles/ made): `document` (tileset()) as one indented
    tileset.json while that is at most ONE_FILE_MAX_BYTES, else split into external tilesets
    (tileset_files at the document's `place`, `mesh` and `merge_leaves`), compact. Returns {path: bytes written}."""
    text = json.dumps(document, indent=1).encode()
    if len(text) <= ONE_FILE_MAX_BYTES:
        (folder / "tileset.json").write_bytes(text)
        return {"tileset.json": len(text)}
    written = {}
    for path, part in tileset_files(hlod, place=place, mesh=mesh, merge_leaves=merge_leaves).items():
        data = json.dumps(part, separators=(",", ":")).encode()
        (folder / path).write_bytes(data)
        written[path] = len(data)
    return written


def _write_tiles(tiles: _Tiles, folder: Path, *, images: dict[str, TileImage], mesh: str) -> tuple[int, int, int, int]:
    """folder/<tile>.glb for every tile with triangles (folder made here; `tile_name`); (files, stored
    triangles, triangles the GLBs hold, bytes). Draco holds no triangle whose corners repeat a vertex
    (position and attributes): zero area, nothing drawn."""
    hlod = tiles.hlod
    folder.mkdir()
    written, tris, held, size = 0, 0, 0, 0
    for tile in tiles.content():
        geometry = nodes_geometry(hlod, tiles.nodes_of(tile))
        data = glb_bytes(geometry.positions, geometry.faces, geometry.normals, uvs=geometry.uvs, colors=geometry.colors,
                         face_material=geometry.face_material, materials=hlod.materials, images=images, mesh=mesh)
        (folder / f"{tile_name(tile)}.glb").write_bytes(data)
        written, tris, size = written + 1, tris + geometry.faces.shape[0], size + len(data)
        held += triangle_count(data) if mesh == "draco" else geometry.faces.shape[0]
    return written, tris, held, size


def replace_export(out_dir: Path, staging: Path, *, platform: str | None = None) -> list[str]:
    """Put the export written in `staging` in out_dir's place (core.atomic.replace_folder: out_dir is
    the earlier export or the new one, whole; renames retried while Windows refuses them, a served
    tile being open; the earlier export put back when the new one cannot take its place), replacing
    an earlier export there (a folder holding tileset.json, or an empty one); InputError for any
    other folder. Returns warnings naming earlier exports renamed aside that could not be removed
    yet (a file in them still open): the next export removes them."""
    if out_dir.exists() and not (out_dir / "tileset.json").is_file() and any(out_dir.iterdir()):
        raise InputError(f"{out_dir}: exists, is not empty and holds no tileset.json; not replacing it")
    left = [f"{path}: an earlier export, not removed yet (a file in it is open); the next export removes it"
            for path in replace_folder(staging, out_dir, platform=platform)]
    for line in left:
        log.warning("%s", line)
    return left


def _count(tile: dict) -> int:
    return 1 + sum(_count(c) for c in tile.get("children", []))
