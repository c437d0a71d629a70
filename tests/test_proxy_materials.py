"""The inner nodes' proxy materials (docs/how-it-works.md#proxy-materials-for-the-inner-nodes): one
atlas and one base-colour texture per inner node whose sources need it, real bakes with real
pymeshlab and xatlas.

The sphere of sample_meshes (two materials, vertex colours) is baked with proxies; a textured
variant gives each half an image; the stiff cases bake tiny meshes whose expected colours are known.
"""
from __future__ import annotations

import logging
import os
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from hlod_core.bake.appearance import atlas as atlas_module
from hlod_core.bake.appearance.atlas import node_atlas, texture_side
from hlod_core.bake.pipeline import bake
from hlod_core.bake.settings import BakeSettings
from hlod_core.core.errors import InputError
from hlod_core.io import hlod_file, meshes
from hlod_core.model.appearance import Material
from hlod_core.model.hierarchy import node_geometry
from sample_meshes import SPHERE_CENTER, SPHERE_TARGET_TRIS, textured_sphere

#: A small cap keeps the tests' textures (and their bakes) small; the rule itself is tested below.
CAP = 64
SETTINGS = BakeSettings(target_tris=SPHERE_TARGET_TRIS, texture_cap=CAP, texture_floor=8)


def _checker(n: int, a, b) -> np.ndarray:
    """(n,n,4) uint8 RGBA checkerboard of colours a and b (sRGB bytes), 8 texels a square."""
    yy, xx = np.mgrid[0:n, 0:n]
    board = ((xx // 8 + yy // 8) % 2).astype(bool)
    out = np.empty((n, n, 4), np.uint8)
    out[...] = np.array([*a, 255], np.uint8)
    out[board] = np.array([*b, 255], np.uint8)
    return out


@pytest.fixture(scope="module")
def sphere_bakes():
    """The two-material sphere baked with proxies, inline and with two workers."""
    mesh = textured_sphere()
    return {jobs: bake(mesh, replace(SETTINGS, jobs=jobs)) for jobs in (1, 2)}


def test_every_inner_node_draws_in_one_part_and_leaves_keep_the_source_materials(sphere_bakes):
    hlod = sphere_bakes[1]
    inner = np.flatnonzero(hlod.child_count > 0)
    proxies = hlod.meta["proxies"]
    assert proxies["nodes"] and set(proxies["nodes"]) <= set(inner.tolist())
    scene = 2  # the sphere's red and blue
    assert len(hlod.materials) == scene + len(proxies["nodes"])  # opaque sources: one part each
    for node in range(hlod.node_count):
        begin, end = int(hlod.tri_offset[node]), int(hlod.tri_offset[node] + hlod.tri_count[node])
        used = np.unique(hlod.tri_material[begin:end])
        if hlod.child_count[node] == 0:
            assert used.max() < scene  # the leaves keep the sources' materials
        elif node in proxies["nodes"]:
            assert used.size == 1 and used[0] >= scene
            material = hlod.materials[int(used[0])]
            assert material.texture is not None and material.texture.endswith(f"proxy_{node}.png")
            with Image.open(material.texture) as image:
                assert max(image.size) <= CAP and image.size == (
                    proxies["width"][proxies["nodes"].index(node)], proxies["height"][proxies["nodes"].index(node)])


def test_proxy_bakes_are_the_same_inline_and_on_workers(sphere_bakes):
    one, two = sphere_bakes[1], sphere_bakes[2]
    for name in ("positions", "indices", "uvs", "colors", "tri_material"):
        assert np.array_equal(getattr(one, name), getattr(two, name)), name
    assert one.meta["proxies"] == two.meta["proxies"]
    for a, b in zip(one.materials, two.materials):
        if a.texture is not None:
            with Image.open(a.texture) as x, Image.open(b.texture) as y:
                assert np.array_equal(np.asarray(x), np.asarray(y))


def test_the_quality_gate_is_recorded_per_node(sphere_bakes):
    proxies = sphere_bakes[1].meta["proxies"]
    assert len(proxies["psnr_y"]) == len(proxies["nodes"])
    assert all(np.isfinite(proxies["psnr_y"]))
    assert proxies["psnr_y_median"] == pytest.approx(float(np.median(proxies["psnr_y"])))
    log = sphere_bakes[1].meta["log"]
    assert any(line.startswith("proxy materials:") for line in log)
    for node, db in zip(proxies["nodes"], proxies["psnr_y"]):
        named = [line for line in log if line.startswith(f"node {node}: proxy PSNR-Y")]
        assert bool(named) == (db < 25.0)  # a node under the gate is named, with its reason


#: A bake without a texture folder, in a process of its own: prints the folder its proxies' PNGs are in
#: and whether they are there before the process exits.
_OWN_FOLDER_BAKE = """
from pathlib import Path
from hlod_core.bake.pipeline import bake
from hlod_core.bake.settings import BakeSettings
from sample_meshes import SPHERE_TARGET_TRIS, textured_sphere
hlod = bake(textured_sphere(), BakeSettings(target_tris=SPHERE_TARGET_TRIS, jobs=1, texture_cap=16, texture_floor=8))
files = [Path(m.texture) for m in hlod.materials if m.texture and Path(m.texture).name.startswith("proxy_")]
print(files[0].parent, all(f.is_file() for f in files))
"""


def test_a_bake_without_a_texture_folder_removes_its_own_when_the_process_exits(tmp_path):
    tests = Path(__file__).resolve().parent
    done = subprocess.run([sys.executable, "-c", _OWN_FOLDER_BAKE], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "TMPDIR": str(tmp_path),
                               "PYTHONPATH": os.pathsep.join([str(tests.parent), str(tests)])})
    assert done.returncode == 0, done.stderr[-2000:]
    folder, there = done.stdout.split()[-2:]
    assert Path(folder).parent == tmp_path and there == "True"  # the file's materials named them while it ran
    assert not list(tmp_path.glob("hlod-proxies-*"))


def test_keep_materials_bakes_without_proxies():
    hlod = bake(textured_sphere(), replace(SETTINGS, proxy_materials=False))
    assert "proxies" not in hlod.meta and len(hlod.materials) == 2


def test_a_scene_of_one_untextured_material_makes_no_proxy_and_the_same_arrays():
    mesh = textured_sphere()
    one = replace(mesh, material_ids=np.zeros_like(mesh.material_ids), materials=mesh.materials[:1])
    with_proxies, without = bake(one, SETTINGS), bake(one, replace(SETTINGS, proxy_materials=False))
    assert "proxies" not in with_proxies.meta
    for name in ("positions", "indices", "uvs", "colors", "tri_material", "error"):
        assert np.array_equal(getattr(with_proxies, name), getattr(without, name)), name


def test_the_texture_side_follows_the_error_and_stays_within_floor_and_cap():
    # N^2 = A / (s^2 eta): a 100 x 100 surface at texels of 1 packed at 0.5 -> ceil(sqrt(20000)) = 142
    assert texture_side(100.0 * 100.0, 1.0, efficiency=0.5, floor=16, cap=1024) == 142
    assert texture_side(100.0 * 100.0, 2.0, efficiency=0.5, floor=16, cap=1024) == 71  # twice the error: half
    assert texture_side(100.0 * 100.0, 0.001, efficiency=0.5, floor=16, cap=1024) == 1024  # capped
    assert texture_side(1.0, 10.0, efficiency=0.5, floor=16, cap=1024) == 16  # floored
    assert texture_side(1.0, 0.0, efficiency=0.5, floor=16, cap=1024) == 1024  # a lossless node: the cap


def test_an_xatlas_atlas_is_freed_only_once_it_has_been_idle(monkeypatch):
    # freeing an Atlas right after generate() can hang in xatlas's scheduler (atlas.py's docstring)
    monkeypatch.setattr(atlas_module, "retired", [])
    monkeypatch.setattr(atlas_module, "IDLE_BEFORE_FREE_SECONDS", 0.3)
    grid = np.stack(np.meshgrid(np.arange(4.0), np.arange(4.0), indexing="ij"), -1).reshape(-1, 2)
    positions = np.column_stack([grid, np.zeros(16)]).astype(np.float32)
    quads = [(4 * i + j, 4 * i + j + 4, 4 * i + j + 5, 4 * i + j + 1) for i in range(3) for j in range(3)]
    faces = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], np.int32)
    first = node_atlas(positions, faces, texels_per_unit=8.0, floor=16, cap=64)
    assert first.width > 0 and len(atlas_module.retired) == 1  # kept alive
    node_atlas(positions, faces, texels_per_unit=8.0, floor=16, cap=64)
    assert len(atlas_module.retired) == 2  # the first is not yet idle long enough
    time.sleep(0.35)
    node_atlas(positions, faces, texels_per_unit=8.0, floor=16, cap=64)
    assert len(atlas_module.retired) == 1  # both earlier ones freed, the newest kept


def _two_halves(images: dict, *, uv_scale: float = 1.0):
    """The sphere with its two halves textured: material 0 a checker, material 1 a flat colour
    texture; uvs scaled by uv_scale (far outside [0, 1] for a large one)."""
    mesh = textured_sphere(colors=False)
    materials = (Material("checker", base_color=(1.0, 1.0, 1.0, 1.0), texture="checker.png"),
                 Material("flat", base_color=(1.0, 1.0, 1.0, 1.0), texture="flat.png"))
    return replace(mesh, materials=materials, uvs=mesh.uvs * uv_scale), images


def test_a_checker_is_averaged_in_linear_colour_and_a_flat_texture_keeps_its_colour():
    mesh, images = _two_halves({0: _checker(256, (255, 255, 255), (0, 0, 0)),
                                1: np.full((1, 1, 4), (40, 160, 90, 255), np.uint8)}, uv_scale=40.0)
    hlod = bake(mesh, replace(SETTINGS, texture_cap=32), images=images)
    root = node_geometry(hlod, 0)
    with Image.open(hlod.materials[int(root.face_material[0])].texture) as image:
        texels = np.asarray(image.convert("RGBA"))[::-1]  # row 0 at v = 0
    h, w, _ = texels.shape
    centroid = (hlod.origin + root.positions[root.faces].mean(axis=1))[:, 0] - SPHERE_CENTER[0]
    uv = root.uvs[root.faces].mean(axis=1)
    at = texels[np.clip((uv[:, 1] * h).astype(int), 0, h - 1), np.clip((uv[:, 0] * w).astype(int), 0, w - 1)]
    # at the root's texels (a few model units wide) the 40x-repeated checker is far finer: its linear
    # mean, 0.5, is 188 in sRGB (not the 128 of a mean of sRGB values); the flat half keeps its colour
    checker, flat = at[centroid < -0.2], at[centroid > 0.5]
    assert checker.size and flat.size
    assert np.median(np.abs(checker[:, :3].astype(int) - 188)) <= 6
    assert np.median(np.abs(flat[:, :3].astype(int) - (40, 160, 90)), axis=0).max() <= 3
    assert np.all(texels[..., 3] == 255)


def test_stiff_textures_stay_finite(tmp_path):
    big = np.broadcast_to(np.array([200, 30, 30, 255], np.uint8), (8192, 8192, 4))
    mesh, images = _two_halves({0: big, 1: np.full((1, 1, 4), (10, 10, 250, 255), np.uint8)}, uv_scale=1e4)
    hlod = bake(mesh, replace(SETTINGS, texture_cap=16), images=images)
    assert hlod.meta["proxies"]["nodes"]
    assert all(np.isfinite(hlod.meta["proxies"]["psnr_y"]))
    hlod_file.save(hlod, tmp_path / "stiff.hlod")
    hlod_file.load(tmp_path / "stiff.hlod")


def test_a_sliver_node_bakes_a_proxy_a_texel_wide():
    # two long thin strips of two materials, 1000 x 0.001 units
    x = np.linspace(0.0, 1000.0, 301)
    top = np.stack([x, np.full_like(x, 0.001), np.zeros_like(x)], 1)
    bottom = np.stack([x, np.zeros_like(x), np.zeros_like(x)], 1)
    positions = np.concatenate([bottom, top])
    n = x.size
    quads = [[i, i + 1, n + i + 1] for i in range(n - 1)] + [[i, n + i + 1, n + i] for i in range(n - 1)]
    faces = np.array(quads, np.int64)
    ids = (positions[faces].mean(axis=1)[:, 0] > 500).astype(np.int32)
    materials = (Material("a", base_color=(1, 0, 0, 1)), Material("b", base_color=(0, 0, 1, 1)))
    mesh = meshes.from_arrays(positions, faces, name="sliver", material_ids=ids, materials=materials)
    hlod = bake(mesh, BakeSettings(target_tris=100, texture_cap=CAP, texture_floor=1))
    assert hlod.meta["proxies"]["nodes"]
    assert all(np.isfinite(hlod.meta["proxies"]["psnr_y"]))
    for node in hlod.meta["proxies"]["nodes"]:
        geometry = node_geometry(hlod, node)
        assert np.all(np.isfinite(geometry.positions)) and geometry.faces.shape[0] > 0


def test_a_missing_image_file_gets_one_warning_that_names_it(tmp_path, caplog):
    mesh, images = _two_halves({1: np.full((4, 4, 4), (10, 200, 10, 255), np.uint8)})
    missing = str(tmp_path / "no-such-image.png")
    mesh = replace(mesh, materials=(replace(mesh.materials[0], texture=missing), mesh.materials[1]))
    from hlod_core.io.textures import load_material_images

    with caplog.at_level(logging.WARNING):
        loaded = load_material_images(mesh.materials)
        hlod = bake(mesh, replace(SETTINGS, texture_cap=16), images={**loaded, **images})
    named = [r for r in caplog.records if missing in r.getMessage()]
    assert len(named) == 1 and "checker" in named[0].getMessage()
    assert hlod.meta["proxies"]["nodes"]


def test_bad_texture_sizes_are_refused():
    with pytest.raises(InputError, match="floor"):
        BakeSettings(texture_cap=8, texture_floor=16)


def _gradient_plane():
    """A gently waved 1 x 1 plane: its left part textured with a gradient (red = u, green = v, the
    UVs its x and y), its right part (x > 0.7) a flat blue material."""
    n = 60
    x, y = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1))
    positions = np.stack([x.ravel(), y.ravel(), (0.05 * np.sin(7 * x) * np.cos(5 * y)).ravel()], 1)
    index = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    ids = (positions[faces].mean(axis=1)[:, 0] > 0.7).astype(np.int32)
    texture = np.zeros((256, 256, 4), np.uint8)
    texture[..., 3] = 255
    texture[..., 0] = np.arange(256)[None, :]  # red grows with u (columns)
    texture[..., 1] = np.arange(256)[::-1, None]  # green grows with v (the top row is v = 1)
    materials = (Material("gradient", base_color=(1, 1, 1, 1), texture="gradient.png"),
                 Material("flat", base_color=(0, 0, 1, 1)))
    mesh = meshes.from_arrays(positions, faces, name="plane", uvs=positions[:, :2], material_ids=ids,
                              materials=materials)
    return mesh, {0: texture}


def test_a_proxy_shows_its_sources_colours_where_they_are_and_the_gate_says_so():
    mesh, images = _gradient_plane()
    hlod = bake(mesh, BakeSettings(target_tris=400, texture_cap=128), images=images)
    proxies = hlod.meta["proxies"]
    for node in proxies["nodes"]:
        geometry = node_geometry(hlod, node)
        with Image.open(hlod.materials[int(geometry.face_material[0])].texture) as image:
            texels = np.asarray(image.convert("RGBA"))[::-1]
        h, w, _ = texels.shape
        centre = hlod.origin + geometry.positions[geometry.faces].mean(axis=1)
        uv = geometry.uvs[geometry.faces].mean(axis=1)
        left = centre[:, 0] < 0.65
        at = texels[np.clip((uv[left, 1] * h).astype(int), 0, h - 1), np.clip((uv[left, 0] * w).astype(int), 0, w - 1)]
        # the gradient where each face is: red = 255 x, green = 255 y (sRGB bytes, as the texture holds)
        assert np.median(np.abs(at[:, 0] - 255 * centre[left, 0])) <= 2, node
        assert np.median(np.abs(at[:, 1] - 255 * centre[left, 1])) <= 2, node
    # a proxy this close to its sources scores high at the gate (a white proxy base colour: no dimming)
    assert proxies["psnr_y_median"] >= 35.0


def test_empty_texels_take_the_colours_of_the_charts_nearest_them():
    from hlod_core.bake.appearance.texels import fill_empty

    rgba = np.zeros((5, 7, 4), np.float32)
    filled = np.zeros((5, 7), bool)
    rgba[1, 1], rgba[3, 5] = (1, 0, 0, 1), (0, 0, 1, 1)
    filled[1, 1] = filled[3, 5] = True
    out = fill_empty(rgba, filled)
    assert np.array_equal(out[1, 1], rgba[1, 1]) and np.array_equal(out[3, 5], rgba[3, 5])  # kept
    assert np.array_equal(out[0, 0], (1, 0, 0, 1)) and np.array_equal(out[2, 6], (0, 0, 1, 1))  # the nearer
    # every texel a blend of the two charts' colours, never a colour that is on neither (no black)
    assert np.allclose(out[..., 0] + out[..., 2], 1.0) and np.all(out[..., 3] == 1.0)
