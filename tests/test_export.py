"""3D Tiles export and batch baking from background mode (issue "Batch export ... 3D Tiles"),
checked by independent tools: the Khronos glTF validator for every GLB and CesiumGS 3d-tiles-tools
reading the tileset back (tools/validators/check_tileset.mjs)."""
import json
import os
import struct
import subprocess
import sys

import numpy as np
import pytest

from helpers import ROOT, baked
from hlod_core import fileformat, meshio, tiles3d
from hlod_core.bake import BakeSettings, bake
from test_addon import versioned_repo  # noqa: F401 - the extension installed in each Blender
from test_addon import blender
from test_cli import hlod, last_json, one_line_error

VALIDATORS = ROOT / "tools/validators"


def independent_read(folder) -> dict:
    proc = subprocess.run(["node", str(VALIDATORS / "check_tileset.mjs"), str(folder)], capture_output=True,
                          text=True, timeout=600, cwd=VALIDATORS)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def assert_matches(tiles_dir, hlod_file):
    """Every GLB valid; the reader's tiles are the hierarchy's nodes, with their triangle counts,
    boxes and errors; each parent's geometricError is at least its children's."""
    h = fileformat.load(hlod_file)
    read = independent_read(tiles_dir)
    tiles = read["tiles"]
    assert len(tiles) == h.node_count == sum(1 for t in tiles if t["uri"])
    bad = [(t["uri"], t["messages"]) for t in tiles if t["errors"]]
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
    data = tiles3d.glb_bytes(positions, np.array([[0, 1, 2], [0, 2, 3]]))
    magic, version, total = struct.unpack("<III", data[:12])
    assert (magic, version, total) == (tiles3d.GLB_MAGIC, 2, len(data)) and total % 4 == 0
    json_len, kind = struct.unpack("<II", data[12:20])
    doc = json.loads(data[20:20 + json_len])
    assert kind == tiles3d.CHUNK_JSON and json_len % 4 == 0
    position = doc["accessors"][0]
    # Z up (x, y, z) is written Y up as (x, z, -y): model +y (2) becomes glTF -z, +z (3) glTF +y
    assert position["min"] == [0.0, 0.0, -2.0] and position["max"] == [1.0, 3.0, 0.0]
    assert doc["accessors"][-1]["componentType"] == tiles3d.UNSIGNED_SHORT and "NORMAL" not in doc["meshes"][0][
        "primitives"][0]["attributes"]


def test_export_command_on_shared_model_passes_the_validators(tmp_path):
    _, h = baked("cow.obj", target_tris=500)
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
    mesh = meshio.load_mesh(ROOT.parent / "shared/models/spot.obj")
    p, f = mesh.positions + 1e6, mesh.faces  # a scene placed a million metres away
    e1, e2 = p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]]
    normals = np.zeros_like(p)
    np.add.at(normals, f.ravel(), np.repeat(np.cross(e1, e2), 3, axis=0))
    h = bake(meshio.from_arrays(p, f, normals, name="spot far"), BakeSettings(target_tris=800))
    src = fileformat.save(h, tmp_path / "spot.hlod")
    tiles3d.export(h, tmp_path / "tiles")
    doc = json.loads((tmp_path / "tiles/tileset.json").read_text())
    assert doc["root"]["transform"][12:15] == pytest.approx(list(h.origin))
    glb = (tmp_path / "tiles/tiles/0.glb").read_bytes()
    gltf = json.loads(glb[20:20 + struct.unpack("<I", glb[12:16])[0]])
    assert "NORMAL" in gltf["meshes"][0]["primitives"][0]["attributes"]
    assert max(abs(v) for v in gltf["accessors"][0]["max"]) < 10  # origin-relative, not 1e6
    assert_matches(tmp_path / "tiles", src)


def test_export_refuses_to_replace_a_foreign_folder(tmp_path):
    _, h = baked("cow.obj", target_tris=500)
    src = fileformat.save(h, tmp_path / "cow.hlod")
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep me")
    assert "holds no tileset.json; not replacing it" in one_line_error(
        hlod("export", src, "--format", "3dtiles", "-o", tmp_path / "mine", check=False))
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep me"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.blender
def test_background_batch_over_blend_files(versioned_repo, tmp_path):  # noqa: F811
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


def test_empty_leaves_are_absent_and_inner_nodes_without_triangles_keep_their_children():
    _, h = baked("cow.obj", target_tris=500)
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


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_export_modes_follow_the_umask(tmp_path, umask):
    """Issue 11: the tileset folder came out 0700 (mkdtemp's mode) whatever the umask; now folders
    are 0777 and files 0666 less the umask, like any other tool's output, also when replacing."""
    _, h = baked("cow.obj", target_tris=500)
    old = os.umask(umask)
    try:
        for _ in range(2):  # a fresh export, then one replacing it
            tiles3d.export(h, tmp_path / "tiles")
            folders = [tmp_path / "tiles", tmp_path / "tiles" / "tiles"]
            files = [tmp_path / "tiles" / "tileset.json", *(tmp_path / "tiles" / "tiles").iterdir()]
            assert {oct(p.stat().st_mode & 0o777) for p in folders} == {oct(0o777 & ~umask)}
            assert {oct(p.stat().st_mode & 0o777) for p in files} == {oct(0o666 & ~umask)}
    finally:
        os.umask(old)
