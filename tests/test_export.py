"""3D Tiles export and batch baking from background mode,
checked by independent tools: the Khronos glTF validator for every GLB and CesiumGS 3d-tiles-tools
reading the tileset back (tools/validators/check_tileset.mjs)."""
import hashlib
import json
import logging
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from blender_runs import blender
from helpers import ROOT, model, textured_scene
from hlod_core.bake.pipeline import BakeSettings, bake
from hlod_core.core.errors import InputError
from hlod_core.export import draco as draco_bits
from hlod_core.export import glb, place, tiles3d
from hlod_core.io import hlod_file as fileformat
from hlod_core.io import meshes
from hlod_core.model.appearance import Material
from hlod_core.model.hierarchy import Hlod, node_geometry
from processes import hlod, last_json, one_line_error

VALIDATORS = ROOT / "tools/validators"


def independent_read(folder) -> dict:
    proc = subprocess.run(["node", str(VALIDATORS / "check_tileset.mjs"), str(folder)], capture_output=True,
                          text=True, timeout=600, cwd=VALIDATORS)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


# Every GLB under a folder through the Khronos validator, with its external images loaded relative
# to the GLB, reporting which images it read (for tests of the image files themselves).
VALIDATE_WITH_IMAGES = r"""
import fs from "node:fs";
import path from "node:path";
import validator from "gltf-validator";
const dir = path.resolve(process.argv[1]);
const out = {};
for (const name of fs.readdirSync(dir, { recursive: true }).filter((n) => n.endsWith(".glb")).sort()) {
  const file = path.join(dir, name);
  const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(file)), {
    uri: name, maxIssues: 0, writeTimestamp: false,
    externalResourceFunction: (uri) => fs.promises.readFile(path.resolve(path.dirname(file), decodeURIComponent(uri)))
      .then((data) => new Uint8Array(data)),
  });
  out[name.split(path.sep).join("/")] = {
    errors: report.issues.numErrors, warnings: report.issues.numWarnings,
    messages: report.issues.messages.filter((m) => m.severity <= 1).map((m) => `${m.code}: ${m.message}`),
    images: (report.info.resources ?? []).filter((r) => r.image).map((r) => r.uri),
  };
}
console.log(JSON.stringify(out));
"""


def validate_with_images(folder) -> dict:
    """{GLB path relative to folder: {errors, warnings, messages, images (URIs read and decoded)}}."""
    proc = subprocess.run(["node", "--input-type=module", "-e", VALIDATE_WITH_IMAGES, str(folder)], capture_output=True,
                          text=True, timeout=600, cwd=VALIDATORS)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def assert_matches(tiles_dir, hlod_file):
    """Every GLB valid (with the images it refers to); the reader's tiles are the hierarchy's nodes,
    with their triangle counts, boxes and errors; each parent's geometricError is at least its
    children's."""
    h = fileformat.load(hlod_file)
    read = independent_read(tiles_dir)
    every = read["tiles"]
    tiles = [t for t in every if not t["external"]]  # a tile referring to an external tileset is no node
    assert len(tiles) == h.node_count == sum(1 for t in tiles if t["uri"])
    for ref in (t for t in every if t["external"]):  # same box and error as the root it refers to
        root = next(t for t in every if t["path"].startswith(ref["path"] + "/[external:"))
        assert (root["box"], root["geometricError"]) == (ref["box"], ref["geometricError"])
    bad = [(t["uri"], t["messages"]) for t in tiles if t["errors"]]  # images read relative to each GLB
    assert not bad, bad[:3]
    origin = np.asarray(h.origin)
    diag = float(np.linalg.norm(h.box_max[0] - h.box_min[0]))
    for t in tiles:
        node = int(t["uri"].split("/")[-1].split(".")[0])
        assert t["triangles"] == int(h.tri_count[node])
        centre, half = np.array(t["box"][:3]), np.array(t["box"][3:])[[0, 4, 8]]
        assert np.allclose(centre - half, h.box_min[node] - origin, atol=1e-6 * diag + 1e-9)
        assert np.allclose(centre + half, h.box_max[node] - origin, atol=1e-6 * diag + 1e-9)
        assert t["geometricError"] == pytest.approx(float(h.error[node]))
        if t["parentGeometricError"] is not None:
            assert t["parentGeometricError"] >= t["geometricError"]
    assert read["tilesetGeometricError"] >= tiles[0]["geometricError"]
    return tiles


def test_glb_layout_and_axes():
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3]], np.float32)
    data = glb.glb_bytes(positions, np.array([[0, 1, 2], [0, 2, 3]]))
    magic, version, total = struct.unpack("<4sII", data[:12])
    assert (magic, version, total) == (b"glTF", 2, len(data)) and total % 4 == 0
    json_len, kind = struct.unpack("<II", data[12:20])
    doc = json.loads(data[20:20 + json_len])
    assert kind == 0x4E4F534A and json_len % 4 == 0  # "JSON", little-endian
    position = doc["accessors"][0]
    # Z up (x, y, z) is written Y up as (x, z, -y): model +y (2) becomes glTF -z, +z (3) glTF +y
    assert position["min"] == [0.0, 0.0, -2.0] and position["max"] == [1.0, 3.0, 0.0]
    assert doc["accessors"][-1]["componentType"] == 5123 and "NORMAL" not in doc["meshes"][0][
        "primitives"][0]["attributes"]


def test_export_command_on_shared_model_passes_the_validators(bakes, tmp_path):
    _, h = bakes.baked("cow", target_tris=500)
    src = fileformat.save(h, tmp_path / "cow.hlod")
    out = last_json(hlod("-q", "export", src, "--format", "3dtiles", "-o", tmp_path / "cow_tiles"))
    assert out["tiles"] == out["glb_files"] == h.node_count and out["triangles"] == int(h.tri_count.sum())
    assert_matches(tmp_path / "cow_tiles", src)
    # again into the same folder: replaced atomically, nothing left beside it
    hlod("-q", "export", src, "--format", "3dtiles", "-o", tmp_path / "cow_tiles")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cow.hlod", "cow_tiles"]
    native = last_json(hlod("-q", "export", src, "--format", "hlod", "-o", tmp_path / "native"))
    assert fileformat.load(native["output"]).node_count == h.node_count


def test_normals_are_written_only_when_baked_with_them_and_far_origins_keep_precision(tmp_path):
    mesh = meshes.load_mesh(model("spot"))
    p, f = mesh.positions + 1e6, mesh.faces  # a scene placed a million metres away
    e1, e2 = p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]]
    normals = np.zeros_like(p)
    np.add.at(normals, f.ravel(), np.repeat(np.cross(e1, e2), 3, axis=0))
    h = bake(meshes.from_arrays(p, f, normals, name="spot far"), BakeSettings(target_tris=800))
    src = fileformat.save(h, tmp_path / "spot.hlod")
    tiles3d.export(h, tmp_path / "tiles")
    doc = json.loads((tmp_path / "tiles/tileset.json").read_text())
    assert doc["root"]["transform"][12:15] == pytest.approx(list(h.origin))
    glb = (tmp_path / "tiles/tiles/0.glb").read_bytes()
    gltf = json.loads(glb[20:20 + struct.unpack("<I", glb[12:16])[0]])
    assert "NORMAL" in gltf["meshes"][0]["primitives"][0]["attributes"]
    assert max(abs(v) for v in gltf["accessors"][0]["max"]) < 10  # origin-relative, not 1e6
    assert_matches(tmp_path / "tiles", src)


def test_export_refuses_to_replace_a_foreign_folder(bakes, tmp_path):
    _, h = bakes.baked("cow", target_tris=500)
    src = fileformat.save(h, tmp_path / "cow.hlod")
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep me")
    assert "holds no tileset.json; not replacing it" in one_line_error(
        hlod("export", src, "--format", "3dtiles", "-o", tmp_path / "mine", check=False))
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep me"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.blender
def test_background_batch_over_blend_files(versioned_repo, tmp_path):
    """Two .blend files made here plus a broken one, baked and exported in one background call of
    the installed extension's command (through each Blender's bpy module; the extension enabled
    from its repository, its dependencies from its wheels): the broken one fails alone, the summary
    says so, the exit status is 1 (bpy 4.2 crashed at exit, 139, before exit_process), and both good
    files give a .hlod and a 3D Tiles folder that pass the validators."""
    made = blender(versioned_repo, "make_blends", tmp_path)
    broken = tmp_path / "broken.blend"
    broken.write_text("not a blend file")
    env = {**os.environ, "BLENDER_USER_RESOURCES": str(versioned_repo / "user")}

    def command(*args):
        return subprocess.run([str(versioned_repo.python), str(ROOT / "scripts/hlod_blender.py"), "--extension-repo",
                               str(versioned_repo / "repo"), *map(str, args)], capture_output=True, text=True,
                              timeout=600, env=env, cwd=ROOT)

    run = command("bake", made["boxes"], broken, made["monkeys"], "-o", tmp_path / "out", "--format", "hlod", "3dtiles",
                  "--target-tris", "400")
    assert run.returncode == 1, run.stderr[-3000:]
    summary = json.loads(run.stdout.strip().splitlines()[-1])
    assert [r["ok"] for r in summary["files"]] == [True, False, True] and summary["failed"] == 1
    assert "broken.blend" in summary["files"][1]["error"]
    for stem in ("boxes", "monkeys"):
        assert_matches(tmp_path / "out" / f"{stem}_3dtiles", tmp_path / "out" / f"{stem}.hlod")
    # --collection picks only the monkeys' collection (the plane is outside it)
    one = command("bake", made["monkeys"], "--collection", "props", "-o", tmp_path / "props")
    assert one.returncode == 0, one.stderr[-3000:]
    result = json.loads(one.stdout.strip().splitlines()[-1])["files"][0]
    assert result["input_tris"] == made["monkeys_tris"]
    bad = command("bake", made["monkeys"], "--collection", "nope", "-o", tmp_path / "x")
    assert bad.returncode == 1 and "no such collection" in bad.stdout.strip().splitlines()[-1]


@pytest.mark.blender
def test_background_command_names_a_missing_extension_repository(tmp_path):
    run = subprocess.run([sys.executable, str(ROOT / "scripts/hlod_blender.py"), "--extension-repo", str(tmp_path),
                          "bake", "-o", str(tmp_path / "x.hlod")], capture_output=True, text=True, timeout=120,
                         cwd=ROOT)
    assert run.returncode == 2 and run.stderr.strip().splitlines() == [
        f"hlod_blender: --extension-repo {tmp_path}: not an extension repository holding hlod "
        "(make one with blender_ext.py install-files --local-dir DIR hlod-*.zip)"]


def test_empty_leaves_are_absent_and_inner_nodes_without_triangles_keep_their_children(bakes):
    _, h = bakes.baked("cow", target_tris=500)
    leaves = np.flatnonzero(h.child_count == 0)
    counts = np.asarray(h.tri_count).copy()
    counts[leaves[0]] = 0  # an empty leaf: no tile at all
    counts[0] = 0          # an empty root: a tile without content, children kept
    doc = tiles3d.tileset(h.replace(tri_count=counts), lambda node: f"tiles/{node}.glb")

    def walk(tile):
        yield tile
        for child in tile.get("children", []):
            yield from walk(child)

    tiles = list(walk(doc["root"]))
    uris = {t["content"]["uri"] for t in tiles if "content" in t}
    assert len(tiles) == h.node_count - 1 and "content" not in doc["root"]
    assert f"tiles/{leaves[0]}.glb" not in uris and len(uris) == h.node_count - 2


def _flatten(files: dict, path: str = "tileset.json") -> dict:
    """The tileset of `files` (tiles3d.tileset_files) back in one document: each tile referring to an
    external tileset replaced by that tileset's root, URIs made relative to the top folder."""
    folder = path.rpartition("/")[0]

    def tile(t: dict) -> dict:
        t = dict(t)
        uri = t.get("content", {}).get("uri")
        if uri is not None:
            full = f"{folder}/{uri}" if folder else uri
            if full.endswith(".json"):
                root = _flatten(files, full)["root"]
                root.pop("refine")
                return root
            t["content"] = {"uri": full}
        if "children" in t:
            t["children"] = [tile(c) for c in t["children"]]
        return t

    return {**files[path], "root": tile(files[path]["root"])}


def _tile_count(t: dict) -> int:
    return 1 + sum(_tile_count(c) for c in t.get("children", []))


@pytest.mark.parametrize("max_tiles", [9, 20, 40])  # 9: an octree node and its 8 children
def test_external_tilesets_hold_the_one_document_tileset_exactly(bakes, max_tiles):
    """Split at any size, the files put back together are tileset()'s document, every box, error,
    URI and the root's transform the same; each file at most max_tiles tiles, each subtree's file
    rooted at a tile of the same box and error as the tile that refers to it."""
    _, h = bakes.baked("cow", target_tris=200)
    whole = tiles3d.tileset(h, lambda node: f"tiles/{node}.glb")
    files = tiles3d.tileset_files(h, max_tiles=max_tiles)
    assert _tile_count(whole["root"]) > max_tiles and len(files) > 1
    assert _flatten(files) == whole
    placed = place.place(-71.06, 42.36, 5.0, 20.0)  # the root's transform and extras, placed, the same
    assert _flatten(tiles3d.tileset_files(h, max_tiles=max_tiles, place=placed)) == tiles3d.tileset(
        h, lambda node: f"tiles/{node}.glb", place=placed)
    assert all(_tile_count(f["root"]) <= max_tiles for f in files.values())
    for path, part in files.items():
        assert part["asset"] == whole["asset"] and part["root"]["refine"] == "REPLACE"
        assert ("transform" in part["root"]) == (path == "tileset.json")
        if path != "tileset.json":
            assert part["geometricError"] == part["root"]["geometricError"]


def test_merge_leaves_puts_a_nodes_leaves_in_one_tile_with_their_triangles(bakes, tmp_path):
    """`export --merge-leaves`: the two leaves of the literal hierarchy are one tile, tiles/0-leaves.glb,
    whose box is their boxes' union and whose error is 0, holding their triangles (positions as the
    plain export's two GLBs, the first leaf's then the second's vertices renumbered); the root is
    as without it; the merged tileset of a bake, split into external tilesets, is its one document."""
    h = literal_hlod(normals=True)
    plain, merged = (tiles3d.export(h, tmp_path / name, merge_leaves=(name == "merged"))
                     for name in ("plain", "merged"))
    assert (plain["tiles"], merged["tiles"], merged["glb_files"], merged["triangles"]) == (3, 2, 2, plain["triangles"])
    docs = {name: json.loads((tmp_path / f"{name}/tileset.json").read_text()) for name in ("plain", "merged")}
    leaves, (tile,) = docs["plain"]["root"].pop("children"), docs["merged"]["root"].pop("children")
    assert docs["merged"] == docs["plain"]  # the root, its box, error and transform
    boxes = np.array([c["boundingVolume"]["box"] for c in leaves])
    lo = (boxes[:, :3] - boxes[:, [3, 7, 11]]).min(axis=0)
    hi = (boxes[:, :3] + boxes[:, [3, 7, 11]]).max(axis=0)
    assert tile["content"] == {"uri": "tiles/0-leaves.glb"} and tile["geometricError"] == 0.0
    assert np.allclose(tile["boundingVolume"]["box"], [*(lo + hi) / 2, (hi - lo)[0] / 2, 0, 0, 0, (hi - lo)[1] / 2,
                                                      0, 0, 0, (hi - lo)[2] / 2])
    gltf, binary = read_glb(tmp_path / "merged/tiles/0-leaves.glb")
    primitive = gltf["meshes"][0]["primitives"][0]
    corners = accessor(gltf, binary, primitive["attributes"]["POSITION"])[accessor(gltf, binary, primitive["indices"])]
    want = []
    for node in (1, 2):
        g, b = read_glb(tmp_path / f"plain/tiles/{node}.glb")
        q = g["meshes"][0]["primitives"][0]
        want.append(accessor(g, b, q["attributes"]["POSITION"])[accessor(g, b, q["indices"])])
    assert np.array_equal(corners.reshape(-1, 3, 3), np.concatenate(want).reshape(-1, 3, 3))
    _, baked = bakes.baked("cow", target_tris=200)
    whole = tiles3d.tileset(baked, lambda tile: f"tiles/{tiles3d.tile_name(tile)}.glb", merge_leaves=True)
    files = tiles3d.tileset_files(baked, max_tiles=20, merge_leaves=True)
    assert len(files) > 1 and _flatten(files) == whole and "-leaves.glb" in json.dumps(whole)
    assert _tile_count(whole["root"]) < _tile_count(tiles3d.tileset(baked, lambda node: f"tiles/{node}.glb")["root"])


def second_read(folder) -> dict:
    """loaders.gl's reading of an export (tools/validators/read_loaders_gl.mjs): {"tilesets": files
    read, "tiles": {GLB path relative to folder: triangles decoded}}."""
    proc = subprocess.run(["node", str(VALIDATORS / "read_loaders_gl.mjs"), str(folder)], capture_output=True,
                          text=True, timeout=600, cwd=VALIDATORS)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_a_big_export_has_a_small_first_file_and_passes_the_readers(city_hlod, tmp_path):
    """The city (445 nodes: 0.3 MB as one indented document) is written as external tilesets: the
    first file at most 64 KB, the independent reader finds every node through them; a small
    tileset stays one file (test_an_export_without_appearance_is_byte_identical_to_before). A second
    reader, loaders.gl's Tiles3DLoader, reads every tileset file and decodes every tile of it and of
    its Draco export with merged leaves (a node's leaves in one tile) with the triangles the bake
    stores, less (Draco) those whose corners repeat a vertex: zero area, not stored."""
    src = fileformat.save(city_hlod, tmp_path / "city.hlod")
    summary = tiles3d.export(city_hlod, tmp_path / "tiles")
    first = (tmp_path / "tiles/tileset.json").stat().st_size
    assert summary["tileset_json_bytes"] == first <= 64_000 < len(json.dumps(
        tiles3d.tileset(city_hlod, lambda node: f"tiles/{node}.glb"), indent=1))
    assert summary["tileset_files"] == 1 + len(list((tmp_path / "tiles/tiles").glob("*.json"))) > 1
    assert_matches(tmp_path / "tiles", src)
    draco = tiles3d.export(city_hlod, tmp_path / "draco", mesh="draco", merge_leaves=True)
    stored, repeated = {}, {}
    for node in np.flatnonzero(city_hlod.tri_count > 0).tolist():
        geometry = node_geometry(city_hlod, node)
        corners = geometry.positions[geometry.faces]  # the city has no other vertex attributes
        stored[node] = int(city_hlod.tri_count[node])
        repeated[node] = int(np.count_nonzero(np.all(corners[:, 0] == corners[:, 1], axis=1)
                                              | np.all(corners[:, 1] == corners[:, 2], axis=1)
                                              | np.all(corners[:, 0] == corners[:, 2], axis=1)))
    plain_read, draco_read = second_read(tmp_path / "tiles"), second_read(tmp_path / "draco")
    assert plain_read == {"tilesets": summary["tileset_files"],
                          "tiles": {f"tiles/{n}.glb": c for n, c in stored.items()}}
    merged = tiles3d.content_tiles(city_hlod, merge_leaves=True)  # its leaves share tiles
    assert draco_read["tiles"] == {f"tiles/{name}.glb": sum(stored[n] - repeated[n] for n in nodes)
                                   for name, nodes in merged.items()}
    assert draco_read["tilesets"] == draco["tileset_files"] and len(merged) == draco["glb_files"] < len(stored)
    assert sum(repeated.values()) == draco["triangles"] - draco["glb_triangles"] > 0


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_export_modes_follow_the_umask(bakes, tmp_path, umask):
    """Folders are 0777 and files 0666 less the umask, like any other tool's output, also when
    replacing (a tileset folder made by mkdtemp is 0700 whatever the umask); the copied textures
    too, whatever the modes of their sources."""
    _, h = bakes.baked("cow", target_tris=500)
    png, jpeg = write_textures(tmp_path)
    os.chmod(png, 0o600)
    os.chmod(jpeg, 0o755)
    textured = with_appearance(literal_hlod(normals=False), png, jpeg)
    old = os.umask(umask)
    try:
        for _ in range(2):  # a fresh export, then one replacing it
            tiles3d.export(h, tmp_path / "tiles")
            tiles3d.export(textured, tmp_path / "textured")
            folders = [tmp_path / "tiles", tmp_path / "tiles" / "tiles", tmp_path / "textured" / "textures"]
            files = [tmp_path / "tiles" / "tileset.json", *(tmp_path / "tiles" / "tiles").iterdir(),
                     *(tmp_path / "textured" / "textures").iterdir()]
            assert {oct(p.stat().st_mode & 0o777) for p in folders} == {oct(0o777 & ~umask)}
            assert {oct(p.stat().st_mode & 0o777) for p in files} == {oct(0o666 & ~umask)}
    finally:
        os.umask(old)


# --- appearance: materials, UVs, colours, textures -----------------------------------------------

def literal_hlod(*, normals: bool) -> Hlod:
    """A 3-node HLOD written out by hand, no bake: the root's 2-triangle LOD over [0,2]x[0,1], leaves
    1 and 2 with 8 triangles each over [0,1]x[0,1] and [1,2]x[0,1]. Coordinates are binary fractions
    (normals too, but for a (0, 0.6, 0.8) the export normalises with IEEE sqrt and division), so
    every byte an export writes is the same on every machine."""
    def grid(x0):
        xs, ys = np.meshgrid(np.arange(3) * 0.5 + x0, np.arange(3) * 0.5, indexing="xy")
        z = 0.25 * ((np.arange(9) % 3) * (np.arange(9) // 3) % 3)
        quads = np.array([[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 7, 6], [4, 5, 8, 7]])
        return np.stack([xs.ravel(), ys.ravel(), z], axis=1), np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])

    root_pos = np.array([[0, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0]], float)
    root_tris = np.array([[0, 1, 2], [0, 2, 3]])
    (p1, t1), (p2, t2) = grid(0.0), grid(1.0)
    positions = np.concatenate([root_pos, p1, p2]).astype(np.float32)
    nrm = None
    if normals:
        nrm = np.tile(np.array([[0, 0, 1], [0, 0.6, 0.8], [0, 0, 2]], np.float32), (positions.shape[0] // 3 + 1, 1))
        nrm = nrm[:positions.shape[0]]
    lod_min = np.array([root_pos.min(0), p1.min(0), p2.min(0)])
    lod_max = np.array([root_pos.max(0), p1.max(0), p2.max(0)])
    box_min = np.concatenate([np.minimum(lod_min[0], lod_min[1:].min(0))[None], lod_min[1:]])
    box_max = np.concatenate([np.maximum(lod_max[0], lod_max[1:].max(0))[None], lod_max[1:]])
    origin, centre = np.array([100.0, -50.0, 2.5]), 0.5 * (box_min + box_max)
    return Hlod(parent=np.array([-1, 0, 0], np.int32), child_offset=np.array([1, -1, -1], np.int32),
                child_count=np.array([2, 0, 0], np.int32), depth=np.array([0, 1, 1], np.int32),
                lod_box_min=lod_min + origin, lod_box_max=lod_max + origin, box_min=box_min + origin,
                box_max=box_max + origin, sphere_center=centre + origin,
                sphere_radius=np.linalg.norm(box_max - centre, axis=1), error=np.array([0.125, 0.0, 0.0]),
                cube_side=np.ones(3), tri_offset=np.array([0, 2, 10], np.int64),
                tri_count=np.array([2, 8, 8], np.int64), vertex_offset=np.array([0, 4, 13], np.int64),
                vertex_count=np.array([4, 9, 9], np.int64), origin=origin, positions=positions,
                indices=np.concatenate([root_tris, t1 + 4, t2 + 13]).astype(np.uint32), normals=nrm)


def folder_digest(folder) -> tuple[list[str], str]:
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    digest = hashlib.sha256()
    for p in files:
        digest.update(p.relative_to(folder).as_posix().encode() + b"\0" + p.read_bytes())
    return [p.relative_to(folder).as_posix() for p in files], digest.hexdigest()


# SHA-256 of the export of literal_hlod (file names and bytes, see folder_digest) by the code before
# the export carried appearance: recorded with hlod_core/export/tiles3d.py at commit 6d77cb6 (unchanged
# since 844ae1f), running
# `tiles3d.export(literal_hlod(normals=...), DIR)` then `folder_digest(DIR)`.
BEFORE_APPEARANCE_DIGESTS = {False: "93e9e14dca7b80309e75213edcbea1d67289dcef4ac23a4c31036573010ea475",
                             True: "369da809dca32415f02196c25d4f9fa7b3e3c67b6559f746f4caf1afbcd4eb60"}


@pytest.mark.parametrize("normals", [False, True])
def test_an_export_without_appearance_is_byte_identical_to_before(tmp_path, normals):
    summary = tiles3d.export(literal_hlod(normals=normals), tmp_path / "tiles")
    names, digest = folder_digest(tmp_path / "tiles")
    assert names == ["tiles/0.glb", "tiles/1.glb", "tiles/2.glb", "tileset.json"]
    assert digest == BEFORE_APPEARANCE_DIGESTS[normals]
    assert summary["image_files"] == 0 and summary["warnings"] == []


def read_glb(path) -> tuple[dict, bytes]:
    data = path.read_bytes()
    json_len = struct.unpack("<I", data[12:16])[0]
    bin_len = struct.unpack("<I", data[20 + json_len:24 + json_len])[0]
    return json.loads(data[20:20 + json_len]), data[28 + json_len:28 + json_len + bin_len]


def accessor(gltf: dict, binary: bytes, index: int) -> np.ndarray:
    """An accessor's values as (count, components) (count,) for scalars, read from the BIN chunk."""
    acc = gltf["accessors"][index]
    view = gltf["bufferViews"][acc["bufferView"]]
    dtype = {5126: np.float32, 5123: np.uint16, 5125: np.uint32}[acc["componentType"]]  # FLOAT, USHORT, UINT
    width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[acc["type"]]
    values = np.frombuffer(binary, dtype, acc["count"] * width, view.get("byteOffset", 0) + acc.get("byteOffset", 0))
    return values.reshape(acc["count"], width) if width > 1 else values


def write_textures(folder) -> tuple[str, str]:
    """A 4x2 PNG (with alpha) and an 8x8 JPEG written by Pillow; returns their paths."""
    png, jpeg = folder / "brick wall.png", folder / "label.jpeg"
    Image.fromarray(np.arange(32, dtype=np.uint8).reshape(2, 4, 4) * 8, "RGBA").save(png)
    Image.fromarray(np.full((8, 8, 3), (200, 30, 60), np.uint8), "RGB").save(jpeg)
    return str(png), str(jpeg)


def with_appearance(h: Hlod, png: str, jpeg: str) -> Hlod:
    """`h` with UVs and colours from its positions and four materials by triangle centroid: "brick"
    and "brick dark" share the PNG, "label" has the JPEG, "paint" has no texture; triangles sorted by
    material within each node, as the bake stores them."""
    materials = (Material("brick", (1.0, 0.9, 0.8, 1.0), 0.0, 0.75, png),
                 Material("brick dark", (0.5, 0.4, 0.4, 1.0), 0.25, 0.5, png),
                 Material("label", (1.0, 1.0, 1.0, 1.0), 0.0, 0.5, jpeg),
                 Material("paint", (0.1, 0.6, 0.2, 1.0), 1.0, 0.3))
    lo, hi = h.positions.min(0), h.positions.max(0)
    unit = (h.positions - lo) / np.where(hi > lo, hi - lo, 1)
    centroid = unit[h.indices.astype(np.int64)].mean(axis=1)
    material = (np.minimum((centroid[:, 0] * 2).astype(int), 1) * 2 + (centroid[:, 1] > 0.5)).astype(np.uint16)
    by_offset = np.argsort(h.tri_offset, kind="stable")
    owner = np.repeat(np.arange(h.node_count), h.tri_count[by_offset])  # the rank of each triangle's node range
    order = np.lexsort((material, owner))  # keeps every node's range, sorts materials within it
    colors = np.concatenate([unit, np.ones((unit.shape[0], 1))], axis=1).astype(np.float32)
    return h.replace(indices=h.indices[order], tri_material=material[order], materials=materials,
                     uvs=np.ascontiguousarray(unit[:, :2] * [2.0, 1.0] - [0.0, 0.25], np.float32), colors=colors)


def test_textured_glbs_carry_materials_uvs_colours_and_share_images(tmp_path):
    png, jpeg = write_textures(tmp_path)
    h = with_appearance(literal_hlod(normals=True), png, jpeg)
    summary = tiles3d.export(h, tmp_path / "tiles")
    assert summary["image_files"] == 2 and summary["warnings"] == []
    # one file per distinct texture, the original bytes, whatever the number of materials and tiles
    assert sorted(p.name for p in (tmp_path / "tiles/textures").iterdir()) == ["brick_wall.png", "label.jpg"]
    assert (tmp_path / "tiles/textures/brick_wall.png").read_bytes() == open(png, "rb").read()
    assert (tmp_path / "tiles/textures/label.jpg").read_bytes() == open(jpeg, "rb").read()
    report = validate_with_images(tmp_path / "tiles")
    assert sorted(report) == ["tiles/0.glb", "tiles/1.glb", "tiles/2.glb"]
    assert {name: r["errors"] for name, r in report.items()} == dict.fromkeys(report, 0), report
    # the validator read and decoded the shared images from the GLBs' URIs: the root ("brick dark"
    # and "label" by centroid) uses both, leaf 1 ("brick", "brick dark") the PNG only
    assert sorted(report["tiles/0.glb"]["images"]) == ["../textures/brick_wall.png", "../textures/label.jpg"]
    assert report["tiles/1.glb"]["images"] == ["../textures/brick_wall.png"]
    for node in range(h.node_count):
        gltf, binary = read_glb(tmp_path / f"tiles/tiles/{node}.glb")
        geometry = node_geometry(h, node)
        primitives = gltf["meshes"][0]["primitives"]
        used = np.unique(geometry.face_material)
        # one primitive per material of the node, sharing the vertex accessors, triangles kept
        assert [gltf["materials"][p["material"]]["name"] for p in primitives] == [h.materials[m].name for m in used]
        assert [accessor(gltf, binary, p["indices"]).size // 3 for p in primitives] == np.bincount(
            geometry.face_material)[used].tolist()
        indices = np.concatenate([accessor(gltf, binary, p["indices"]) for p in primitives]).reshape(-1, 3)
        assert np.array_equal(indices, geometry.faces[np.argsort(geometry.face_material, kind="stable")])
        attributes = primitives[0]["attributes"]
        assert all(p["attributes"] == attributes for p in primitives)
        st = accessor(gltf, binary, attributes["TEXCOORD_0"])
        assert np.array_equal(st[:, 0], geometry.uvs[:, 0]) and np.array_equal(st[:, 1], 1 - geometry.uvs[:, 1])
        assert np.array_equal(accessor(gltf, binary, attributes["COLOR_0"]), geometry.colors)
        for p in primitives:
            material, row = h.materials[used[primitives.index(p)]], gltf["materials"][p["material"]]
            pbr = row["pbrMetallicRoughness"]
            assert pbr["baseColorFactor"] == pytest.approx(material.base_color)
            factors = (pbr["metallicFactor"], pbr["roughnessFactor"])
            assert factors == pytest.approx((material.metallic, material.roughness))
            image = None
            if "baseColorTexture" in pbr:
                image = gltf["images"][gltf["textures"][pbr["baseColorTexture"]["index"]]["source"]]
            expected = {png: {"uri": "../textures/brick_wall.png", "mimeType": "image/png"},
                        jpeg: {"uri": "../textures/label.jpg", "mimeType": "image/jpeg"}, None: None}[material.texture]
            assert image == expected
        assert len(gltf.get("images", [])) == len({h.materials[m].texture for m in used} - {None})
    # the root: textured, with TEXCOORD_0; a known vertex: the
    # root's corner (0, 1) has our uv (0, 0.75), glTF's (0, 0.25)
    gltf, binary = read_glb(tmp_path / "tiles/tiles/0.glb")
    assert any("baseColorTexture" in m["pbrMetallicRoughness"] for m in gltf["materials"])
    corner = np.flatnonzero(np.all(node_geometry(h, 0).positions == [0, 1, 0], axis=1))[0]
    attributes = gltf["meshes"][0]["primitives"][0]["attributes"]
    assert accessor(gltf, binary, attributes["TEXCOORD_0"])[corner].tolist() == [0.0, 0.25]
    assert node_geometry(h, 0).uvs[corner].tolist() == [0.0, 0.75]


def test_a_texture_that_cannot_be_used_is_named_with_its_materials_and_left_out(tmp_path, caplog):
    png, _ = write_textures(tmp_path)
    not_an_image = tmp_path / "notes.png"
    not_an_image.write_text("not a picture")
    h = with_appearance(literal_hlod(normals=False), png, str(tmp_path / "gone.jpeg"))
    h = h.replace(materials=(*h.materials[:3], Material("paint", texture=str(not_an_image))))
    with caplog.at_level(logging.WARNING, logger="hlod_core.export.tiles3d"):
        summary = tiles3d.export(h, tmp_path / "tiles")
    assert summary["warnings"] == [line.getMessage() for line in caplog.records]
    assert len(summary["warnings"]) == 2
    assert f"{tmp_path / 'gone.jpeg'}: texture of material 'label' cannot be read" in summary["warnings"][0]
    assert f"{not_an_image}: texture of material 'paint' is neither PNG nor JPEG" in summary["warnings"][1]
    assert [p.name for p in (tmp_path / "tiles/textures").iterdir()] == ["brick_wall.png"]
    report = validate_with_images(tmp_path / "tiles")
    assert [r["errors"] for r in report.values()] == [0, 0, 0], report
    gltf, _ = read_glb(tmp_path / "tiles/tiles/2.glb")  # leaf 2: "label" and "paint", both untextured now
    assert [m["name"] for m in gltf["materials"]] == ["label", "paint"] and "images" not in gltf
    assert not any("baseColorTexture" in m["pbrMetallicRoughness"] for m in gltf["materials"])
    # without UVs no texture can be bound (a baseColorTexture needs TEXCOORD_0): one warning, no images
    summary = tiles3d.export(h.replace(uvs=None), tmp_path / "no_uvs")
    assert summary["warnings"] == ["3D Tiles export: the HLOD has no UVs; the textures of materials 'brick', "
                                   "'brick dark', 'label', 'paint' are left out"]
    assert summary["image_files"] == 0 and not (tmp_path / "no_uvs/textures").exists()
    assert [r["errors"] for r in validate_with_images(tmp_path / "no_uvs").values()] == [0, 0, 0]


def test_an_interrupted_textured_export_leaves_the_earlier_one(tmp_path, monkeypatch):
    """The textures are copied into the staging folder like the tiles: a failure after they are
    copied leaves nothing beside the output and the earlier export as it was."""
    png, jpeg = write_textures(tmp_path)
    h = with_appearance(literal_hlod(normals=False), png, jpeg)
    tiles3d.export(h, tmp_path / "out" / "tiles")
    before = folder_digest(tmp_path / "out" / "tiles")

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(tiles3d, "glb_bytes", interrupted)
    with pytest.raises(KeyboardInterrupt):
        tiles3d.export(h.replace(materials=(Material("other", texture=jpeg),) * 4), tmp_path / "out" / "tiles")
    assert folder_digest(tmp_path / "out" / "tiles") == before
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["tiles"]


def test_textured_bake_exported_by_the_command_passes_the_validators(tmp_path):
    """A bake of a numpy mesh (a wavy 64x64 grid), given UVs, colours and four materials, saved as
    .hlod (texture paths relative to it) and exported by `hlod export`: every GLB valid with its
    images read, the tiles the hierarchy's nodes, the root textured with TEXCOORD_0 and COLOR_0, one
    image file per distinct texture."""
    n = 64
    xs, ys = np.meshgrid(np.linspace(0, 8, n), np.linspace(0, 8, n))
    positions = np.stack([xs.ravel(), ys.ravel(), 0.3 * np.sin(xs.ravel()) * np.cos(ys.ravel())], axis=1)
    cell = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    faces = np.concatenate([np.stack([cell, cell + 1, cell + n + 1], 1), np.stack([cell, cell + n + 1, cell + n], 1)])
    h = bake(meshes.from_arrays(positions, faces, name="grid"), BakeSettings(target_tris=1000))
    assert h.node_count > 1 and not h.has_appearance
    png, jpeg = write_textures(tmp_path)
    src = fileformat.save(with_appearance(h, png, jpeg), tmp_path / "grid.hlod")
    out = last_json(hlod("-q", "export", src, "--format", "3dtiles", "-o", tmp_path / "grid_tiles"))
    assert out["image_files"] == 2 and out["warnings"] == [] and out["glb_files"] == h.node_count
    assert sorted(p.name for p in (tmp_path / "grid_tiles/textures").iterdir()) == ["brick_wall.png", "label.jpg"]
    assert_matches(tmp_path / "grid_tiles", src)
    report = validate_with_images(tmp_path / "grid_tiles")
    assert len(report) == h.node_count and not [(k, r["messages"]) for k, r in report.items() if r["errors"]]
    gltf, _ = read_glb(tmp_path / "grid_tiles/tiles/0.glb")
    assert any("baseColorTexture" in m["pbrMetallicRoughness"] for m in gltf["materials"])
    assert {"TEXCOORD_0", "COLOR_0"} <= set(gltf["meshes"][0]["primitives"][0]["attributes"])
    assert len(gltf["meshes"][0]["primitives"]) == 4  # the root covers all four materials


@pytest.mark.slow
@pytest.mark.blender
def test_the_textured_scene_baked_in_blender_exports_textured_tiles(repo, tmp_path):
    """The shared textured scene (tests/scenes/textured_scene.py, small) baked from its .blend by the
    installed extension's background command, with 3D Tiles: every GLB valid with its images, the
    root tile textured with TEXCOORD_0 (and COLOR_0: the scene has colour attributes) and referring to
    its own proxy texture only, one image file per distinct texture of the scene and per proxy, each
    its source's bytes."""
    scene = textured_scene("small")
    run = subprocess.run([sys.executable, str(ROOT / "scripts/hlod_blender.py"), "--extension-repo", str(repo / "repo"),
                          "bake", str(scene["blend"]), "-o", str(tmp_path / "out"), "--format", "hlod", "3dtiles"],
                         capture_output=True, text=True, timeout=600, cwd=ROOT,
                         env={**os.environ, "BLENDER_USER_RESOURCES": str(repo / "user")})
    assert run.returncode == 0, run.stderr[-3000:]
    tiles_dir, src = tmp_path / "out" / "textured_3dtiles", tmp_path / "out" / "textured.hlod"
    h = fileformat.load(src)
    assert h.node_count > 1 and h.uvs is not None and h.colors is not None
    assert_matches(tiles_dir, src)
    textures = sorted(scene["textures"].iterdir())
    # the scene's textures and the inner nodes' proxy textures (OUT.textures/proxy_<node>.png)
    proxies = sorted({Path(m.texture) for m in h.materials if m.name.startswith("HLOD proxy")})
    assert proxies and len({m.texture for m in h.materials} - {None}) == len(textures) + len(proxies)
    copied = sorted((tiles_dir / "textures").iterdir())
    assert sorted(p.read_bytes() for p in copied) == sorted(p.read_bytes() for p in [*textures, *proxies])
    gltf, _ = read_glb(tiles_dir / "tiles/0.glb")
    assert any("baseColorTexture" in m["pbrMetallicRoughness"] for m in gltf["materials"])
    # the root refers to its own proxy texture only
    names = [image.get("uri", "").rsplit("/", 1)[-1] for image in gltf.get("images", [])]
    assert names and all(name.startswith("proxy_0") for name in names), names
    assert {"TEXCOORD_0", "COLOR_0"} <= set(gltf["meshes"][0]["primitives"][0]["attributes"])


# --- quantized tile content (KHR_mesh_quantization) ------------------------------------------------

def _decoded(gltf: dict, binary: bytes, index: int) -> np.ndarray:
    """An accessor's values as float64 (count, components), through its view's byteStride and, for a
    normalized integer accessor, glTF's decoding (max(c / (2^(bits-1) - 1), -1) for signed types)."""
    acc = gltf["accessors"][index]
    view = gltf["bufferViews"][acc["bufferView"]]
    dtype = np.dtype({5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32,
                      5126: np.float32}[acc["componentType"]])
    width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[acc["type"]]
    stride = view.get("byteStride", dtype.itemsize * width) // dtype.itemsize
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    rows = np.frombuffer(binary, dtype, acc["count"] * stride, start).reshape(acc["count"], stride)[:, :width]
    values = rows.astype(np.float64)
    if acc.get("normalized"):
        values = np.maximum(values / np.iinfo(dtype).max, -1.0) if dtype.kind == "i" else values / np.iinfo(dtype).max
    return values


def test_quantized_tiles_decode_to_the_plain_ones_and_pass_the_validators(bakes, tmp_path):
    """The cow with normals and colours exported plain and quantized (`export --mesh quantized`): every
    quantized GLB requires KHR_mesh_quantization, its positions through the node's translation and
    uniform scale are the plain ones within half a step (the largest side / 65534) and inside the
    tile's box, its normals within half an int8 step, its colours half a uint16 step; indices and the
    tileset are the plain export's (the tileset's extras.mesh names the encoding); the glTF
    validator finds no error and no warning the plain GLB does not have; bytes go down."""
    _, h = bakes.baked("cow", target_tris=300)
    rng = np.random.default_rng(7)
    normals = rng.normal(size=h.positions.shape)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    normals[0] = 0.0  # a zero normal becomes +Y in both
    colors = rng.random((h.positions.shape[0], 4)).astype(np.float32)
    src = fileformat.save(h.replace(normals=normals.astype(np.float32), colors=colors), tmp_path / "cow.hlod")
    plain = last_json(hlod("-q", "export", src, "-o", tmp_path / "plain"))
    quantized = last_json(hlod("-q", "export", src, "-o", tmp_path / "quantized", "--mesh", "quantized"))
    assert (plain["mesh"], quantized["mesh"]) == ("plain", "quantized") and quantized["bytes"] < plain["bytes"]
    tileset, plain_tileset = (json.loads((tmp_path / f"{name}/tileset.json").read_text())
                              for name in ("quantized", "plain"))
    assert tileset.pop("extras") == {"mesh": "quantized"} and "extras" not in plain_tileset and tileset == plain_tileset
    h = fileformat.load(src)
    origin = np.asarray(h.origin)
    for node in range(h.node_count):
        a, a_bin = read_glb(tmp_path / f"plain/tiles/{node}.glb")
        b, b_bin = read_glb(tmp_path / f"quantized/tiles/{node}.glb")
        assert "extensionsRequired" not in a and b["extensionsRequired"] == b["extensionsUsed"] == [
            "KHR_mesh_quantization"]
        pa, pb = a["meshes"][0]["primitives"][0], b["meshes"][0]["primitives"][0]
        position = _decoded(b, b_bin, pb["attributes"]["POSITION"])
        assert b["accessors"][pb["attributes"]["POSITION"]]["min"] == np.rint(position.min(0) * 32767).tolist()
        scale, translation = b["nodes"][0]["scale"], np.array(b["nodes"][0]["translation"])
        assert scale[0] == scale[1] == scale[2] > 0
        world = position * scale[0] + translation  # Y up, relative to the origin
        exact = _decoded(a, a_bin, pa["attributes"]["POSITION"])
        assert np.abs(world - exact).max() <= scale[0] / 32767 * 0.5 + 1e-6 * scale[0]
        z_up = world @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float).T  # glTF (x, y, z) -> (x, -z, y)
        slack = scale[0] / 32767
        assert np.all(z_up >= h.box_min[node] - origin - slack) and np.all(z_up <= h.box_max[node] - origin + slack)
        na, nb = (_decoded(g, data, p["attributes"]["NORMAL"]) for g, data, p in ((a, a_bin, pa), (b, b_bin, pb)))
        assert np.abs(na - nb).max() <= 0.5 / 127 + 1e-6
        ca, cb = (_decoded(g, data, p["attributes"]["COLOR_0"]) for g, data, p in ((a, a_bin, pa), (b, b_bin, pb)))
        assert np.abs(ca - cb).max() <= 0.5 / 65535 + 1e-7
        assert np.array_equal(accessor(a, a_bin, pa["indices"]), accessor(b, b_bin, pb["indices"]))
    reports = {kind: validate_with_images(tmp_path / kind) for kind in ("plain", "quantized")}
    assert all(r["errors"] == 0 for r in reports["quantized"].values()), reports["quantized"]
    assert all(reports["quantized"][k]["warnings"] <= reports["plain"][k]["warnings"] for k in reports["plain"])
    assert_matches(tmp_path / "quantized", src)


# --- Draco tile content (KHR_draco_mesh_compression) ----------------------------------------------

def _draco_rows(gltf: dict, binary: bytes, primitive: dict) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """A Draco primitive decoded with DracoPy: ({glTF attribute: (n, k) float64}, faces (t, 3)),
    checked against the primitive's accessors (counts; POSITION's bounds)."""
    import DracoPy

    ext = primitive["extensions"]["KHR_draco_mesh_compression"]
    view = gltf["bufferViews"][ext["bufferView"]]
    mesh = DracoPy.decode(binary[view.get("byteOffset", 0):view.get("byteOffset", 0) + view["byteLength"]])
    rows = {}
    for name, unique_id in ext["attributes"].items():
        values = np.asarray(mesh.get_attribute_by_unique_id(unique_id)["data"], np.float64)
        acc = gltf["accessors"][primitive["attributes"][name]]
        assert "bufferView" not in acc and acc["count"] == values.shape[0]
        rows[name] = values / 255.0 if acc.get("normalized") else values  # COLOR_0: normalized uint8
    position = gltf["accessors"][primitive["attributes"]["POSITION"]]
    bounds = rows["POSITION"]
    assert np.array_equal(np.float32(position["min"]), bounds.min(0).astype(np.float32))  # float32 exact
    assert np.array_equal(np.float32(position["max"]), bounds.max(0).astype(np.float32))
    faces = np.asarray(mesh.faces, np.int64).reshape(-1, 3)
    assert gltf["accessors"][primitive["indices"]]["count"] == faces.size
    return rows, faces


def _with_defaults(material: dict) -> dict:
    """A glTF material row with its defaults filled in (glb.DEFAULTS) and no name, as a reader sees it."""
    pbr = {**glb.DEFAULTS["pbrMetallicRoughness"], **material.get("pbrMetallicRoughness", {})}
    return {**glb.DEFAULTS["materials"], **{k: v for k, v in material.items() if k != "name"},
            "pbrMetallicRoughness": pbr}


def _rolled(faces: np.ndarray) -> np.ndarray:
    """Triangles (t, 3) each turned to start at its smallest index (winding kept), sorted by row."""
    turned = np.stack([np.roll(f, -int(np.argmin(f))) for f in faces]) if len(faces) else faces.reshape(0, 3)
    return turned[np.lexsort(turned.T[::-1])]


def test_draco_tiles_decode_to_the_plain_ones_and_pass_the_validators(tmp_path):
    """A textured hierarchy (four materials, normals, UVs, colours) exported plain and Draco compressed
    (`export --mesh draco`): every Draco GLB requires KHR_draco_mesh_compression and has a primitive
    per material, each decoding (DracoPy) to that material's triangles of the plain GLB, winding kept,
    every vertex within a step of Draco's quantization of a plain vertex (draco.POSITION_BITS of the
    part's largest side, NORMAL_BITS, UV_BITS of their range; colours half an 8-bit step); the tileset
    and the images are the plain export's; the glTF validator and 3d-tiles-tools find no error and no warning the plain
    export does not have, and the triangle counts the hierarchy stores. The tileset is the plain
    export's with extras.mesh naming the encoding (the viewer starts CesiumJS's Draco decoder on it)."""
    png, jpeg = write_textures(tmp_path)
    src = fileformat.save(with_appearance(literal_hlod(normals=True), png, jpeg), tmp_path / "lit.hlod")
    plain = last_json(hlod("-q", "export", src, "-o", tmp_path / "plain"))
    draco = last_json(hlod("-q", "export", src, "-o", tmp_path / "draco", "--mesh", "draco"))
    assert (draco["mesh"], draco["image_files"]) == ("draco", plain["image_files"])  # bytes: tiny tiles, no gain
    tileset, plain_tileset = (json.loads((tmp_path / f"{name}/tileset.json").read_text())
                              for name in ("draco", "plain"))
    assert tileset.pop("extras") == {"mesh": "draco"} and "extras" not in plain_tileset and tileset == plain_tileset
    h = fileformat.load(src)
    for node in range(h.node_count):
        a, a_bin = read_glb(tmp_path / f"plain/tiles/{node}.glb")
        b, b_bin = read_glb(tmp_path / f"draco/tiles/{node}.glb")
        assert b["extensionsRequired"] == b["extensionsUsed"] == ["KHR_draco_mesh_compression"]
        prims_a, prims_b = a["meshes"][0]["primitives"], b["meshes"][0]["primitives"]
        assert [p["material"] for p in prims_a] == [p["material"] for p in prims_b]
        assert [_with_defaults(m) for m in a["materials"]] == [_with_defaults(m) for m in b["materials"]]
        assert a.get("images") == b.get("images") and "generator" not in b["asset"]
        rows = {**{name: b.get(name, []) for name in glb.DEFAULTS}, "primitives": prims_b,
                "pbrMetallicRoughness": [m["pbrMetallicRoughness"] for m in b["materials"]]}
        assert not any(row.get(key) == default for name, table in rows.items() for row in table
                       for key, default in glb.DEFAULTS[name].items())  # no field at its glTF default
        names = ("POSITION", "NORMAL", "TEXCOORD_0", "COLOR_0")
        exact = {n: accessor(a, a_bin, prims_a[0]["attributes"][n]).astype(np.float64) for n in names}
        for pa, pb in zip(prims_a, prims_b):
            faces = accessor(a, a_bin, pa["indices"]).reshape(-1, 3).astype(np.int64)
            rows, decoded_faces = _draco_rows(b, b_bin, pb)
            used = np.unique(faces)
            steps = {"POSITION": np.ptp(exact["POSITION"][used], axis=0).max() / (2 ** draco_bits.POSITION_BITS - 1),
                     "TEXCOORD_0": np.ptp(exact["TEXCOORD_0"][used], axis=0).max() / (2 ** draco_bits.UV_BITS - 1),
                     "NORMAL": 2.0 / (2 ** draco_bits.NORMAL_BITS - 1), "COLOR_0": 1.0 / 255}
            # Draco's decoder takes a quantized value q back as lo + q * range / 2^bits: the top of the
            # range comes back a whole step low, the rest within a step; colours (uint8 in glTF) half a step
            slack = {"POSITION": 1.0, "TEXCOORD_0": 1.0, "NORMAL": 1.0, "COLOR_0": 0.5}
            close = np.ones((rows["POSITION"].shape[0], used.size), bool)  # decoded vertex x plain vertex
            for name in names:
                gap = np.abs(rows[name][:, None, :] - exact[name][used][None, :, :]).max(axis=2)
                close &= gap <= steps[name] * slack[name] * (1 + 1e-6) + 1e-9
            assert close.any(axis=1).all() and (close.sum(axis=1) == 1).all()
            plain_id = used[close.argmax(axis=1)]
            assert np.array_equal(_rolled(plain_id[decoded_faces]), _rolled(faces))
    reports = {kind: validate_with_images(tmp_path / kind) for kind in ("plain", "draco")}
    assert all(r["errors"] == 0 for r in reports["draco"].values()), reports["draco"]
    assert all(reports["draco"][k]["warnings"] <= reports["plain"][k]["warnings"] for k in reports["plain"])
    assert sorted(reports["draco"]["tiles/0.glb"]["images"]) == sorted(reports["plain"]["tiles/0.glb"]["images"])
    assert_matches(tmp_path / "draco", src)


def test_draco_without_dracopy_is_one_line_and_writes_nothing(tmp_path, monkeypatch):
    """Without the DracoPy package (blocked here) `--mesh draco` fails before anything is written:
    one line naming the package and how to install it; an earlier export in the folder stays."""
    h = literal_hlod(normals=True)
    tiles3d.export(h, tmp_path / "tiles")
    before = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*"))
    monkeypatch.setitem(sys.modules, "DracoPy", None)  # `import DracoPy` raises ImportError
    with pytest.raises(InputError, match=r"--mesh draco needs the DracoPy package \(pip install DracoPy"):
        tiles3d.export(h, tmp_path / "tiles", mesh="draco")
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")) == before
    code = ("import sys; sys.modules['DracoPy'] = None; from hlod_core.cli.main import main; "
            f"sys.exit(main(['export', {str(fileformat.save(h, tmp_path / 'lit.hlod'))!r}, '-o', "
            f"{str(tmp_path / 'new')!r}, '--mesh', 'draco']))")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert "DracoPy" in one_line_error(proc) and not (tmp_path / "new").exists()


# --- texture images re-encoded (JPEG, WebP) -------------------------------------------------------

def test_textures_reencoded_as_webp_or_jpeg_are_smaller_valid_and_close(tmp_path, monkeypatch):
    """`export --textures webp`: an opaque 64x64 PNG becomes a smaller WebP bound through
    EXT_texture_webp (required), its pixels within 40 dB PSNR of the PNG's, and so does the 8x8 JPEG;
    the 4x2 PNG with alpha stays as it is (its WebP is not smaller). `--textures jpeg`: the opaque PNG a
    smaller JPEG, the PNG with alpha a PNG (JPEG has no alpha), the JPEG the same bytes (no second
    loss). The glTF validator decodes every image and finds no error or warning. Without Pillow
    (blocked) it is one InputError and nothing is written."""
    from hlod_core.report.image_error import psnr

    png, jpeg = write_textures(tmp_path)
    yy, xx = np.mgrid[0:64, 0:64]
    photo = np.stack([xx * 4, yy * 4, 128 + 100 * np.sin(xx / 5) * np.cos(yy / 7)], axis=2).astype(np.uint8)
    Image.fromarray(photo, "RGB").save(tmp_path / "photo.png")
    h = with_appearance(literal_hlod(normals=True), png, jpeg)
    h = h.replace(materials=(*h.materials[:3], Material("paint", (0.1, 0.6, 0.2, 1.0), 1.0, 0.3,
                                                        str(tmp_path / "photo.png"))))
    files = {}
    for textures in ("original", "webp", "jpeg"):
        summary = last_json(hlod("-q", "export", fileformat.save(h, tmp_path / "lit.hlod"), "-o",
                                 tmp_path / textures, "--textures", textures))
        assert summary["textures"] == textures and summary["warnings"] == []
        files[textures] = {p.name: p.read_bytes() for p in (tmp_path / textures / "textures").iterdir()}
    assert sorted(files["original"]) == ["brick_wall.png", "label.jpg", "photo.png"]
    assert sorted(files["webp"]) == ["brick_wall.png", "label.webp", "photo.webp"]
    assert sorted(files["jpeg"]) == ["brick_wall.png", "label.jpg", "photo.jpg"]
    assert files["jpeg"]["label.jpg"] == files["original"]["label.jpg"]
    assert files["webp"]["brick_wall.png"] == files["original"]["brick_wall.png"]
    for name in ("photo.webp", "photo.jpg"):
        assert len(files[name.split(".")[1].replace("jpg", "jpeg")][name]) < len(files["original"]["photo.png"])
        decoded = np.asarray(Image.open(tmp_path / name.split(".")[1].replace("jpg", "jpeg") / "textures" / name)
                             .convert("RGB"))
        assert float(psnr(photo, decoded)[0]) >= 40.0, name
    for textures in ("webp", "jpeg"):
        report = validate_with_images(tmp_path / textures)
        assert all(r["errors"] == 0 and r["warnings"] == 0 for r in report.values()), report
        read = {uri for r in report.values() for uri in r["images"]}
        assert read == {f"../textures/{name}" for name in files[textures]}, read
        for node in range(h.node_count):
            gltf, _ = read_glb(tmp_path / textures / f"tiles/{node}.glb")
            webp = [row for row in gltf.get("textures", []) if "extensions" in row]
            assert [gltf["images"][row["extensions"]["EXT_texture_webp"]["source"]]["mimeType"] for row in webp] == \
                ["image/webp"] * len(webp)
            assert bool(webp) == ("EXT_texture_webp" in gltf.get("extensionsRequired", [])) == (
                textures == "webp" and any(row["mimeType"] == "image/webp" for row in gltf.get("images", [])))
    assert any("EXT_texture_webp" in read_glb(p)[0].get("extensionsRequired", [])
               for p in (tmp_path / "webp/tiles").glob("*.glb"))
    monkeypatch.setitem(sys.modules, "PIL", None)  # `from PIL import Image` raises ImportError
    with pytest.raises(InputError, match=r"--textures jpeg\|webp needs the Pillow package"):
        tiles3d.export(h, tmp_path / "blocked", textures="webp")
    assert not (tmp_path / "blocked").exists()


def test_a_texture_pillow_cannot_decode_is_one_warning_and_left_out(tmp_path):
    """A file with a PNG signature and a broken body, re-encoded (`--textures webp`): one warning
    naming the file and its material, the material exported without it, the other texture kept."""
    png, jpeg = write_textures(tmp_path)
    broken = tmp_path / "broken.png"
    broken.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 64)
    h = with_appearance(literal_hlod(normals=True), png, jpeg)
    h = h.replace(materials=(*h.materials[:2], Material("label", (1.0, 1.0, 1.0, 1.0), 0.0, 0.5, str(broken)),
                             h.materials[3]))
    summary = tiles3d.export(h, tmp_path / "tiles", textures="webp")
    assert len(summary["warnings"]) == 1 and summary["image_files"] == 1, summary["warnings"]
    assert summary["warnings"][0].startswith(f"{broken}: texture of material 'label' cannot be decoded")
    assert sorted(p.name for p in (tmp_path / "tiles/textures").iterdir()) == ["brick_wall.png"]
