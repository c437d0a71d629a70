"""Hostile bake inputs: STL files that used to hang pymeshlab's reader, OBJ lines it
read wrongly without a word, scene specs nested too deep or placing a model with a singular
transform, and settings or geometry that made a bake crash inside pymeshlab. Each is refused in
one line naming the file (and line or transform), or bakes."""
import importlib.util
import json
import os
import subprocess
import sys

import numpy as np
import pymeshlab
import pytest

import models
from helpers import ROOT, SCENES, load_model, model
from hlod_core.bake import checks
from hlod_core.bake.pipeline import BakeSettings, bake
from hlod_core.core.errors import InputError
from hlod_core.io import meshes, obj
from models import OBJ_ROLES

ALL_TRUE = {"leaf_tris_equal_input": True, "nested_bounds": True, "monotone_error": True, "leaf_budget": True}

#: Seconds a subprocess gets to refuse every hostile STL file; pymeshlab's reader never returned.
STL_REFUSAL_TIMEOUT_S = 120


def _write(path, data):
    path.write_bytes(data if isinstance(data, bytes) else data.encode())
    return path


#: Binary STL, written here independently of the reader: 80-byte header, uint32 count, 50-byte records.
STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])


def _binary_stl(tris: np.ndarray, header: bytes = b"binary") -> bytes:
    records = np.zeros(tris.shape[0], STL_RECORD)
    records["corners"] = tris
    return header.ljust(80, b" ") + np.uint32(tris.shape[0]).tobytes() + records.tobytes()


def _ascii_stl(tris: np.ndarray) -> str:
    facets = ["facet normal 0 0 1\n outer loop\n" + "".join(f"  vertex {x!r} {y!r} {z!r}\n" for x, y, z in t.tolist())
              + " endloop\nendfacet" for t in tris]
    return "\n".join(["solid model", *facets, "endsolid model\n"])


def _triangle_rows(positions, faces) -> np.ndarray:
    rows = np.asarray(positions, np.float64)[np.asarray(faces)].reshape(-1, 9)
    return rows[np.lexsort(rows.T[::-1])]


# --- STL ------------------------------------------------------------------------------------------

def test_zero_filled_and_lying_stl_files_are_refused_at_once(tmp_path):
    """`head -c 200 /dev/zero > z.stl` and headers claiming 2..1e9 triangles over zeros: pymeshlab's
    reader spun at 100% CPU for minutes; now each is one line naming the file and its size."""
    files = [_write(tmp_path / f"zero{n}.stl", bytes(n)) for n in (0, 50, 134, 150, 199, 200)]
    files += [_write(tmp_path / f"claims{n}.stl", bytes(80) + np.uint32(n).tobytes() + bytes(116))
              for n in (2, 3, 1000, 10**9)]
    cow = load_model("cow")
    whole = _binary_stl(cow.positions[cow.faces].astype(np.float32), header=b"solid cow (binary)")
    files.append(_write(tmp_path / "truncated.stl", whole[:-7]))
    script = ("import sys\nfrom hlod_core.io import meshes\nfrom hlod_core.core.errors import InputError\n"
              "for p in sys.argv[1:]:\n"
              "    try:\n        meshes.load_mesh(p)\n        print('read', p)\n"
              "    except InputError as e:\n        print(e)\n")
    proc = subprocess.run([sys.executable, "-c", script, *map(str, files)], cwd=ROOT, capture_output=True, text=True,
                          timeout=STL_REFUSAL_TIMEOUT_S, env={**os.environ, "PYTHONPATH": str(ROOT)})
    lines = proc.stdout.splitlines()
    assert proc.returncode == 0 and len(lines) == len(files), proc.stderr
    for path, line in zip(files, lines):
        assert line.startswith(f"{path}: not an STL file ({path.stat().st_size} bytes"), line
    assert "header gives 1000000000 triangles has 50000000084" in lines[files.index(tmp_path / "claims1000000000.stl")]


def test_stl_whose_size_matches_its_header_is_read_even_if_all_zero(tmp_path):
    """84 + 50 * 2 bytes of zeros is a valid binary STL: two triangles collapsed at the origin."""
    mesh = meshes.load_mesh(_write(tmp_path / "two.stl", bytes(80) + np.uint32(2).tobytes() + bytes(100)))
    assert mesh.tri_count == 2 and mesh.positions.shape == (1, 3)
    hlod = bake(mesh)
    assert hlod.node_count == 1 and checks.check(hlod)["checks"] == ALL_TRUE


@pytest.mark.parametrize("form", ["binary", "ascii"])
def test_valid_stl_reads_the_triangles_pymeshlab_reads(tmp_path, form):
    cow = load_model("cow")
    tris = cow.positions[cow.faces].astype(np.float32)
    path = _write(tmp_path / f"cow_{form}.stl", _binary_stl(tris) if form == "binary" else _ascii_stl(tris))
    mesh = meshes.load_mesh(path)
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(path))
    theirs = ms.current_mesh()
    assert mesh.tri_count == theirs.face_number() == cow.tri_count
    assert mesh.positions.shape[0] == theirs.vertex_number()  # shared corners welded, as pymeshlab does
    assert np.array_equal(_triangle_rows(mesh.positions, mesh.faces),
                          _triangle_rows(theirs.vertex_matrix(), theirs.face_matrix()))


@pytest.mark.parametrize("text, expect", [
    ("solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n",
     r"ASCII STL without 'endsolid' \(truncated\?\)"),
    ("solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nvertex 1 1 0\nendloop\n"
     "endfacet\nendsolid x\n", r"line 2: a facet with 4 vertices"),
    ("solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 x 0\nvertex 0 1 0\nendloop\nendfacet\n"
     "endsolid x\n", r"line 5: vertex coordinates are not numbers"),
    ("solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0\nvertex 0 1 0\nendloop\nendfacet\n"
     "endsolid x\n", r"line 5: a vertex needs three coordinates"),
    ("solid x\nendsolid x\n", r"the mesh has no triangles"),
])
def test_broken_ascii_stl_names_the_line(tmp_path, text, expect):
    with pytest.raises(InputError, match=r"bad\.stl: " + expect):
        meshes.load_mesh(_write(tmp_path / "bad.stl", text))


# --- OBJ ------------------------------------------------------------------------------------------

TRIANGLE = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"


@pytest.mark.parametrize("text, expect", [
    # pymeshlab dropped this face and baked one triangle short, exit 0
    (TRIANGLE + "f 1 2 3\nf 1 2 9\n", r"line 5 \('f 1 2 9'\): a face refers to vertex 9, but the file has 3 vertices"),
    # pymeshlab read this vertex as (1, 0, 0)
    ("v 0 0 0\nv 1 x 0\nv 0 1 0\nf 1 2 3\n", r"line 2 \('v 1 x 0'\): 'x' is not a number"),
    (TRIANGLE + "f 0 1 2\n", r"line 4 .*refers to vertex 0"),
    ("v 0 0 0\nv 1 0 0\nf -1 -2 -3\nv 0 1 0\n", r"line 3 .*refers to vertex -3, but the file has fewer vertices above"),
    (TRIANGLE + "f 1 2\nf 1 2 3\n", r"line 4 \('f 1 2'\): a face needs three or more vertices"),
    ("v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n", r"line 2 \('v 1 0'\): a vertex needs three coordinates"),
    (TRIANGLE + "f 1 2 3.5\n", r"line 4 .*malformed face"),
    (TRIANGLE + "f 1/1/1/1 2 3\n", r"line 4 .*malformed face"),
    (TRIANGLE + "f 1 2-3 3\n", r"line 4 .*malformed face"),
    (TRIANGLE + "f 1 2 99999999999999999999999\n", r"line 4 .*refers to vertex"),
    ("v 0 0 0\nv 1 0 0\nv nan 1 0\nv inf 0 1\nf 1 2 3\n", r"2 of 4 vertices could not be read \(line 3: NaN"),
    # pymeshlab dropped this face (texture index past the vt list)
    (TRIANGLE + "vt 0 0\nf 1/5 2/1 3/1\n", r"line 5 .*refers to texture coordinate 5, but the file has 1 texture"),
    (TRIANGLE + "vn 0 0 1\nf 1//1 2//-2 3//1\n", r"line 5 .*refers to normal -2, but the file has fewer normals above"),
    (TRIANGLE + "vt 0 0\nvn 0 0 1\nf 1/1//1 2 3\n", r"line 6 .*malformed face"),
    # pymeshlab skipped the indented vertex, kept the face and crashed on its out-of-range index
    ("v 0 0 0\n  v 1 0 0\nv 0 1 0\nf 1 2 3\n", r"line 2 \('v 1 0 0'\): an indented vertex line"),
    # pymeshlab read 'f 1 2 3 # c' as the face (2, 3, 4)
    (TRIANGLE + "v 1 1 0\nf 1 2 3 # c\n", r"line 5 .*a comment after a face"),
])
def test_obj_lines_pymeshlab_misreads_are_refused_with_their_line(tmp_path, text, expect):
    with pytest.raises(InputError, match=r"bad\.obj: " + expect):
        meshes.load_mesh(_write(tmp_path / "bad.obj", text))


def test_relative_indices_slashes_polygons_and_comments_read_as_pymeshlab_reads_them(tmp_path):
    plain = meshes.load_mesh(_write(tmp_path / "plain.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 2 2 0\n"
                                                           "f 1 2 3\nf 2 4 3\nf 1 2 4 5 3\n"))
    fancy = meshes.load_mesh(_write(tmp_path / "fancy.obj", "# a comment\nv 0 0 0 # origin\r\nv 1 0 0\r\nvt 0 0\n"
                                                           "vn 0 0 1\nv 0 1 0\nf -3/1/1 -2//1 -1/1\nv 1 1 0\n"
                                                           "v 2 2 0 1.0\nf 2/1 -2/-1 3/1\n  f 1 2 -2 -1 3\n"))
    assert plain.tri_count == fancy.tri_count == 5
    assert np.array_equal(plain.positions, fancy.positions) and np.array_equal(plain.faces, fancy.faces)


@pytest.mark.parametrize("name", OBJ_ROLES)
def test_every_test_obj_passes_the_check_and_declares_what_pymeshlab_reads(name):
    path = model(name)
    vertices, tris = obj.check_obj(path, path.read_bytes())
    mesh = load_model(name)
    assert (vertices, tris) == (mesh.positions.shape[0], mesh.tri_count)


# --- scene specs ----------------------------------------------------------------------------------

IDENTITY = np.eye(4).ravel().tolist()


def test_the_scene_specs_are_what_generate_specs_writes(tmp_path):
    """tests/scenes/gallery_1m.json, crowd_1m.json and yard_1m.json are generate_specs.py's output from today's test
    models (a placement follows its model's box: a changed model comes with regenerated specs), and
    every model they name is found where they name it."""
    spec = importlib.util.spec_from_file_location("generate_specs", SCENES / "generate_specs.py")
    generate_specs = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(generate_specs)
    for name, make in (("gallery_1m", generate_specs.gallery), ("crowd_1m", generate_specs.crowd),
                       ("yard_1m", generate_specs.yard)):
        generate_specs.write_spec(tmp_path / f"{name}.json", make())
        written, kept = (json.loads(p.read_text()) for p in (tmp_path / f"{name}.json", SCENES / f"{name}.json"))
        # the same models in the same order; placements equal to a few ulps (the last printed digit
        # of a float may differ between CPUs: libm's trigonometry is not correctly rounded)
        assert [m["path"] for m in written["models"]] == [m["path"] for m in kept["models"]], name
        for a, b in zip(written["models"], kept["models"]):
            assert set(a) == set(b), name
            np.testing.assert_allclose(a["transforms"], b["transforms"], rtol=1e-12, atol=1e-12, err_msg=name)
        mesh = meshes.load_inputs([models.scene(name)])
        assert mesh.tri_count == {"gallery_1m": 1_004_268, "crowd_1m": 1_535_020, "yard_1m": 1_589_952}[name]


def _spec(tmp_path, transforms, name="spec.json"):
    spec = {"models": [{"path": str(model("cow")), "transforms": transforms}]}
    return _write(tmp_path / name, json.dumps(spec))


def test_deeply_nested_scene_spec_is_one_clear_error(tmp_path):
    deep = _write(tmp_path / "deep.json", '{"models": ' + "[" * 100_000 + "]" * 100_000 + "}")
    with pytest.raises(InputError, match=r"deep\.json: scene spec is not valid JSON \(nested 100001 levels deep"):
        meshes.load_inputs([deep])


def test_nan_literal_in_a_scene_spec_is_refused(tmp_path):
    spec = _write(tmp_path / "nan.json", '{"models": [{"path": "cow.obj", "transforms": [[NaN]]}]}')
    with pytest.raises(InputError, match=r"nan\.json: scene spec is not valid JSON \(NaN is not a JSON number"):
        meshes.load_inputs([spec])


@pytest.mark.parametrize("linear", [
    np.zeros((3, 3)),                                # a zero linear part put every triangle on one point
    np.diag([1.0, 1.0, 0.0]),                        # a projection onto a plane
    np.array([[1.0, 2, 3], [2, 4, 6], [0, 0, 1]]),  # rank 2, not axis-aligned
])
def test_singular_transform_names_the_spec_and_transform(tmp_path, linear):
    bad = np.eye(4)
    bad[:3, :3] = linear
    bad[:3, 3] = 5.0
    with pytest.raises(InputError, match=r"spec\.json: models\[0\]\.transforms\[1\] is singular"):
        meshes.load_inputs([_spec(tmp_path, [IDENTITY, bad.ravel().tolist()])])


def test_millimetre_and_huge_but_invertible_transforms_are_accepted(tmp_path):
    mm, huge = np.diag([1e-3, 1e-3, 1e-3, 1.0]), np.diag([1e300, 1.0, 1.0, 1.0])
    scene = meshes.load_inputs([_spec(tmp_path, [IDENTITY, mm.ravel().tolist(), huge.ravel().tolist()])])
    assert scene.tri_count == 3 * 5804


def test_transform_overflowing_the_coordinates_names_the_transform(tmp_path):
    huge = np.diag([1e308, 1e308, 1e308, 1.0])  # cow's coordinates reach 6: 6e308 overflows
    huge[:3, 3] = 1e308
    with pytest.raises(InputError, match=r"spec\.json: models\[0\]\.transforms\[0\] moves .*cow\.obj out of the"):
        meshes.load_inputs([_spec(tmp_path, [huge.ravel().tolist()])])


# --- geometry and settings that crashed inside pymeshlab ------------------------------------------

def _uv_sphere(rings: int = 6, segments: int = 8) -> meshes.TriangleMesh:
    """A closed sphere: two poles and (rings - 1) rings of `segments` vertices."""
    theta = np.pi * np.arange(1, rings) / rings
    phi = 2 * np.pi * np.arange(segments) / segments
    ring = np.stack([np.sin(theta)[:, None] * np.cos(phi), np.sin(theta)[:, None] * np.sin(phi),
                     np.cos(theta)[:, None] * np.ones(segments)], -1).reshape(-1, 3)
    p = np.concatenate([[[0, 0, 1]], ring, [[0, 0, -1]]])
    s = np.arange(segments)
    faces = [np.stack([np.zeros(segments, int), 1 + s, 1 + (s + 1) % segments], 1)]
    for r in range(rings - 2):
        a, b = 1 + r * segments + s, 1 + r * segments + (s + 1) % segments
        faces += [np.stack([a, a + segments, b], 1), np.stack([b, a + segments, b + segments], 1)]
    last = 1 + (rings - 2) * segments
    faces.append(np.stack([last + (s + 1) % segments, last + s, np.full(segments, p.shape[0] - 1)], 1))
    return meshes.from_arrays(p, np.concatenate(faces), name="sphere")


def test_target_of_one_triangle_bakes():
    """--target-tris 1 is valid; pymeshlab collapsed a closed node's last two triangles into an
    empty mesh ("Vertex matrix is empty"). Decimation now asks for at least MIN_DECIMATION_TRIS."""
    sphere = _uv_sphere()
    hlod = bake(sphere, BakeSettings(target_tris=1))
    assert checks.check(hlod)["checks"] == ALL_TRUE
    assert np.all(hlod.tri_count >= 1) and hlod.tri_count[0] <= 2
    assert np.all(hlod.tri_count[hlod.is_leaf] == 1) and hlod.meta["input_tris"] == sphere.tri_count


def test_node_of_zero_area_triangles_bakes():
    """Triangles on one line (distinct corners, zero area): pymeshlab's clean-up removed them all
    and the bake crashed on an empty mesh. The node keeps target_tris of them and says so."""
    x = np.arange(3 * 3000, dtype=float)
    mesh = meshes.from_arrays(np.stack([x, 0 * x, 0 * x], 1), np.arange(x.size).reshape(-1, 3), name="line")
    hlod = bake(mesh, BakeSettings(target_tris=100))
    assert checks.check(hlod)["checks"] == ALL_TRUE
    assert np.all(hlod.tri_count[~hlod.is_leaf] == 100)
    assert np.isfinite(hlod.error).all() and hlod.error[0] > 0
    assert any("every triangle has zero area" in line for line in hlod.meta["log"])
