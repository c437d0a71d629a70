"""Textures under the GPU budget (render.texture_table, render.residency, render.streamed_geometry):
a texture is counted once while a resident node draws with it, as GL holds it (RGBA8 and its mip
chain), comes with the first such node and is freed with the last; a budget that holds the
geometry but not geometry and textures holds fewer nodes. The bookkeeping on tiny literal
trees; on the GPU (llvmpipe), the two-textured sphere baked with proxies (a proxy texture per
inner node, two source textures the leaves share)."""
from __future__ import annotations

import ctypes
from dataclasses import replace

import moderngl
import numpy as np
import pytest

from helpers import gl_function
from hlod_core.bake.pipeline import bake
from hlod_core.bake.settings import BakeSettings
from hlod_core.io.textures import load_images
from hlod_core.model.appearance import Material
from hlod_core.model.camera_path import inspection_path
from hlod_core.render.renderer import Renderer
from hlod_core.render.residency import Residency, StreamingSettings
from hlod_core.render.streamed_geometry import node_bytes
from hlod_core.render.texture_table import TextureTable, mip_chain_bytes
from hlod_core.report.runner import run_path
from hlod_core.traversal.methods import make
from hlod_core.traversal.settings import RuntimeSettings
from sample_meshes import SPHERE_TARGET_TRIS, textured_sphere

SIZE = (160, 120)
FRAMES = 40


def test_a_texture_takes_its_rgba8_mip_chain():
    assert mip_chain_bytes(1, 1) == 4
    assert mip_chain_bytes(256, 256) == 349_524  # 4 (4^9 - 1) / 3: levels 256 .. 1
    assert mip_chain_bytes(4, 1) == 4 * (4 + 2 + 1)
    assert mip_chain_bytes(21, 32) == 4 * (21 * 32 + 10 * 16 + 5 * 8 + 2 * 4 + 1 * 2 + 1 * 1)


def _tree(budget: int, **kwargs) -> Residency:
    """Root 0 (geometry 10, its proxy texture 0 of 40 bytes) over leaves 1, 2, 3 (geometry 10
    each): 1 and 2 share texture 1, 3 draws with texture 2 (100 bytes each)."""
    return Residency(child_offset=np.array([1, -1, -1, -1]), child_count=np.array([3, 0, 0, 0]),
                     depth=np.array([0, 1, 1, 1]), node_bytes=np.array([10, 10, 10, 10]),
                     node_textures=[(0,), (1,), (1,), (2,)], texture_bytes=np.array([40, 100, 100]),
                     settings=StreamingSettings(budget_bytes=budget, upload_bytes_per_frame=1000), **kwargs)


def _frame(residency: Residency, *, refine: bool) -> None:
    """A frame that draws the root, refining into its leaves or not; the plan carried out."""
    residency.begin_frame()
    residency.use(0)
    if refine and residency.can_refine(0, visible=True, error_over_tau=3.0):
        for leaf in (1, 2, 3):
            residency.use(leaf)
    plan = residency.plan()
    for node in plan.evict:
        residency.evicted(node)
    for node in plan.upload:
        residency.uploaded(node)


def test_a_shared_texture_is_counted_once_and_goes_with_its_last_user():
    residency = _tree(1000)
    assert residency.preload_all  # 40 of geometry and 240 of textures fit in 1000
    for node in (0, 1):
        assert residency.textures_to_make(node) == (node,)
        residency.uploaded(node)
    assert residency.resident_bytes == 10 + 40 + 10 + 100
    assert residency.textures_to_make(2) == ()  # texture 1 is resident: leaf 2 brings only its geometry
    residency.uploaded(2)
    assert residency.resident_bytes == 160 + 10
    assert residency.evicted(1) == () and residency.resident_bytes == 160  # leaf 2 still draws with it
    assert residency.evicted(2) == (1,) and residency.resident_bytes == 50
    assert residency.texture_resident.tolist() == [True, False, False]
    assert residency.uploaded_bytes == 170


def test_a_budget_that_holds_the_geometry_but_not_the_textures_holds_fewer_nodes():
    """Budget 200: the geometry (40) would all fit, with the textures (280) it does not. The root
    and its proxy (50) are pinned; leaves 1 and 2 with their shared texture (120) fit; leaf 3 with
    its own (110) does not, and waits: the root stands in for its leaves."""
    residency = _tree(200)
    assert not residency.preload_all and residency.initial_uploads() == (0,)
    residency.uploaded(0)
    for _ in range(3):
        _frame(residency, refine=True)
        assert residency.resident_bytes <= 200
    assert residency.resident.tolist() == [True, True, True, False] and residency.resident_bytes == 170
    assert residency.substitutions == 1 and residency.waiting == 1


def test_a_node_over_the_budget_with_its_texture_waits_and_the_root_stays():
    """As for geometry alone: leaf 3 with a texture of 10,000 bytes never comes under a budget of
    300 (the root stands in for its leaves); a root over the budget with its texture is still
    uploaded at the start and stays, the one node's slack."""
    residency = Residency(child_offset=np.array([1, -1, -1, -1]), child_count=np.array([3, 0, 0, 0]),
                          depth=np.array([0, 1, 1, 1]), node_bytes=np.array([10, 10, 10, 10]),
                          node_textures=[(0,), (1,), (1,), (2,)], texture_bytes=np.array([40, 100, 10_000]),
                          settings=StreamingSettings(budget_bytes=300, upload_bytes_per_frame=1000))
    residency.uploaded(0)
    for _ in range(4):
        _frame(residency, refine=True)
        assert residency.resident_bytes <= 300
    assert residency.resident.tolist() == [True, True, True, False] and residency.waiting == 1
    over = _tree(30)
    assert over.initial_uploads() == (0,)
    over.uploaded(0)
    for _ in range(3):
        _frame(over, refine=True)
    assert over.resident.tolist() == [True, False, False, False] and over.resident_bytes == 50


def _leaf_one_then(budget: int, wanted: int) -> Residency:
    """The tree with the root and leaf 1 resident and leaf `wanted` asked for (the only one in
    view) after a frame; its plan must evict leaf 1 and upload `wanted`."""
    residency = _tree(budget)
    residency.uploaded(0)
    residency.uploaded(1)
    residency.begin_frame()
    residency.use(0)
    assert not residency.can_refine(0, visible=True, error_over_tau=2.0, needed=lambda leaf: leaf == wanted)
    plan = residency.plan()
    assert plan.evict == (1,) and plan.upload == (wanted,)
    return residency


def test_an_eviction_frees_the_textures_no_resident_node_uses():
    """Budget 160, leaves wanted one at a time: leaf 3 needs 110 and only leaf 1's eviction with
    texture 1 (110) makes room."""
    residency = _leaf_one_then(160, 3)
    assert residency.evicted(1) == (1,)
    residency.uploaded(3)
    assert residency.resident_bytes == 50 + 110 and residency.texture_resident.tolist() == [True, False, True]


def test_a_texture_the_next_upload_draws_with_is_kept_through_its_users_eviction():
    """Budget 165 holds the root and leaf 1 (160); leaf 2 shares leaf 1's texture, so making room
    for it evicts leaf 1's geometry alone, and texture 1 stays: not freed and made again."""
    residency = _leaf_one_then(165, 2)
    assert residency.evicted(1) == () and residency.texture_resident[1]
    assert residency.textures_to_make(2) == ()
    residency.uploaded(2)
    assert residency.resident_bytes == 160 and residency.uploaded_bytes == 50 + 110 + 10
    assert residency.evicted(2) == (1,)  # its last user gone, no upload planned: freed


# --- on the GPU --------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def textured_bake():
    """(hlod, images): the sphere whose halves carry a 64x64 and a 32x32 texture, baked with
    proxies of at most 32 texels a side; images: the source rows' arrays and the proxies' files."""
    mesh = textured_sphere(colors=False)
    materials = (Material("checker", texture="checker.png"), Material("flat", texture="flat.png"))
    sources = {0: np.full((64, 64, 4), (200, 60, 60, 255), np.uint8), 1: np.full((32, 32, 4), (60, 60, 200, 255),
                                                                                  np.uint8)}
    hlod = bake(replace(mesh, materials=materials), BakeSettings(target_tris=SPHERE_TARGET_TRIS, texture_cap=32,
                                                                  texture_floor=8, jobs=1), images=sources)
    images = {**load_images(hlod), **sources}  # the proxies' PNGs (the sources name no file)
    return hlod, images


def _textures_in_use(hlod, table: TextureTable, resident: np.ndarray) -> np.ndarray:
    """(k,) bool: the textures some resident node draws with, from the node table itself."""
    used = np.zeros(table.count, bool)
    for node in np.flatnonzero(resident):
        used[list(table.node_textures(hlod)[node])] = True
    return used


@pytest.mark.gl
def test_streamed_textures_stay_within_the_budget_and_are_freed_with_their_nodes(gl_ctx, textured_bake):
    hlod, images = textured_bake
    geometry = node_bytes(hlod, with_uv=True, with_colour=False)
    renderer = Renderer(gl_ctx, hlod, size=SIZE, images=images)
    table = renderer.texture_table
    renderer.release()
    assert table.count == 2 + len(hlod.meta["proxies"]["nodes"])
    budget = int(geometry.sum() + table.texture_bytes.sum() // 3)  # all the geometry, a third of the textures
    renderer = Renderer(gl_ctx, hlod, size=SIZE, images=images, streaming=StreamingSettings(budget_bytes=budget))
    is_texture = gl_function(gl_ctx, "glIsTexture", ctypes.c_uint8, ctypes.c_uint32)
    try:
        residency = renderer.residency
        assert not residency.preload_all
        traversal = make("vfc", hlod, renderer, settings=RuntimeSettings(skip_queries="off"))
        path = inspection_path(hlod, seed=5, frames=FRAMES)
        names: dict[int, int] = {}  # texture number -> its GL name while made
        freed = 0
        for i in range(len(path)):
            stats = traversal.frame(path.view(i, SIZE))
            in_use = _textures_in_use(hlod, table, residency.resident)
            assert np.array_equal(residency.texture_resident, in_use)
            assert stats.resident_bytes == geometry[residency.resident].sum() + table.texture_bytes[in_use].sum()
            assert stats.resident_bytes <= budget
            made = {n: t.glo for n, t in renderer.streamed._textures.items()}
            assert sorted(made) == np.flatnonzero(in_use).tolist()
            for number, name in names.items():
                if number not in made:  # freed with its last node (a GL name can be reused at once)
                    freed += 1
                    assert bool(is_texture(name)) == (name in made.values())
            names = made
        assert residency.resident.sum() < hlod.node_count  # fewer nodes than the geometry alone would hold
        assert freed > 0
    finally:
        renderer.release()
    assert not any(isinstance(o, moderngl.Texture) for o in renderer.streamed.gl_objects)
    assert not residency.texture_users.any()


@pytest.mark.gl
def test_the_report_counts_textures_and_counted_images_make_none(gl_ctx, textured_bake):
    """run's gpu_resident_bytes_peak without a budget: the file's geometry and every texture; the
    preview's private renderer (counted_images: the gpu batches draw them) makes no texture, yet
    its budget counts them."""
    hlod, images = textured_bake
    path = inspection_path(hlod, seed=5, frames=4)
    renderer = Renderer(gl_ctx, hlod, size=SIZE, images=images)
    try:
        out = run_path(hlod, "vfc", RuntimeSettings(), path=path, size=SIZE, renderer=renderer)
        whole = node_bytes(hlod, with_uv=True, with_colour=False).sum() + renderer.texture_table.texture_bytes.sum()
        assert out["gpu_resident_bytes_peak"] == whole
    finally:
        renderer.release()
    budget = int(node_bytes(hlod, with_uv=False, with_colour=False).sum())  # the geometry, no texture
    counted = Renderer(gl_ctx, hlod, size=SIZE, counted_images=images, streaming=StreamingSettings(budget_bytes=budget))
    try:
        assert not counted.residency.preload_all
        assert not any(isinstance(o, moderngl.Texture) for o in counted.gl_objects + counted.streamed.gl_objects)
        assert counted.gpu_bytes == counted.residency.resident_bytes > node_bytes(
            hlod, with_uv=False, with_colour=False)[counted.residency.resident].sum()
    finally:
        counted.release()


@pytest.mark.gl
def test_a_streamed_preview_warms_each_mipmap_class_and_frees_what_it_made(gl_ctx, textured_bake, monkeypatch):
    """Streaming makes a node's textures between frames: their first mipmap generation of each shape
    class (the driver's blit compiled on first use) is done once when the preview starts, on small
    textures freed at once; an unlimited preview, which makes every texture at the start, makes none."""
    from hlod_core.render import materials

    hlod, images = textured_bake
    made = []

    def recorded(ctx, image):
        texture = real(ctx, image)
        made.append((image.shape[:2], texture.glo))
        return texture

    real = materials.gl_texture
    monkeypatch.setattr(materials, "gl_texture", recorded)
    is_texture = gl_function(gl_ctx, "glIsTexture", ctypes.c_uint8, ctypes.c_uint32)
    budget = int(node_bytes(hlod, with_uv=True, with_colour=False).sum())
    renderer = Renderer(gl_ctx, hlod, size=SIZE, images=images, streaming=StreamingSettings(budget_bytes=budget))
    try:
        warm = [(shape, name) for shape, name in made if shape in materials.WARM_SHAPES]
        assert [shape for shape, _ in warm] == list(materials.WARM_SHAPES)
        assert made[:len(warm)] == warm  # before the first node's textures
        kept = {t.glo for t in renderer.streamed._textures.values()}
        assert not any(is_texture(name) and name not in kept for _, name in warm)
    finally:
        renderer.release()
    made.clear()
    renderer = Renderer(gl_ctx, hlod, size=SIZE, images=images)
    renderer.release()
    assert made and not any(shape in materials.WARM_SHAPES for shape, _ in made)
