"""bake.appearance.quality: the numpy renderer of a Surface (coverage, z-buffer, MASK and BLEND) and the
proxy's PSNR-Y against its sources, on literal squares and spheres with values computed by hand."""
from __future__ import annotations

import time

import numpy as np
import pytest

from hlod_core.bake.appearance.quality import DIRECTIONS, GATE_DB, PSNR_CAP_DB, luma, node_psnr, render
from hlod_core.bake.appearance.surface_colour import MipChain, Surface
from hlod_core.model.appearance import Material

UP = np.array([0.0, 0.0, 1.0])  # the view looks down -z: nearer is larger z
SQUARE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float64)
TWO = np.array([[0, 1, 2], [0, 2, 3]])


def srgb_grey(value: float) -> tuple:
    """Linear RGBA of the grey whose sRGB encoding is `value`."""
    c = value / 12.92 if value <= 0.04045 else ((value + 0.055) / 1.055) ** 2.4
    return (c, c, c, 1.0)


def square(base=(0.5, 0.5, 0.5, 1.0), *, scale=1.0, z=0.0, mode="OPAQUE", image=None) -> Surface:
    """The unit square (x scale) at height z, one material."""
    images = {} if image is None else {0: MipChain.of(np.asarray(image, np.uint8))}
    return Surface(positions=SQUARE * scale + [0, 0, z], faces=TWO, uvs=SQUARE[:, :2].astype(np.float32),
                   face_material=np.zeros(2, np.int64), materials=(Material("m", base_color=base, alpha_mode=mode),),
                   images=images)


def merged(*surfaces: Surface) -> Surface:
    """One surface of several one-material surfaces, material i for surface i."""
    offsets = np.cumsum([0] + [len(s.positions) for s in surfaces])
    return Surface(positions=np.concatenate([s.positions for s in surfaces]),
                   faces=np.concatenate([s.faces + o for s, o in zip(surfaces, offsets)]),
                   uvs=np.concatenate([s.uvs for s in surfaces]),
                   face_material=np.concatenate([np.full(len(s.faces), i) for i, s in enumerate(surfaces)]),
                   materials=tuple(s.materials[0] for s in surfaces),
                   images={i: s.images[0] for i, s in enumerate(surfaces) if s.images})


def uv_sphere(rows: int, cols: int, chain: MipChain) -> Surface:
    """A unit UV sphere of 2 rows cols triangles (those at the poles degenerate), spherical UVs."""
    theta, phi = np.meshgrid(np.linspace(0, np.pi, rows + 1), np.linspace(0, 2 * np.pi, cols + 1), indexing="ij")
    positions = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1).reshape(-1, 3)
    uvs = np.stack([phi / (2 * np.pi), 1 - theta / np.pi], -1).reshape(-1, 2).astype(np.float32)
    grid = np.arange((rows + 1) * (cols + 1)).reshape(rows + 1, cols + 1)
    a, b, c, d = grid[:-1, :-1], grid[:-1, 1:], grid[1:, 1:], grid[1:, :-1]
    faces = np.concatenate([np.stack([a, d, c], -1).reshape(-1, 3), np.stack([a, c, b], -1).reshape(-1, 3)])
    return Surface(positions=positions, faces=faces, uvs=uvs, face_material=np.zeros(len(faces), np.int64),
                   materials=(Material("t"),), images={0: chain})


def stripes() -> MipChain:
    """256 x 256: red ramp across, green squares of 32 texels, blue ramp up."""
    y, x = np.mgrid[:256, :256]
    image = np.dstack([x, ((x // 32 + y // 32) % 2) * 200, y, np.full_like(x, 255)]).astype(np.uint8)
    return MipChain.of(image)


def test_render_covers_the_pixels_whose_centres_lie_inside_and_shows_the_colour():
    r = render(square(), direction=UP, center=np.array([0.5, 0.5, 0.0]), radius=1.0, pixel_size=0.1)
    assert r.rgb.shape == (20, 20, 3) and r.pixel_size == 0.1
    # the square spans x, y in [0, 1] = pixels 5..14 of the 20 over [-0.5, 1.5]
    expected = np.zeros((20, 20), bool)
    expected[5:15, 5:15] = True
    np.testing.assert_array_equal(r.coverage, expected)
    np.testing.assert_allclose(r.rgb[expected], 0.5)
    np.testing.assert_allclose(r.rgb[~expected], srgb_grey(0.5)[0], rtol=1e-6)  # the mid-grey background


def test_render_grows_the_pixel_past_max_side_and_orients_right_and_up():
    red_left = merged(square((1, 0, 0, 1), scale=0.5), square((0, 0, 1, 1), scale=0.5))
    red_left.positions[4:] += [0.5, 0.5, 0]  # the blue one at the upper right
    r = render(red_left, direction=UP, center=np.array([0.5, 0.5, 0.0]), radius=0.5, pixel_size=1e-6, max_side=8)
    assert r.rgb.shape == (8, 8, 3) and r.pixel_size == pytest.approx(0.125)
    np.testing.assert_allclose(r.rgb[0, 0], [1, 0, 0])  # row 0 is the bottom, column 0 the left (x)
    np.testing.assert_allclose(r.rgb[7, 7], [0, 0, 1])


def test_the_z_buffer_keeps_the_nearest_surface_from_either_side():
    both = merged(square((1, 0, 0, 1), z=0.0), square((0, 1, 0, 1), z=0.5))
    kw = dict(center=np.array([0.5, 0.5, 0.25]), radius=1.0, pixel_size=0.1)
    np.testing.assert_allclose(render(both, direction=UP, **kw).rgb[10, 10], [0, 1, 0])
    np.testing.assert_allclose(render(both, direction=-UP, **kw).rgb[10, 10], [1, 0, 0])


def test_mask_below_its_cutoff_is_not_drawn_and_shows_what_is_behind():
    # 2 x 1 texture: opaque white at u < 1/2, clear at u > 1/2 (bilinear alpha >= 1/2 for u in [0, 1/2])
    leaf = square(mode="MASK", z=0.5, image=[[[255, 255, 255, 255], [255, 255, 255, 0]]], base=(1, 1, 1, 1))
    ground = square((1, 0, 0, 1))
    r = render(merged(leaf, ground), direction=UP, center=np.array([0.5, 0.5, 0.25]), radius=1.0, pixel_size=0.1)
    np.testing.assert_allclose(r.rgb[10, 5:10], 1.0)  # u = 0.05 .. 0.45: the leaf
    np.testing.assert_allclose(r.rgb[10, 10:15], [[1, 0, 0]] * 5)  # u = 0.55 .. 0.95: the ground
    alone = render(leaf, direction=UP, center=np.array([0.5, 0.5, 0.25]), radius=1.0, pixel_size=0.1)
    assert alone.coverage[10, 5:10].all() and not alone.coverage[10, 10:15].any()


def test_blend_layers_composite_front_to_back_over_what_is_behind():
    red = square((1, 0, 0, 1))
    blue = square((0, 0, 1, 0.5), z=0.25, mode="BLEND")
    green = square((0, 1, 0, 0.5), z=0.5, mode="BLEND")
    r = render(merged(red, green, blue), direction=UP, center=np.array([0.5, 0.5, 0.25]), radius=1.0, pixel_size=0.1)
    np.testing.assert_allclose(r.rgb[10, 10], [0.25, 0.5, 0.25], atol=1e-6)  # 1/2 green + 1/4 blue + 1/4 red
    # the same everywhere, also on the diagonal (pixel centres on both triangles' shared edge, drawn once)
    np.testing.assert_allclose(r.rgb[5:15, 5:15].reshape(-1, 3), [[0.25, 0.5, 0.25]] * 100, atol=1e-6)
    faint = square((1, 1, 1, 0.25), mode="BLEND")
    f = render(faint, direction=UP, center=np.array([0.5, 0.5, 0.0]), radius=1.0, pixel_size=0.1)
    np.testing.assert_allclose(f.rgb[10, 10], 0.25 + 0.75 * srgb_grey(0.5)[0], rtol=1e-6)
    assert not f.coverage.any()  # opacity 1/4 < 1/2
    two = render(merged(faint, square((1, 1, 1, 0.5), z=0.1, mode="BLEND")), direction=UP,
                 center=np.array([0.5, 0.5, 0.0]), radius=1.0, pixel_size=0.1)
    assert two.coverage[10, 10]  # opacity 1 - 3/4 x 1/2 = 5/8


def test_identical_surfaces_give_the_cap():
    surface = uv_sphere(8, 16, stripes())
    assert node_psnr(surface, surface, error=0.05) == (PSNR_CAP_DB, None)


def test_a_grey_step_of_a_tenth_gives_20_db_named_as_colour():
    # every covered pixel differs by 0.1 in sRGB R', G' and B', so by 0.1 in Y: 10 log10(1 / 0.01) = 20 dB
    source, proxy = square(srgb_grey(0.5)), square(srgb_grey(0.6))
    db, reason = node_psnr(proxy, source, error=0.02)
    assert db == pytest.approx(20.0, abs=0.01)
    assert reason.startswith("colour:") and "differs on 0% of pixels" in reason
    # a step of 0.04: 27.96 dB, over the gate
    db, reason = node_psnr(square(srgb_grey(0.54)), source, error=0.02)
    assert db == pytest.approx(-20 * np.log10(0.04), abs=0.02) and db > GATE_DB and reason is None


def test_a_shrunken_proxy_is_named_as_a_silhouette_difference():
    white = srgb_grey(1.0)
    source, proxy = square(white), square(white, scale=0.5)
    db, reason = node_psnr(proxy, source, error=0.02)
    # 3/4 of the covered pixels show grey 0.5 instead of white: Y differs by 0.5 there, MSE 3/16
    assert db == pytest.approx(10 * np.log10(16 / 3), abs=0.2)
    assert reason.startswith("silhouette: coverage differs on 75% of pixels")


def test_luma_is_bt601_on_srgb_encoded_values():
    np.testing.assert_allclose(luma(np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])),
                               [0.299, 0.587, 0.114, 1.0], rtol=1e-6)
    np.testing.assert_allclose(luma(np.array(srgb_grey(0.5)[:3])), 0.5, rtol=1e-5)


def test_degenerate_nodes_stay_finite():
    one = Surface(positions=np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float64), faces=np.array([[0, 1, 2]]))
    assert node_psnr(one, one, error=0.01) == (PSNR_CAP_DB, None)
    db, reason = node_psnr(one, square(), error=0.01)
    assert np.isfinite(db) and reason is not None
    # every triangle at one point: nothing is drawn in either render, nothing differs
    point = Surface(positions=np.full((4, 3), 3.0), faces=TWO)
    assert node_psnr(point, point, error=0.0) == (PSNR_CAP_DB, None)
    db, _ = node_psnr(point, one, error=0.0)
    assert np.isfinite(db)
    # a sliver a texel wide: 1 unit long, 1e-3 wide, textured; error 1e-3 asks for 2000 pixels, max_side gives 128
    sliver = Surface(positions=np.array([[0, 0, 0], [1, 0, 0], [1, 1e-3, 0]], np.float64), faces=np.array([[0, 1, 2]]),
                     uvs=np.array([[0, 0], [1, 0], [1, 1]], np.float32), face_material=np.zeros(1, np.int64),
                     materials=(Material("s"),), images={0: stripes()})
    for error in (1e-3, 0.0, np.inf, np.nan):
        db, reason = node_psnr(sliver, sliver, error=error)
        assert db == PSNR_CAP_DB and reason is None
    db, reason = node_psnr(point, sliver, error=1e-3)
    assert np.isfinite(db)


def test_a_lossless_node_is_seen_at_max_side_pixels():
    # error 0: pixel = 2 radius / max_side; the grey step of a tenth still gives 20 dB
    db, reason = node_psnr(square(srgb_grey(0.6)), square(srgb_grey(0.5)), error=0.0, max_side=32)
    assert db == pytest.approx(20.0, abs=0.01) and reason.startswith("colour")


def test_time_of_a_16k_triangle_source_at_128_pixels():
    chain = stripes()
    source, proxy = uv_sphere(64, 128, chain), uv_sphere(12, 24, chain)
    assert len(source.faces) == 16384
    start = time.perf_counter()
    db, reason = node_psnr(proxy, source, error=2.0 / 128)  # 128 x 128 pixels over the sphere
    seconds = time.perf_counter() - start
    six_start = time.perf_counter()
    db_six, _ = node_psnr(proxy, source, error=2.0 / 128, directions=DIRECTIONS[:6])
    six = time.perf_counter() - six_start
    print(f"\nnode_psnr, 16,384 against 576 triangles, 128 x 128 pixels: 14 directions {seconds:.2f} s "
          f"({db:.2f} dB, {reason}); 6 directions {six:.2f} s ({db_six:.2f} dB)")
    assert 15.0 < db < PSNR_CAP_DB and 15.0 < db_six < PSNR_CAP_DB
