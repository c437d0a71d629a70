"""bake.appearance.surface_colour: what a textured surface shows at given points, on tiny literal inputs with
exact expected values (the renderer's colour, sRGB decoded to linear, repeat wrap, mip levels from
the footprint), and the stiff cases (1x1 and 8192x8192 images, far-out UVs, degenerate faces)."""
from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from hlod_core.bake.appearance.surface_colour import MipChain, Surface, colour_at, texture_texels_per_unit
from hlod_core.core.errors import InputError
from hlod_core.model.appearance import Material


def lin(byte: float) -> float:
    """sRGB byte -> linear value (IEC 61966-2-1)."""
    c = byte / 255.0
    return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4


def square(image, *, mode="OPAQUE", base=(1.0, 1.0, 1.0, 1.0), colors=None, uv_scale=1.0) -> Surface:
    """Two triangles over the unit square z=0, UVs = position x uv_scale, one material with `image`."""
    positions = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    images = {} if image is None else {0: MipChain.of(np.asarray(image, np.uint8))}
    return Surface(positions=positions, faces=faces, uvs=positions[:, :2] * np.float32(uv_scale), colors=colors,
                   face_material=np.zeros(2, np.int64), materials=(Material("m", base_color=base, alpha_mode=mode),),
                   images=images)


def bary_of(points_xy) -> tuple[np.ndarray, np.ndarray]:
    """(face, bary) of points of the unit square `square` makes (face 0 below the diagonal)."""
    p = np.asarray(points_xy, np.float64)
    x, y = p[:, 0], p[:, 1]
    lower = x >= y
    face = np.where(lower, 0, 1)
    # face 0: (0,0) (1,0) (1,1) -> weights (1 - x, x - y, y); face 1: (0,0) (1,1) (0,1) -> (1 - y, x, y - x)
    bary = np.where(lower[:, None], np.stack([1 - x, x - y, y], 1), np.stack([1 - y, x, y - x], 1))
    return face, bary


# A 2x2 image, top row first: red, green over blue, white (sRGB bytes).
RED, GREEN, BLUE, WHITE = [255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255], [255, 255, 255, 255]
TWO_BY_TWO = [[RED, GREEN], [BLUE, WHITE]]


def test_a_1x1_texture_is_its_decoded_colour_times_the_base_colour_at_any_uv_and_footprint():
    surface = square([[[255, 128, 0, 255]]], base=(0.5, 1.0, 1.0, 1.0))
    face, bary = bary_of([[0.1, 0.05], [0.9, 0.7], [0.3, 0.8]])
    for footprint in (0.0, 1e-3, 1.0, 1e6):
        got = colour_at(surface, face, bary, footprint=footprint)
        np.testing.assert_allclose(got, [[0.5, lin(128), 0.0, 1.0]] * 3, atol=1e-6)


def test_a_2x2_texture_at_its_texel_centres_with_uv_origin_bottom_left():
    surface = square(TWO_BY_TWO)
    face, bary = bary_of([[0.25, 0.25], [0.75, 0.25], [0.25, 0.75], [0.75, 0.75]])
    got = colour_at(surface, face, bary, footprint=0.0)
    # v up: the image's bottom row (blue, white) is at v = 0.25
    np.testing.assert_allclose(got, np.array([BLUE, WHITE, RED, GREEN]) / 255.0, atol=1e-6)


def test_bilinear_between_texel_centres_averages_in_linear_colour_and_wraps():
    surface = square(TWO_BY_TWO)
    face, bary = bary_of([[0.5, 0.5], [0.0, 0.0]])
    got = colour_at(surface, face, bary, footprint=0.0)
    # at the centre all four texels weigh 1/4; at the corner too, by repeat wrap (the texel centres
    # around (0, 0) are the four corner texels of the next tiles); each channel is 1 in two of them
    np.testing.assert_allclose(got, [[0.5, 0.5, 0.5, 1.0]] * 2, atol=1e-6)


def test_the_footprint_picks_the_mip_level_by_log2_of_footprint_times_texels_per_unit():
    surface = square(TWO_BY_TWO)
    # uv area 1/2, 3D area 1/2, 2 x 2 texels: 2 texels per model unit on both faces
    np.testing.assert_allclose(texture_texels_per_unit(surface), [2.0, 2.0])
    face, bary = bary_of([[0.25, 0.25]])
    mean = [0.5, 0.5, 0.5, 1.0]
    # footprint 0.5 unit = 1 texel: level 0 (blue); 1 unit = 2 texels: level 1, the 1x1 mean;
    # sqrt(2)/2 unit: level 0.5, halfway (trilinear)
    np.testing.assert_allclose(colour_at(surface, face, bary, footprint=0.5)[0], [0, 0, 1, 1], atol=1e-6)
    np.testing.assert_allclose(colour_at(surface, face, bary, footprint=1.0)[0], mean, atol=1e-3)
    half = colour_at(surface, face, bary, footprint=np.sqrt(0.5))[0]
    np.testing.assert_allclose(half, [0.25, 0.25, 0.75, 1.0], atol=1e-3)
    # per-sample footprints: the same three in one call
    three = colour_at(surface, np.repeat(face, 3), np.repeat(bary, 3, axis=0), footprint=np.array([0.5, 1.0, 0.7071]))
    np.testing.assert_allclose(three, [[0, 0, 1, 1], mean, [0.25, 0.25, 0.75, 1.0]], atol=2e-3)


def test_a_checkerboard_seen_over_4_texels_gives_its_mean_in_linear_colour_not_in_srgb():
    # 16 x 16 texels in squares of 2 x 2, black and white: level 2 (4 x 4 texels per texel) is all 0.5 linear
    cells = (np.add.outer(np.arange(16) // 2, np.arange(16) // 2) % 2).astype(np.uint8) * 255
    image = np.dstack([cells, cells, cells, np.full((16, 16), 255, np.uint8)])
    surface = square(image)
    density = texture_texels_per_unit(surface)
    np.testing.assert_allclose(density, [16.0, 16.0])
    points = np.random.default_rng(1).random((50, 2))
    face, bary = bary_of(points)
    got = colour_at(surface, face, bary, footprint=4.0 / 16.0)
    np.testing.assert_allclose(got[:, :3], 0.5, atol=1e-3)  # the sRGB mean would be lin(127.5) = 0.212
    assert abs(lin(127.5) - 0.5) > 0.25
    sharp = colour_at(surface, *bary_of([[1 / 32, 1 / 32], [3 / 32 + 1 / 16, 1 / 32]]), footprint=0.0)
    # level 0: the squares themselves; the bottom rows 14, 15 start white ((7 + 0) % 2 = 1), v up
    np.testing.assert_allclose(sharp[:, 0], [1.0, 0.0], atol=1e-6)


def test_uvs_far_outside_0_1_repeat():
    near = square(TWO_BY_TWO)
    face, bary = bary_of([[0.25, 0.25], [0.75, 0.75], [0.6, 0.3]])
    expected = colour_at(near, face, bary, footprint=0.0)
    for offset in (np.array([1000.0, -999.0]), np.array([-123456.0, 98765.0])):
        far = Surface(positions=near.positions, faces=near.faces, uvs=(near.uvs + offset).astype(np.float64),
                      face_material=near.face_material, materials=near.materials, images=near.images)
        np.testing.assert_allclose(colour_at(far, face, bary, footprint=0.0), expected, atol=2e-4)
    # UV scale 3: the texture repeats 3 times over the square, 6 texels per unit
    tiled = square(TWO_BY_TWO, uv_scale=3.0)
    np.testing.assert_allclose(texture_texels_per_unit(tiled), [6.0, 6.0])
    got = colour_at(tiled, *bary_of([[0.25 / 3 + 2 / 3, 0.25 / 3 + 1 / 3]]), footprint=0.0)
    np.testing.assert_allclose(got[0], np.array(BLUE) / 255, atol=1e-5)


def test_base_colour_vertex_colour_and_texture_multiply_and_blend_keeps_alpha():
    colors = np.array([[0.5, 1.0, 1.0, 0.5]] * 4, np.float32)
    colors[2] = [1.0, 1.0, 1.0, 1.0]  # corner (1, 1)
    surface = square([[[255, 128, 64, 128]]], mode="BLEND", base=(0.5, 0.25, 1.0, 0.5), colors=colors)
    face, bary = bary_of([[0.0, 0.0], [1.0, 1.0], [0.5, 0.5]])
    got = colour_at(surface, face, bary, footprint=0.0)
    vertex = np.array([[0.5, 1, 1, 0.5], [1, 1, 1, 1], [0.75, 1, 1, 0.75]])
    texture = np.array([1.0, lin(128), lin(64), 128 / 255])
    np.testing.assert_allclose(got, np.array([0.5, 0.25, 1.0, 0.5]) * vertex * texture, rtol=1e-5, atol=1e-6)


def test_opaque_materials_and_no_material_give_alpha_1():
    surface = square([[[255, 255, 255, 0]]], base=(1.0, 1.0, 1.0, 0.5), colors=np.full((4, 4), 0.5, np.float32))
    got = colour_at(surface, *bary_of([[0.5, 0.2]]), footprint=0.0)
    np.testing.assert_allclose(got[0, 3], 1.0)
    plain = Surface(positions=surface.positions, faces=surface.faces, colors=surface.colors)
    np.testing.assert_allclose(colour_at(plain, *bary_of([[0.5, 0.2]]), footprint=1.0), [[0.5, 0.5, 0.5, 1.0]])


def test_mip_levels_premultiply_alpha_so_transparent_texels_do_not_bleed():
    # 2 x 1: opaque red beside transparent green; the 1 x 1 level is red at alpha 1/2 (GL's straight
    # average would give (0.5, 0.5, 0) at alpha 1/2)
    surface = square([[[255, 0, 0, 255], [0, 255, 0, 0]]], mode="MASK")
    got = colour_at(surface, *bary_of([[0.5, 0.5]]), footprint=10.0)
    np.testing.assert_allclose(got[0], [1.0, 0.0, 0.0, 0.5], atol=1e-3)
    clear = square([[[0, 255, 0, 0]]], mode="MASK")  # nothing visible: colour 0, alpha 0, finite
    np.testing.assert_allclose(colour_at(clear, *bary_of([[0.5, 0.5]]), footprint=0.0)[0], [0, 0, 0, 0])


def test_odd_sizes_average_exact_areas():
    rng = np.random.default_rng(2)
    image = rng.integers(0, 256, (3, 5, 4), dtype=np.uint8)
    image[..., 3] = 255
    chain = MipChain.of(image)
    assert chain.level_count == 3 and chain.size(1) == (2, 1) and chain.size(2) == (1, 1)
    linear = np.vectorize(lin)(image[::-1, :, :3].astype(np.float64))  # bottom row first
    # level 1 is 2 x 1: texel 0 covers columns 0, 1 and half of 2 (5 / 2 = 2.5 columns), all 3 rows
    weights = np.array([[1, 1, 0.5, 0, 0], [0, 0, 0.5, 1, 1]]) / 2.5
    expected = np.einsum("jc,rck->jk", weights, linear) / 3
    got = chain.sample(np.array([[0.25, 0.5], [0.75, 0.5]]), np.array([1.0, 1.0]))
    np.testing.assert_allclose(got[:, :3], expected, atol=2e-3)  # float16 levels
    top = chain.sample(np.array([[0.3, 0.9]]), np.array([2.0]))
    np.testing.assert_allclose(top[0, :3], linear.mean(axis=(0, 1)), atol=2e-3)


def test_degenerate_faces_give_finite_colours_and_no_density():
    positions = np.array([[0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0], [1e-30, 0, 0]], np.float32)
    uvs = np.array([[0, 0], [1, 0], [0, 1], [0.5, 0.5], [0.5, 0.5], [0.5, 0.5], [1, 1]], np.float32)
    faces = np.array([[0, 1, 2],   # a point in space, a triangle in UV
                      [3, 4, 5],   # a triangle in space, a point in UV
                      [0, 4, 6]])  # a line in space
    images = {0: MipChain.of(np.array(TWO_BY_TWO, np.uint8))}
    surface = Surface(positions=positions, faces=faces, uvs=uvs, face_material=np.zeros(3, np.int64),
                      materials=(Material("m", alpha_mode="MASK"),), images=images)
    np.testing.assert_array_equal(texture_texels_per_unit(surface), [0.0, 0.0, 0.0])
    face = np.repeat(np.arange(3), 4)
    bary = np.tile([[1, 0, 0], [1 / 3, 1 / 3, 1 / 3], [0, 0.5, 0.5], [0, 0, 1]], (3, 1))
    for footprint in (0.0, 1.0, np.inf, 1e300):
        got = colour_at(surface, face, bary, footprint=footprint)
        assert got.shape == (12, 4) and got.dtype == np.float32 and np.all(np.isfinite(got))


def test_an_8192_texture_samples_its_image_without_building_levels_and_wide_levels_stay_small():
    image = np.broadcast_to(np.array([200, 100, 50, 255], np.uint8), (8192, 8192, 4))  # no memory
    chain = MipChain.of(image)
    assert chain.level_count == 14 and chain.nbytes == image.nbytes
    uv = np.random.default_rng(3).random((1000, 2)) * 10 - 5
    got = chain.sample(uv, np.zeros(1000))
    np.testing.assert_allclose(got[:, :3], [[lin(200), lin(100), lin(50)]] * 1000, rtol=1e-6)
    assert chain.nbytes == image.nbytes  # level 0 needs no level built
    # a strip 8192 wide: its 14 levels, all built by a coarse sample, hold 2 x 8192 x 4 float16 at most
    strip = MipChain.of(np.broadcast_to(image[:4], (4, 8192, 4)))
    got = strip.sample(uv, np.full(1000, 13.0))
    np.testing.assert_allclose(got[:, :3], [[lin(200), lin(100), lin(50)]] * 1000, rtol=2e-3)
    assert strip.nbytes - strip.image.nbytes < 2 * 8192 * 4 * 2


@pytest.mark.slow
def test_the_whole_chain_of_an_8192_texture_holds_its_float16_levels_and_little_more():
    image = np.broadcast_to(np.array([200, 100, 50, 255], np.uint8), (8192, 8192, 4))
    chain = MipChain.of(image)
    tracemalloc.start()
    try:
        got = chain.sample(np.array([[0.3, 0.4], [0.5, 0.5]]), np.array([20.0, 12.5]))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    np.testing.assert_allclose(got[:, :3], [[lin(200), lin(100), lin(50)]] * 2, rtol=2e-3)
    levels = sum(4 * 2 * (8192 >> k) ** 2 for k in range(1, 14))  # float16 RGBA
    assert chain.nbytes == image.nbytes + levels  # 171 MiB
    assert peak < levels + 64 * 2**20, peak / 2**20  # the bands: BAND_TEXELS x 16 B, twice


def test_bad_input_is_refused_with_a_clear_error():
    with pytest.raises(InputError, match="uint8 RGBA"):
        MipChain.of(np.zeros((2, 2, 3), np.uint8))
    surface = square(TWO_BY_TWO)
    with pytest.raises(InputError, match="outside 0..1"):
        colour_at(surface, np.array([2]), np.array([[1.0, 0, 0]]), footprint=0.0)
    with pytest.raises(InputError, match="barycentric"):
        colour_at(surface, np.array([0, 1]), np.array([[1.0, 0, 0]]), footprint=0.0)
