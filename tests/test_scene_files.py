"""Scene files with appearance: glTF/GLB read as scenes, OBJ with its MTL, PLY colours.

The textured scene (tests/scenes/textured_scene.py) is made in the bpy module and written by
Blender's own glTF and OBJ exporters; what our readers find is compared with what Blender's own
importers find in the same files (a bpy subprocess) and with the generator's facts (scene.json,
from Blender's evaluated depsgraph). A tiny glTF written here by hand pins the scene rules: nodes
of the default scene only, parents applied, a mesh shared by two nodes placed twice, a mirroring
node flipping the winding, TEXCOORD_0's v flipped, COLOR_0 normalized.
"""
import base64
import io
import json
import logging
import os
import signal
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from helpers import ROOT, file_bytes, model, textured_scene
from hlod_core.bake.pipeline import BakeSettings, bake
from hlod_core.cli import main as cli
from hlod_core.core.errors import InputError
from hlod_core.io import hlod_file, meshes

#: Positions agree to float32 precision of the files (coordinates up to 40 units).
POSITION_TOL = 1e-4
#: UVs agree to float32 precision.
UV_TOL = 1e-5


def _to_blender_axes(p: np.ndarray) -> np.ndarray:
    """Blender's OBJ exporter's +Y up to Blender's +Z up: (x, y, z) -> (x, -z, y). (The glTF reader
    does this itself: glTF defines its up axis, OBJ does not.)"""
    return np.stack([p[:, 0], -p[:, 2], p[:, 1]], axis=1)


# --- what Blender's own importers find ----------------------------------------------------------

BLENDER_IMPORT = r"""
import json, sys
import bpy
import numpy as np

out = {}
for kind, path in (("glb", sys.argv[1]), ("obj", sys.argv[2])):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    if kind == "glb":
        bpy.ops.import_scene.gltf(filepath=path)
    else:
        bpy.ops.wm.obj_import(filepath=path)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    per = {}
    total = 0
    for obj in bpy.context.scene.objects:
        if obj.type != "MESH":
            continue
        ev = obj.evaluated_get(depsgraph)
        me = ev.to_mesh()
        n = len(me.loop_triangles)
        total += n
        co = np.empty(len(me.vertices) * 3); me.vertices.foreach_get("co", co)
        world = np.array(ev.matrix_world)
        co = co.reshape(-1, 3) @ world[:3, :3].T + world[:3, 3]
        verts = np.empty(n * 3, np.int32); me.loop_triangles.foreach_get("vertices", verts)
        loops = np.empty(n * 3, np.int32); me.loop_triangles.foreach_get("loops", loops)
        slots = np.empty(n, np.int32); me.loop_triangles.foreach_get("material_index", slots)
        uv = None
        if me.uv_layers.active is not None:
            uv = np.empty(len(me.loops) * 2); me.uv_layers.active.data.foreach_get("uv", uv)
            uv = uv.reshape(-1, 2)[loops].reshape(-1, 3, 2)
        p = co[verts].reshape(-1, 3, 3)
        names = [m.name if m is not None else "" for m in me.materials]
        for slot in np.unique(slots):
            pick = slots == slot
            d = per.setdefault(names[slot], {"tris": 0, "lo": [1e30] * 3, "hi": [-1e30] * 3, "uv_sum": [0.0, 0.0],
                                             "uv_lo": [1e30] * 2, "uv_hi": [-1e30] * 2, "uv_corners": 0})
            d["tris"] += int(pick.sum())
            d["lo"] = np.minimum(d["lo"], p[pick].reshape(-1, 3).min(0)).tolist()
            d["hi"] = np.maximum(d["hi"], p[pick].reshape(-1, 3).max(0)).tolist()
            if uv is not None:
                corners = uv[pick].reshape(-1, 2)
                d["uv_sum"] = (np.array(d["uv_sum"]) + corners.sum(0)).tolist()
                d["uv_corners"] += corners.shape[0]
                d["uv_lo"] = np.minimum(d["uv_lo"], corners.min(0)).tolist()
                d["uv_hi"] = np.maximum(d["uv_hi"], corners.max(0)).tolist()
        ev.to_mesh_clear()
    out[kind] = {"triangles": total, "materials": per}
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def scene():
    return textured_scene("small")


@pytest.fixture(scope="module")
def blender_import(scene):
    """Blender's own import of the scene's GLB and OBJ (the bpy module in a subprocess)."""
    run = subprocess.run([sys.executable, "-c", BLENDER_IMPORT, str(scene["glb"]), str(scene["obj"])],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def ours(scene, tmp_path_factory):
    textures = tmp_path_factory.mktemp("embedded")
    return {"glb": meshes.load_mesh(scene["glb"], texture_dir=textures),
            "obj": meshes.load_mesh(scene["obj"]), "textures": textures}


def _per_material(mesh: meshes.TriangleMesh, *, y_up: bool) -> dict:
    out = {}
    corners = mesh.positions[mesh.faces]
    for i, material in enumerate(mesh.materials):
        pick = mesh.material_ids == i
        p = corners[pick].reshape(-1, 3)
        p = _to_blender_axes(p) if y_up else p
        uv = mesh.uvs[mesh.faces[pick]].reshape(-1, 2).astype(np.float64)
        out[material.name] = {"tris": int(pick.sum()), "lo": p.min(0), "hi": p.max(0), "uv_mean": uv.mean(0),
                              "uv_lo": uv.min(0), "uv_hi": uv.max(0)}
    return out


@pytest.mark.blender
@pytest.mark.parametrize("kind", ["glb", "obj"])
def test_triangles_and_materials_match_blenders_import_and_the_generator(kind, scene, blender_import, ours):
    """Triangle count = Blender's import of the same file = the generator's depsgraph count, per
    material too; each material's world bounding box matches Blender's import (so node
    transforms, parents and the linked duplicates are placed as Blender places them)."""
    facts, theirs, mesh = scene["facts"], blender_import[kind], ours[kind]
    assert mesh.tri_count == theirs["triangles"] == facts["triangles"]
    assert len(mesh.materials) == len(theirs["materials"]) == facts["materials"]
    mine = _per_material(mesh, y_up=kind == "obj")
    assert {k: v["tris"] for k, v in mine.items()} == {k: v["tris"] for k, v in theirs["materials"].items()} \
        == facts["triangles_per_material"]
    for name, m in mine.items():
        np.testing.assert_allclose(m["lo"], theirs["materials"][name]["lo"], atol=POSITION_TOL, err_msg=name)
        np.testing.assert_allclose(m["hi"], theirs["materials"][name]["hi"], atol=POSITION_TOL, err_msg=name)


@pytest.mark.blender
@pytest.mark.parametrize("kind", ["glb", "obj"])
def test_uvs_match_blenders_import(kind, blender_import, ours):
    """UVs in Blender's convention: each material's UV range matches Blender's import (a v left
    as glTF stores it would come out mirrored); for the GLB, whose triangles are fixed by the
    file, the mean UV over all triangle corners matches too."""
    mine, theirs = _per_material(ours[kind], y_up=kind == "obj"), blender_import[kind]["materials"]
    for name, m in mine.items():
        t = theirs[name]
        np.testing.assert_allclose(m["uv_lo"], t["uv_lo"], atol=UV_TOL, err_msg=name)
        np.testing.assert_allclose(m["uv_hi"], t["uv_hi"], atol=UV_TOL, err_msg=name)
        assert np.all(m["uv_lo"] >= -UV_TOL) and np.all(m["uv_hi"] <= 1 + UV_TOL), name
        if kind == "glb":
            np.testing.assert_allclose(m["uv_mean"], np.array(t["uv_sum"]) / t["uv_corners"], atol=UV_TOL,
                                       err_msg=name)


@pytest.mark.parametrize("kind", ["glb", "obj"])
def test_ground_uvs_follow_the_grid(kind, ours):
    """Blender's grid primitive maps its 80 x 80 square to [0, 1]^2: u = (x + 40) / 80 and
    v = (y_blender + 40) / 80: y_blender is the GLB as read (Blender's axes) and -z in the OBJ's
    +Y-up axes. Pins the v flip, and that the GLB comes out in Blender's axes."""
    mesh = ours[kind]
    ground = np.unique(mesh.faces[mesh.material_ids == [m.name for m in mesh.materials].index("Ground")])
    p, uv = mesh.positions[ground], mesh.uvs[ground]
    y_blender = p[:, 1] if kind == "glb" else -p[:, 2]
    np.testing.assert_allclose(uv[:, 0], (p[:, 0] + 40.0) / 80.0, atol=UV_TOL)
    np.testing.assert_allclose(uv[:, 1], (y_blender + 40.0) / 80.0, atol=UV_TOL)
    assert np.ptp(p[:, 2]) < 1e-3 * np.ptp(p[:, 0]) if kind == "glb" else np.ptp(p[:, 1]) < 1e-3 * np.ptp(p[:, 0])


def test_glb_appearance(scene, ours):
    """Materials as Blender's exporter wrote them: textures for Ground, Wall, Monkey written once
    each from the GLB with their original bytes; Roof's factors; COLOR_0 colours on the ground
    and monkeys, white where the file has none (the houses); the stored normals agree with the
    winding on every triangle (the mirrored house included)."""
    mesh = ours["glb"]
    by_name = {m.name: m for m in mesh.materials}
    assert sorted(m for m in by_name if by_name[m].texture) == scene["facts"]["textured_materials"]
    written = sorted(p.name for p in ours["textures"].iterdir())
    assert len(written) == 3
    for name, png in (("Ground", "checker.png"), ("Wall", "bricks.png"), ("Monkey", "color_grid.png")):
        assert open(by_name[name].texture, "rb").read() == (scene["textures"] / png).read_bytes()
    roof = by_name["Roof"]
    np.testing.assert_allclose(roof.base_color, (0.45, 0.08, 0.05, 1.0), atol=1e-6)
    assert roof.metallic == pytest.approx(0.1) and roof.roughness == pytest.approx(0.7)
    house = np.isin(mesh.material_ids, [i for i, m in enumerate(mesh.materials) if m.name in ("Wall", "Roof")])
    house_vertices = np.unique(mesh.faces[house])
    other = np.setdiff1d(np.arange(mesh.positions.shape[0]), house_vertices)
    assert np.all(mesh.colors[house_vertices] == 1.0)
    assert mesh.colors[other, :3].std(axis=0).min() > 0.05  # varying colours
    t = mesh.positions[mesh.faces]
    geometric = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    assert np.all(np.einsum("ij,ij->i", geometric, mesh.normals[mesh.faces].sum(axis=1)) > 0)


def test_separate_gltf_refers_to_its_image_files(scene, ours):
    """The same export as .gltf with an external .bin and PNG files: the same triangles and
    materials as the GLB, the textures the exporter's files themselves (nothing written)."""
    mesh = meshes.load_mesh(scene["gltf"])
    glb = ours["glb"]
    assert mesh.tri_count == glb.tri_count == scene["facts"]["triangles"]
    np.testing.assert_array_equal(mesh.positions, glb.positions)
    np.testing.assert_array_equal(mesh.uvs, glb.uvs)
    folder = scene["gltf"].parent / "textures"
    assert [m.texture for m in mesh.materials] == [None if m.texture is None else str(folder / Path(m.texture).name
                                                   .rsplit("-", 1)[0]) + ".png" for m in glb.materials]


def test_the_textured_scenes_glb_is_read_whole(scene, ours):
    """The textured scene's file shape (a ground grid, 16 linked duplicates of a two-material house,
    subdivided monkeys, from Blender's glTF exporter): pymeshlab read one monkey of it (3,936 of
    49,856 triangles here; 15,744 of 283,880 at full scale), silently. Every triangle now."""
    assert ours["glb"].tri_count == scene["facts"]["triangles"]
    assert meshes.load_inputs([scene["glb"]]).tri_count == scene["facts"]["triangles"]


# --- a glTF written by hand ----------------------------------------------------------------------

def _png(rgb=(255, 0, 0)) -> bytes:
    out = io.BytesIO()
    Image.new("RGB", (2, 2), rgb).save(out, format="PNG")
    return out.getvalue()


def _hand_gltf(*, image: str = "buffer") -> dict:
    """One triangle mesh (with a points and a line-loop primitive before it, which have no
    triangles) used by node 0 (translated) and node 1 (mirrored: scale x -1) under node 2 (a
    matrix: turn 90 degrees about z, move +5 y); node 3 uses it too but is only in scene 1,
    which is not the default. TEXCOORD_0 as glTF stores it (v down); COLOR_0 normalized bytes."""
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    normals = np.array([[0, 0, 1]] * 3, np.float32)
    uvs = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 0.25]], np.float32)
    colors = np.array([[255, 0, 0, 255], [0, 128, 0, 255], [0, 0, 255, 51]], np.uint8)
    indices = np.array([0, 1, 2, 0], np.uint16)  # padded to 4 bytes; the accessor reads 3
    png = _png()
    chunks = [positions.tobytes(), normals.tobytes(), uvs.tobytes(), colors.tobytes(), indices.tobytes(),
              png + b"\0" * (-len(png) % 4)]
    offsets = np.concatenate([[0], np.cumsum([len(c) for c in chunks])]).tolist()
    buffer = b"".join(chunks)
    views = [{"buffer": 0, "byteOffset": offsets[i], "byteLength": len(chunks[i])} for i in range(5)]
    views.append({"buffer": 0, "byteOffset": offsets[5], "byteLength": len(png)})
    FLOAT, UBYTE, USHORT = 5126, 5121, 5123
    accessors = [{"bufferView": 0, "componentType": FLOAT, "count": 3, "type": "VEC3", "min": [0, 0, 0],
                  "max": [1, 1, 0]},
                 {"bufferView": 1, "componentType": FLOAT, "count": 3, "type": "VEC3"},
                 {"bufferView": 2, "componentType": FLOAT, "count": 3, "type": "VEC2"},
                 {"bufferView": 3, "componentType": UBYTE, "normalized": True, "count": 3, "type": "VEC4"},
                 {"bufferView": 4, "componentType": USHORT, "count": 3, "type": "SCALAR"}]
    turn = np.array([[0, -1, 0, 0], [1, 0, 0, 5], [0, 0, 1, 0], [0, 0, 0, 1]], float)
    images = {"buffer": [{"bufferView": 5, "mimeType": "image/png", "name": "red"}],
              "data": [{"uri": "data:image/png;base64," + base64.b64encode(png).decode(), "name": "red"}],
              "file": [{"uri": "red%20tex.png"}], "missing": [{"uri": "nowhere.png"}]}[image]
    return {
        "asset": {"version": "2.0"}, "scene": 0,
        "scenes": [{"nodes": [0, 2]}, {"nodes": [3]}],
        "nodes": [{"mesh": 0, "translation": [10, 0, 0], "name": "plain"},
                  {"mesh": 0, "scale": [-1, 1, 1], "name": "mirrored"},
                  {"children": [1], "matrix": turn.T.ravel().tolist(), "name": "parent"},
                  {"mesh": 0, "name": "other scene"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "mode": 0},
                                   {"attributes": {"POSITION": 0}, "mode": 2},
                                   {"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2, "COLOR_0": 3},
                                    "indices": 4, "material": 0}]}],
        "materials": [{"name": "Red", "pbrMetallicRoughness": {
            "baseColorFactor": [0.5, 0.25, 1, 1], "metallicFactor": 0.2, "roughnessFactor": 0.3,
            "baseColorTexture": {"index": 0}}}],
        "textures": [{"source": 0}], "images": images,
        "buffers": [{"byteLength": len(buffer), "uri": "data:application/octet-stream;base64,"
                     + base64.b64encode(buffer).decode()}],
        "bufferViews": views, "accessors": accessors}


def _write_gltf(path, gltf: dict):
    path.write_text(json.dumps(gltf))
    return path


def _glb(gltf: dict) -> bytes:
    """The same scene as GLB: the data-URI buffer moved into the BIN chunk."""
    gltf = json.loads(json.dumps(gltf))
    binary = base64.b64decode(gltf["buffers"][0].pop("uri").split(",", 1)[1])
    text = json.dumps(gltf).encode()
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


@pytest.mark.parametrize("container", ["gltf", "glb"])
def test_hand_written_scene_places_the_shared_mesh_per_node(tmp_path, container):
    """2 triangles: the mesh once per node of the default scene (not node 3 of scene 1, nor the
    points and line loop), at each node's world transform (node 1 through its parent's matrix),
    the mirrored copy with its winding flipped so that it faces +z like its normals; all in
    Blender's axes ((x, y, z) of the file -> (x, -z, y))."""
    gltf = _hand_gltf()
    path = tmp_path / f"hand.{container}"
    if container == "glb":
        path.write_bytes(_glb(gltf))
    else:
        _write_gltf(path, gltf)
    mesh = meshes.load_mesh(path, texture_dir=tmp_path / "textures")
    assert mesh.tri_count == 2
    corners = mesh.positions[mesh.faces]
    plain = _to_blender_axes(np.array([[10, 0, 0], [11, 0, 0], [10, 1, 0]], float))
    mirrored = _to_blender_axes(np.array([[0, 5, 0], [0, 4, 0], [-1, 5, 0]], float))  # x -> -x, 90 about z, +5 y
    found = sorted(corners.tolist(), key=lambda t: t[0][0])
    assert sorted(map(tuple, found[1])) == sorted(map(tuple, plain))
    assert sorted(map(tuple, found[0])) == sorted(map(tuple, mirrored))
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    np.testing.assert_allclose(normal, [[0, -1, 0], [0, -1, 0]], atol=1e-12)  # both face the file's +z
    np.testing.assert_allclose(mesh.normals[mesh.faces].reshape(-1, 3), [[0, -1, 0]] * 6, atol=1e-6)
    # appearance: v flipped, colours normalized, the material's factors and its image
    by_corner = {tuple(np.round(p, 6)): (uv, c) for p, uv, c in zip(mesh.positions, mesh.uvs, mesh.colors)}
    uv, color = by_corner[(11.0, 0.0, 0.0)]
    np.testing.assert_allclose(uv, [1.0, 1.0])
    np.testing.assert_allclose(color, [0.0, 128 / 255, 0.0, 1.0], atol=1e-6)
    uv, color = by_corner[(10.0, 0.0, 1.0)]
    np.testing.assert_allclose(uv, [0.0, 0.75])
    np.testing.assert_allclose(color, [0.0, 0.0, 1.0, 0.2], atol=1e-6)
    (material,) = mesh.materials
    assert (material.name, material.metallic, material.roughness) == ("Red", pytest.approx(0.2), pytest.approx(0.3))
    np.testing.assert_allclose(material.base_color, [0.5, 0.25, 1.0, 1.0])
    written = list((tmp_path / "textures").iterdir())
    assert len(written) == 1 and written[0].read_bytes() == _png() and material.texture == str(written[0])


def test_image_sources_and_missing_images(tmp_path, caplog):
    """An image by data URI is written like one in a buffer view; one by URI is the file itself
    (URI-decoded, relative to the .gltf); a missing file or no texture folder: a warning naming
    it, and the material without its texture."""
    data = meshes.load_mesh(_write_gltf(tmp_path / "data.gltf", _hand_gltf(image="data")), texture_dir=tmp_path / "t")
    assert open(data.materials[0].texture, "rb").read() == _png()
    (tmp_path / "red tex.png").write_bytes(_png((0, 9, 0)))
    by_file = meshes.load_mesh(_write_gltf(tmp_path / "file.gltf", _hand_gltf(image="file")))
    assert by_file.materials[0].texture == str((tmp_path / "red tex.png").resolve())
    with caplog.at_level(logging.WARNING):
        missing = meshes.load_mesh(_write_gltf(tmp_path / "missing.gltf", _hand_gltf(image="missing")))
        no_folder = meshes.load_mesh(_write_gltf(tmp_path / "embedded.gltf", _hand_gltf(image="buffer")))
    assert missing.materials[0].texture is None and no_folder.materials[0].texture is None
    assert missing.tri_count == no_folder.tri_count == 2
    assert "nowhere.png is missing" in caplog.text and "no texture folder was given" in caplog.text


@pytest.mark.parametrize("damage, message", [
    (lambda b: b[:40], "truncated GLB"),
    (lambda b: b"glTF" + struct.pack("<I", 1) + b[8:], "not a glTF 2.0 GLB"),
    (lambda b: b[:20] + b"{not json" + b[29:], "JSON cannot be read"),
])
def test_malformed_glb_is_one_clear_error(tmp_path, damage, message):
    path = tmp_path / "bad.glb"
    path.write_bytes(damage(_glb(_hand_gltf())))
    with pytest.raises(InputError, match=message) as err:
        meshes.load_mesh(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_gltf_alpha_modes_are_read(tmp_path):
    """alphaMode and alphaCutoff reach the material (MASK with its cutoff, BLEND; OPAQUE and 0.5 when
    absent); a mode glTF does not define (trimesh refuses the file), or a cutoff outside [0, 1], is
    refused naming the file."""
    found = {}
    for mode, cutoff in (("MASK", 0.3), ("BLEND", None), (None, None)):
        gltf = _hand_gltf()
        gltf["materials"][0].update({k: v for k, v in (("alphaMode", mode), ("alphaCutoff", cutoff)) if v is not None})
        mesh = meshes.load_mesh(_write_gltf(tmp_path / f"{mode}.gltf", gltf), texture_dir=tmp_path / "t")
        (material,) = mesh.materials
        found[mode] = (material.alpha_mode, material.alpha_cutoff)
    assert found == {"MASK": ("MASK", pytest.approx(0.3)), "BLEND": ("BLEND", 0.5), None: ("OPAQUE", 0.5)}
    for field, value, message in (("alphaMode", "CUTOUT", r"not a readable glTF file .*alphaMode.*CUTOUT"),
                                  ("alphaCutoff", 2, r"materials\[0\]\.alphaCutoff must be a number in \[0, 1\]"),
                                  ("alphaCutoff", "half", r"not a readable glTF file .*half")):
        gltf = _hand_gltf()
        gltf["materials"][0][field] = value
        with pytest.raises(InputError, match=message):
            meshes.load_mesh(_write_gltf(tmp_path / "bad.gltf", gltf), texture_dir=tmp_path / "t")


def test_malformed_gltf_parts_are_named(tmp_path):
    gltf = _hand_gltf()
    gltf["nodes"][0]["rotation"] = [0, 0, 0]
    with pytest.raises(InputError, match=r"nodes\[0\]\.rotation must be 4 finite numbers"):
        meshes.load_mesh(_write_gltf(tmp_path / "rot.gltf", gltf))
    gltf = _hand_gltf()
    gltf["nodes"][1]["children"] = [2]  # a cycle: 2 -> 1 -> 2
    with pytest.raises(InputError, match="deeper than"):
        meshes.load_mesh(_write_gltf(tmp_path / "cycle.gltf", gltf))
    gltf = _hand_gltf()
    gltf["meshes"][0]["primitives"][2]["mode"] = 6
    with pytest.raises(InputError, match="triangle fan"):
        meshes.load_mesh(_write_gltf(tmp_path / "fan.gltf", gltf))
    gltf = _hand_gltf()
    gltf["bufferViews"][0]["extensions"] = {"EXT_meshopt_compression": {}}
    with pytest.raises(InputError, match="meshopt-compressed buffers"):
        meshes.load_mesh(_write_gltf(tmp_path / "meshopt.gltf", gltf))


def _with_gpu_instances(gltf: dict, translations, rotations_i16, scales) -> dict:
    """The hand-written glTF with node 0 instanced by EXT_mesh_gpu_instancing: per instance a
    float translation, a rotation as normalized int16 (x, y, z, w) and a float scale, in a second
    buffer (a data URI) with a byteStride on the rotations' view."""
    t = np.asarray(translations, np.float32)
    r = np.asarray(rotations_i16, np.int16)
    r_padded = np.zeros((len(r), 6), np.int16)  # 12-byte stride: 8 bytes of rotation, 4 of padding
    r_padded[:, :4] = r
    sc = np.asarray(scales, np.float32)
    blob = t.tobytes() + r_padded.tobytes() + sc.tobytes()
    buffer = len(gltf["buffers"])
    gltf["buffers"].append({"byteLength": len(blob),
                            "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()})
    first_view, first_accessor = len(gltf["bufferViews"]), len(gltf["accessors"])
    gltf["bufferViews"] += [{"buffer": buffer, "byteOffset": 0, "byteLength": t.nbytes},
                            {"buffer": buffer, "byteOffset": t.nbytes, "byteLength": r_padded.nbytes, "byteStride": 12},
                            {"buffer": buffer, "byteOffset": t.nbytes + r_padded.nbytes, "byteLength": sc.nbytes}]
    gltf["accessors"] += [{"bufferView": first_view, "componentType": 5126, "count": len(t), "type": "VEC3"},
                          {"bufferView": first_view + 1, "componentType": 5122, "normalized": True, "count": len(r),
                           "type": "VEC4"},
                          {"bufferView": first_view + 2, "componentType": 5126, "count": len(sc), "type": "VEC3"}]
    gltf["nodes"][0]["extensions"] = {"EXT_mesh_gpu_instancing": {"attributes": {
        "TRANSLATION": first_accessor, "ROTATION": first_accessor + 1, "SCALE": first_accessor + 2}}}
    gltf["extensionsUsed"] = ["EXT_mesh_gpu_instancing"]
    return gltf


BLENDER_TRIANGLES = r"""
import json, sys
import bpy
import numpy as np

bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_scene.gltf(filepath=sys.argv[1])
depsgraph = bpy.context.evaluated_depsgraph_get()
corners = []
for inst in depsgraph.object_instances:
    if inst.object.type != "MESH":
        continue
    me = inst.object.to_mesh()
    co = np.empty(len(me.vertices) * 3); me.vertices.foreach_get("co", co)
    world = np.array(inst.matrix_world)
    co = co.reshape(-1, 3) @ world[:3, :3].T + world[:3, 3]
    verts = np.empty(len(me.loop_triangles) * 3, np.int32); me.loop_triangles.foreach_get("vertices", verts)
    corners += co[verts].tolist()
    inst.object.to_mesh_clear()
print(json.dumps(corners))
"""


@pytest.mark.blender
def test_gpu_instances_are_where_blenders_importer_places_them(tmp_path):
    """The instanced glTF read by Blender's own importer (the main environment's bpy, a subprocess):
    the same triangles at the same places (Blender's axes both), the instances included."""
    quarter = round(32767 * np.sqrt(0.5))
    gltf = _with_gpu_instances(_hand_gltf(), translations=[[0, 0, 0], [0, 0, 3], [5, 0, 0]],
                               rotations_i16=[[0, 0, 0, 32767], [0, 0, quarter, quarter], [0, 0, 0, 32767]],
                               scales=[[1, 1, 1], [1, 1, 1], [2, 2, 2]])
    gltf["scenes"], gltf["nodes"] = gltf["scenes"][:1], gltf["nodes"][:3]  # Blender 4.2 imports nodes of no scene too
    path = tmp_path / "instanced.gltf"
    _write_gltf(path, gltf)
    run = subprocess.run([sys.executable, "-c", BLENDER_TRIANGLES, str(path)], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    theirs = np.array(json.loads(run.stdout.strip().splitlines()[-1]), float).reshape(-1, 9)
    mesh = meshes.load_mesh(path, texture_dir=tmp_path / "textures")
    mine = mesh.positions[mesh.faces].reshape(-1, 9).astype(float)
    assert mine.shape == theirs.shape == (4, 9)

    def canonical(tris):  # each triangle's corners in a fixed order, then the triangles sorted
        corners = np.round(tris.reshape(-1, 3, 3), 5)
        corners = np.array([c[np.lexsort(c.T[::-1])] for c in corners]).reshape(-1, 9)
        return corners[np.lexsort(corners.T[::-1])]

    assert np.allclose(canonical(mine), canonical(theirs), atol=1e-4)


@pytest.mark.parametrize("container", ["gltf", "glb"])
def test_gpu_instances_are_placed_each(tmp_path, container, caplog):
    """EXT_mesh_gpu_instancing: node 0's triangle once per instance, at the node's matrix times the
    instance's T * R * S (the rotation a normalized int16 quaternion read through a byteStride),
    with no warning; node 1 is placed once as before."""
    quarter = round(32767 * np.sqrt(0.5))  # 90 degrees about z
    gltf = _with_gpu_instances(_hand_gltf(), translations=[[0, 0, 0], [0, 0, 3], [5, 0, 0]],
                               rotations_i16=[[0, 0, 0, 32767], [0, 0, quarter, quarter], [0, 0, 0, 32767]],
                               scales=[[1, 1, 1], [1, 1, 1], [2, 2, 2]])
    path = tmp_path / f"instanced.{container}"
    if container == "glb":
        gltf["buffers"] = [gltf["buffers"][0]]  # the GLB holds one buffer: move the instances into it
        first = base64.b64decode(_hand_gltf()["buffers"][0]["uri"].split(",", 1)[1])
        extra = base64.b64decode(_with_gpu_instances(_hand_gltf(), [[0, 0, 0], [0, 0, 3], [5, 0, 0]],
                                                     [[0, 0, 0, 32767], [0, 0, quarter, quarter], [0, 0, 0, 32767]],
                                                     [[1, 1, 1], [1, 1, 1], [2, 2, 2]])["buffers"][1]["uri"]
                                 .split(",", 1)[1])
        gltf["buffers"][0] = {"byteLength": len(first) + len(extra), "uri": "data:application/octet-stream;base64,"
                              + base64.b64encode(first + extra).decode()}
        for view in gltf["bufferViews"][-3:]:
            view["buffer"], view["byteOffset"] = 0, view["byteOffset"] + len(first)
        path.write_bytes(_glb(gltf))
    else:
        _write_gltf(path, gltf)
    with caplog.at_level(logging.WARNING):
        mesh = meshes.load_mesh(path, texture_dir=tmp_path / "textures")
    assert mesh.tri_count == 4 and "EXT_mesh_gpu_instancing" not in caplog.text
    triangle = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    node = np.array([10.0, 0.0, 0.0])
    turned = triangle @ np.array([[0, 1, 0], [-1, 0, 0], [0, 0, 1]], float)  # (x, y) -> (-y, x)
    expected = [triangle + node, turned + node + [0, 0, 3], 2 * triangle + node + [5, 0, 0]]
    found = {tuple(sorted(map(tuple, np.round(t, 4)))) for t in mesh.positions[mesh.faces]}
    for corners in expected:
        assert tuple(sorted(map(tuple, np.round(_to_blender_axes(corners), 4)))) in found


def test_gltf_extensions_are_named_never_ignored(tmp_path, caplog):
    """An extension the file requires and the reader does not read: refused in one line naming it;
    one it only uses: read, with one warning naming it; an appearance-only one: no warning."""
    gltf = _hand_gltf()
    gltf["extensionsUsed"] = gltf["extensionsRequired"] = ["KHR_mesh_quantization", "EXT_made_up"]
    with pytest.raises(InputError) as err:
        meshes.load_mesh(_write_gltf(tmp_path / "required.gltf", gltf))
    assert str(err.value).endswith("requires EXT_made_up, KHR_mesh_quantization, which this reader does not read")
    assert "\n" not in str(err.value)
    gltf = _hand_gltf()
    gltf["extensionsUsed"] = ["EXT_made_up", "KHR_materials_emissive_strength"]
    with caplog.at_level(logging.WARNING):
        mesh = meshes.load_mesh(_write_gltf(tmp_path / "used.gltf", gltf))
    assert mesh.tri_count == 2
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert [w for w in warnings if "EXT_made_up" in w] == [
        f"{tmp_path / 'used.gltf'}: uses EXT_made_up, which this reader does not read; where it changes "
        "geometry, the bake leaves that out"]
    assert not any("KHR_materials_emissive_strength" in w for w in warnings)


def test_malformed_gpu_instances_are_named(tmp_path):
    """Attributes of different lengths, an accessor index outside the file: one line naming the part."""
    gltf = _with_gpu_instances(_hand_gltf(), [[0, 0, 0], [1, 0, 0]], [[0, 0, 0, 32767]], [[1, 1, 1]])
    with pytest.raises(InputError, match=r"EXT_mesh_gpu_instancing\.attributes give different instance counts"):
        meshes.load_mesh(_write_gltf(tmp_path / "counts.gltf", gltf))
    gltf = _with_gpu_instances(_hand_gltf(), [[0, 0, 0], [1, 0, 0]], [[0, 0, 0, 32767]] * 2, [[1, 1, 1]] * 2)
    gltf["nodes"][0]["extensions"]["EXT_mesh_gpu_instancing"]["attributes"]["ROTATION"] = 99
    with pytest.raises(InputError, match=r"EXT_mesh_gpu_instancing\.attributes\.ROTATION 99 is not one of"):
        meshes.load_mesh(_write_gltf(tmp_path / "bad_index.gltf", gltf))


def test_gltf_without_trimesh_is_one_clear_error_and_obj_still_reads(tmp_path):
    """trimesh is the command line's dependency: without it (as inside Blender) a glTF file is
    refused in one line, and everything else reads as before (the glTF reader is importable)."""
    path = _write_gltf(tmp_path / "hand.gltf", _hand_gltf())
    obj = _textured_obj(tmp_path)
    code = ("import sys; sys.modules['trimesh'] = None\n"
            "from hlod_core.io import meshes\nfrom hlod_core.core.errors import InputError\n"
            f"print(meshes.load_mesh({str(obj)!r}).tri_count)\n"
            f"try:\n    meshes.load_mesh({str(path)!r})\nexcept InputError as e:\n    print('refused:', e)\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.splitlines() == ["2", f"refused: {path}: reading glTF needs trimesh, a dependency of the "
                                            "command line (pip install -r requirements.txt)"]


# --- OBJ with MTL, PLY colours --------------------------------------------------------------------

def _textured_obj(folder, *, mtl: str | None = None, texture: bool = True):
    (folder / "scene.mtl").write_text(mtl if mtl is not None else (
        "newmtl Brick\nKd 0.9 0.9 0.9\nmap_Kd -s 2 2 1 tex/brick.png\n\n"
        "newmtl Paint # comment\nKd 0.2 0.4 0.6\nd 0.5\nNs 250\n"))
    if texture:
        (folder / "tex").mkdir(exist_ok=True)
        (folder / "tex" / "brick.png").write_bytes(_png())
    path = folder / "scene.obj"
    path.write_text("mtllib scene.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
                    "vt 0.5 0.5\nusemtl Brick\nf 1/1 2/2 3/3\nusemtl Paint\nf 1/5 3/3 4/4\n")
    return path


def test_obj_with_mtl(tmp_path):
    """Kd, d, Ns (roughness = 1 - sqrt(Ns / 1000), Blender's exporter's rule), map_Kd after its
    options, relative to the MTL; vt per corner (vertex 1 has two UVs: split); usemtl groups."""
    mesh = meshes.load_mesh(_textured_obj(tmp_path))
    assert mesh.tri_count == 2 and mesh.positions.shape[0] == 5  # vertex 1 split by its two UVs
    brick, paint = mesh.materials
    assert brick.texture == str((tmp_path / "tex" / "brick.png").resolve()) and brick.base_color == (1, 1, 1, 1)
    assert paint.texture is None and paint.base_color == pytest.approx((0.2, 0.4, 0.6, 0.5))
    assert paint.roughness == pytest.approx(0.5)
    assert mesh.material_ids.tolist() == [0, 1]
    uv_of = {(tuple(p), tuple(uv)) for p, uv in zip(mesh.positions.tolist(), mesh.uvs.tolist())}
    assert ((0.0, 0.0, 0.0), (0.0, 0.0)) in uv_of and ((0.0, 0.0, 0.0), (0.5, 0.5)) in uv_of


def test_obj_missing_texture_or_mtl_warns_and_reads(tmp_path, caplog):
    with caplog.at_level(logging.WARNING):
        mesh = meshes.load_mesh(_textured_obj(tmp_path, texture=False))
    assert mesh.materials[0].texture is None and "brick.png of material Brick is missing" in caplog.text
    (tmp_path / "scene.mtl").unlink()
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        mesh = meshes.load_mesh(tmp_path / "scene.obj")
    assert "scene.mtl: material library missing" in caplog.text
    assert [m.name for m in mesh.materials] == ["Brick", "Paint"] and mesh.tri_count == 2


@pytest.mark.parametrize("name", ["cow", "spot"])
def test_obj_with_mtllib_reads_the_geometry_pymeshlab_reads(tmp_path, name):
    """A test model with an `mtllib` line added goes through our OBJ reader: the triangles
    pymeshlab reads from the original (as sets of corner positions; spot's UV seams split
    vertices, so the vertex count may grow, never the geometry)."""
    original = model(name)
    path = tmp_path / original.name
    path.write_bytes(b"mtllib none.mtl\n" + original.read_bytes())
    ours_mesh, theirs = meshes.load_mesh(path), meshes.load_mesh(original)
    assert ours_mesh.tri_count == theirs.tri_count
    assert np.unique(ours_mesh.positions, axis=0).shape == np.unique(theirs.positions, axis=0).shape

    def triangles(mesh):
        corners = np.sort(mesh.positions[mesh.faces].reshape(-1, 3, 3).round(6).view("f8,f8,f8").ravel()
                          .reshape(-1, 3), axis=1)
        return np.sort(corners.view(np.float64).reshape(-1, 9), axis=0)

    np.testing.assert_array_equal(triangles(ours_mesh), triangles(theirs))
    assert (ours_mesh.uvs is not None) == (name == "spot")


def test_obj_polygons_relative_indices_and_bad_numbers(tmp_path):
    """Fan-triangulated polygons, negative (relative) indices, v/t/n corners; a texture
    coordinate that is no number is refused naming its line."""
    (tmp_path / "m.mtl").write_text("newmtl A\nKd 1 0 0\n")
    path = tmp_path / "poly.obj"
    path.write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv -1 0.5 0\nvt 0 0\nvt 1 1\nvn 0 0 1\n"
                    "usemtl A\nf 1/1/1 2/2/1 3/1/1 4/2/1 5/1/1\nf -5/-2 -3/-1 -1/-2\n")
    mesh = meshes.load_mesh(path)
    assert mesh.tri_count == 4 and mesh.normals is None  # the last face has no normals: none kept
    area = 0.5 * np.linalg.norm(np.cross(*(mesh.positions[mesh.faces][:, 1:] - mesh.positions[mesh.faces][:, :1])
                                         .transpose(1, 0, 2)), axis=1)
    # the convex pentagon: the unit square + triangle (0,0)-(0,1)-(-1,0.5) = 1.5; face 2: vertices 1, 3, 5
    # = 0.5 |(1,1) x (-1,0.5)| = 0.75
    assert area.sum() == pytest.approx(1.5 + 0.75)
    path.write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 zero\nf 1/1 2/1 3/1\n")
    with pytest.raises(InputError, match=r"poly.obj: line 5 \('vt 0 zero'\): 'zero' is not a finite number"):
        meshes.load_mesh(path)


def test_malformed_mtl_is_one_clear_error(tmp_path):
    path = _textured_obj(tmp_path, mtl="newmtl A\nKd 1 zero 0\n")
    with pytest.raises(InputError, match=r"scene.mtl: line 2 \('Kd 1 zero 0'\): Kd needs numbers"):
        meshes.load_mesh(path)


def test_obj_without_mtllib_reads_as_before(tmp_path):
    """No mtllib: pymeshlab's path as before, no appearance at all, even with texture
    coordinates (like the test model spot.obj: no texture for them to map)."""
    path = tmp_path / "plain.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 1\nf 1/1 2/2 3/1 4/2\n")
    mesh = meshes.load_mesh(path)
    assert mesh.tri_count == 2 and mesh.positions.shape[0] == 4
    assert not mesh.has_appearance and mesh.materials == ()


def test_ply_vertex_colours_are_srgb_decoded(tmp_path):
    """8-bit PLY colours are taken as sRGB-encoded (Blender's PLY importer's default) and stored
    linear: 128 -> ((128/255 + 0.055) / 1.055)^2.4 = 0.2158; alpha stays linear."""
    header = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
              "{}element face 1\nproperty list uchar int vertex_indices\nend_header\n")
    colours = "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar alpha\n"
    path = tmp_path / "c.ply"
    path.write_text(header.format(colours) + "0 0 0 255 128 0 128\n1 0 0 0 0 0 255\n0 1 0 10 20 30 255\n3 0 1 2\n")
    mesh = meshes.load_mesh(path)
    np.testing.assert_allclose(mesh.colors[0], [1.0, ((128 / 255 + 0.055) / 1.055) ** 2.4, 0.0, 128 / 255], atol=1e-6)
    np.testing.assert_allclose(mesh.colors[2, :3], [10 / 255 / 12.92, ((20 / 255 + 0.055) / 1.055) ** 2.4,
                                                    ((30 / 255 + 0.055) / 1.055) ** 2.4], atol=1e-6)  # 10: linear part
    plain = tmp_path / "p.ply"
    plain.write_text(header.format("") + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    assert meshes.load_mesh(plain).colors is None


# --- through the bake and the command line --------------------------------------------------------

@pytest.mark.parametrize("kind", ["glb", "obj"])
def test_bake_keeps_materials_and_uvs(kind, ours, scene):
    """A bake of the read scene keeps its material table, UVs and per-triangle materials; the
    leaves keep every triangle of every material."""
    mesh = ours[kind]
    hlod = bake(mesh, BakeSettings(target_tris=8000, jobs=1, proxy_materials=False))  # the table as read
    assert [m.name for m in hlod.materials] == [m.name for m in mesh.materials]
    assert hlod.uvs is not None and hlod.tri_material is not None
    assert (hlod.colors is not None) == (kind == "glb")
    leaves = np.flatnonzero(hlod.is_leaf)
    leaf_material = np.concatenate([hlod.tri_material[hlod.tri_offset[n]:hlod.tri_offset[n] + hlod.tri_count[n]]
                                    for n in leaves])
    counts = np.bincount(leaf_material, minlength=len(hlod.materials)).tolist()
    assert dict(zip([m.name for m in hlod.materials], counts)) == scene["facts"]["triangles_per_material"]


def test_cli_bake_writes_embedded_images_beside_the_output(tmp_path, scene, capsys):
    """bake X.glb -o OUT.hlod: the GLB's images go to OUT.textures/ (once each), the .hlod refers
    to them relative to itself; an OBJ (images are files already) writes no folder; a bake that
    fails after the images were written leaves neither the folder nor its scratch copy. (With the
    sources' materials on every level: the proxies' own textures are test_cli_bake_writes_proxies.)"""
    out = tmp_path / "scene.hlod"
    keep = "--keep-materials"
    assert cli.main(["-q", "bake", str(scene["glb"]), "-o", str(out), "--target-tris", "20000", keep]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    folder = tmp_path / "scene.textures"
    assert summary["texture_folder"] == str(folder) and len(list(folder.iterdir())) == 3
    header_textures = sorted(m.texture for m in hlod_file.load(out).materials if m.texture)
    assert header_textures == sorted(str(p.resolve()) for p in folder.iterdir())
    raw = out.read_bytes()
    assert b'"scene.textures/' in raw and str(folder).encode() not in raw  # stored relative
    assert cli.main(["-q", "bake", str(scene["obj"]), "-o", str(tmp_path / "obj.hlod"), "--target-tris", "20000",
                     keep]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["texture_folder"] is None
    assert not (tmp_path / "obj.textures").exists()
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nf 1 2 3\n")
    before = {p.name: p.read_bytes() for p in [out, *folder.iterdir()]}
    for target in (tmp_path / "failed.hlod", out):  # a new output; a re-bake of the first one
        assert cli.main(["-q", "bake", str(scene["glb"]), str(bad), "-o", str(target), keep]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("hlod_core: error: ") and str(bad) in err and "\n" not in err
        assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.obj", "obj.hlod", "obj.hlod.cache", "scene.hlod",
                                                              "scene.hlod.cache", "scene.textures"]
    assert {p.name: p.read_bytes() for p in [out, *folder.iterdir()]} == before


def test_cli_bake_writes_proxies_beside_the_output(tmp_path, scene, capsys):
    """bake X.obj -o OUT.hlod with proxy materials (the default): the inner nodes' textures are
    OUT.textures/proxy_<node>.png, which the .hlod refers to relative to itself. The same command
    again takes the whole result, every inner node and its proxy, from the bake cache beside the
    output and writes the same file and texture files."""
    out = tmp_path / "proxies.hlod"
    command = ["-q", "bake", str(scene["obj"]), "-o", str(out), "--target-tris", "20000"]
    assert cli.main(command) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    folder = tmp_path / "proxies.textures"
    hlod = hlod_file.load(out)
    proxies = [m for m in hlod.materials if m.name.startswith("HLOD proxy")]
    assert summary["texture_folder"] == str(folder) and summary["cache"]["reused_nodes"] == 0 and proxies
    assert sorted(Path(m.texture).name for m in proxies) == sorted(p.name for p in folder.iterdir())
    assert b'"proxies.textures/proxy_' in out.read_bytes()
    textures = {p.name: p.read_bytes() for p in folder.iterdir()}
    assert cli.main(command) == 0
    again = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["cache"]
    assert again["reused_nodes"] == again["nodes"] == summary["cache"]["nodes"] > 0 and again["reused_result"]
    assert file_bytes(hlod_file.load(out), tmp_path / "a.hlod") == file_bytes(hlod, tmp_path / "b.hlod")
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == textures


def test_interrupted_bake_leaves_no_texture_folder(tmp_path, scene):
    """Ctrl-C during the simplification of a GLB bake (its images already written): no .hlod, no
    OUT.textures, no scratch folder."""
    out = tmp_path / "scene.hlod"
    proc = subprocess.Popen([sys.executable, "-m", "hlod_core", "bake", str(scene["glb"]), "-o", str(out),
                             "--target-tris", "1000"], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "PYTHONPATH": str(ROOT), "TMPDIR": str(tmp_path)})
    for line in proc.stderr:  # the images are written while the inputs load, before this line
        if "bake simplify" in line:
            break
    assert any(p.name.startswith(".scene.textures.partial") for p in tmp_path.iterdir())
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130 and err.strip().splitlines()[-1] == "hlod_core: interrupted"
    assert list(tmp_path.iterdir()) == []
