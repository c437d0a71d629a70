"""Which source surface a proxy texel takes its colour from (texels.closest_facing,
docs/how-it-works.md#proxy-materials-for-the-inner-nodes): the nearest point among the source faces
that face the texel's way, so a LOD moved off its sources by free decimation does not take the far
side of a thin part or a neighbouring object's colour. Real pymeshlab searches and real proxy bakes.
"""
from __future__ import annotations

import numpy as np

from hlod_core.bake.appearance.proxy import ProxySettings, SourceLooks, bake_proxy
from hlod_core.bake.appearance.texels import AXES, FACING_COS, closest_facing, closest_in_bins, closest_on_sources
from hlod_core.model.appearance import AttributeLayout, Material

LAYOUT = AttributeLayout(material=True, uv=True, color=False)  # a proxy bake's rows carry UVs
RED, BLUE, GREEN, MAGENTA = (1.0, 0.0, 0.0, 1.0), (0.0, 0.0, 1.0, 1.0), (0.0, 1.0, 0.0, 1.0), (1.0, 0.0, 1.0, 1.0)


def grid(n: int, corner, u, v, *, material: int) -> tuple:
    """An n x n grid of squares on the parallelogram corner + s u + t v (s, t in [0, 1]), its faces
    turned to the normal u x v: (positions (k,3), faces (f,3), rows (k,3): the material id, UV 0)."""
    s, t = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1))
    positions = np.asarray(corner, float) + s.reshape(-1, 1) * np.asarray(u, float) \
        + t.reshape(-1, 1) * np.asarray(v, float)
    index = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    rows = np.zeros((positions.shape[0], 3), np.float32)
    rows[:, 0] = material
    return positions, faces, rows


def merged(*parts) -> tuple:
    """Grids (positions, faces, rows) as one mesh."""
    offsets = np.cumsum([0] + [p[0].shape[0] for p in parts[:-1]])
    return (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] + o for p, o in zip(parts, offsets)]),
            np.concatenate([p[2] for p in parts]))


def proxy_colours(sources: list[tuple], lod: tuple, materials: dict, *, error: float) -> tuple:
    """Bake the proxy of `lod` (positions, faces) over `sources`; (face normals (m,3), the sRGB
    bytes (m,3) its texture holds at each face's centroid)."""
    looks = SourceLooks(materials={k: Material(f"m{k}", base_color=c) for k, c in materials.items()}, chains={})
    proxy = bake_proxy((lod[0], lod[1], None), error, sources, node=1, layout=LAYOUT, looks=looks,
                       scene_materials=len(materials), settings=ProxySettings(texture_cap=64, texture_floor=16))
    p = proxy.positions.astype(np.float64)[proxy.faces]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    uv = proxy.rows[:, 1:3][proxy.faces].mean(axis=1)
    h, w, _ = proxy.image.shape
    row = np.clip(((1.0 - uv[:, 1]) * h).astype(int), 0, h - 1)  # the image's top row first
    column = np.clip((uv[:, 0] * w).astype(int), 0, w - 1)
    return normal, proxy.image[row, column, :3].astype(int)


def test_a_thin_slab_moved_through_by_its_lod_keeps_each_side_its_own_colour():
    # a slab 0.1 thick: its top red (normal +z), its bottom blue (normal -z); its LOD's two sides
    # each moved past the middle, where the other side of the slab is the nearest source point
    top = grid(8, (0, 0, 0.05), (1, 0, 0), (0, 1, 0), material=0)
    bottom = grid(8, (0, 0, -0.05), (0, 1, 0), (1, 0, 0), material=1)
    lod_top = grid(2, (0.1, 0.1, -0.03), (0.8, 0, 0), (0, 0.8, 0), material=0)
    lod_bottom = grid(2, (0.1, 0.1, 0.03), (0, 0.8, 0), (0.8, 0, 0), material=0)
    lod = merged(lod_top, lod_bottom)
    normal, colour = proxy_colours([top, bottom], lod, {0: RED, 1: BLUE}, error=0.1)
    up = normal[:, 2] > 0
    assert up.any() and (~up).any()
    assert np.all(colour[up] == (255, 0, 0)), colour[up]
    assert np.all(colour[~up] == (0, 0, 255)), colour[~up]


def test_a_card_moved_toward_a_neighbour_keeps_its_own_colour():
    # a green card facing +x at x = 0, a magenta wall at x = 0.1 facing it (-x): the card's LOD moved
    # to x = 0.06, nearer the wall than the card
    card = grid(6, (0, 0, 0), (0, 1, 0), (0, 0, 1), material=0)
    wall = grid(6, (0.1, -0.5, -0.5), (0, 0, 2), (0, 2, 0), material=1)
    lod = grid(2, (0.06, 0.1, 0.1), (0, 0.8, 0), (0, 0, 0.8), material=0)
    normal, colour = proxy_colours([card, wall], lod, {0: GREEN, 1: MAGENTA}, error=0.1)
    assert np.all(normal[:, 0] > 0)
    assert np.all(colour == (0, 255, 0)), colour


def test_a_texel_with_no_face_its_way_within_reach_takes_the_nearest_point_of_all():
    # the only source faces turned away (-z): the nearest of them, not nothing
    down = grid(4, (0, 0, 0), (0, 1, 0), (1, 0, 0), material=0)
    points = np.array([[0.3, 0.3, 0.2], [0.7, 0.6, -0.1]])
    up = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    face, bary, facing = closest_facing(points, up, down[:2], reach=1.0)
    plain_face, plain_bary = closest_on_sources(points, down[:2])
    assert not facing.any()
    assert np.array_equal(face, plain_face) and np.allclose(bary, plain_bary)
    # a point without a normal (a LOD face without area) takes the nearest point of all too
    face, _, facing = closest_facing(points, np.zeros((2, 3)), down[:2], reach=1.0)
    assert np.array_equal(face, plain_face) and not facing.any()


def test_searching_again_only_where_the_nearest_face_is_turned_away_finds_what_a_search_of_every_texel_would():
    # a crumpled sheet, both sides: points near it with random normals; the two-step search
    # against every point searched in its bin (the faces of its dominant axis) at once
    rng = np.random.default_rng(3)
    sheet = grid(12, (0, 0, 0), (1, 0, 0), (0, 1, 0), material=0)
    positions = sheet[0] + np.stack([np.zeros(169), np.zeros(169), 0.05 * rng.standard_normal(169)], 1)
    faces = np.concatenate([sheet[1], sheet[1][:, ::-1]])
    points = np.concatenate([rng.uniform(0, 1, (400, 2)), rng.uniform(-0.2, 0.2, (400, 1))], 1)
    normals = rng.standard_normal((400, 3))
    face, bary, facing = closest_facing(points, normals, (positions, faces), reach=1.0)
    corners = positions[faces]
    face_normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    face_normal /= np.linalg.norm(face_normal, axis=1, keepdims=True)
    member = face_normal @ AXES.T >= FACING_COS
    every, every_bary = closest_in_bins(points, np.argmax(normals @ AXES.T, axis=1), corners, member, reach=1.0)
    assert facing.all() and (every >= 0).all()
    found = np.einsum("sk,skd->sd", bary, corners[face])
    searched = np.einsum("sk,skd->sd", every_bary, corners[every])
    assert np.allclose(np.linalg.norm(found - points, axis=1), np.linalg.norm(searched - points, axis=1), atol=1e-9)
    # every face found faces its point's way (within the bins' 100 degrees of its dominant axis)
    assert np.all(member[face, np.argmax(normals @ AXES.T, axis=1)])
    # and the search is the same every time
    again = closest_facing(points, normals, (positions, faces), reach=1.0)
    assert np.array_equal(again[0], face) and np.array_equal(again[1], bary)


def test_the_second_search_keeps_every_face_within_reach_of_a_point_and_leaves_far_ones_out():
    from hlod_core.bake.appearance.texels import faces_near

    rng = np.random.default_rng(5)
    centres = rng.uniform(-0.5, 0.5, (3000, 1, 3))
    corners = centres + rng.uniform(-0.02, 0.02, (3000, 3, 3))
    corners[:20] = centres[:20] + rng.uniform(-0.3, 0.3, (20, 3, 3))  # a few large ones
    points = rng.uniform(-0.5, 0.5, (25, 3))
    reach = 0.03
    near = faces_near(points, corners, reach)
    # points on each triangle (a barycentric lattice): a triangle with one within reach is kept
    lattice = np.array([(i, j, 12 - i - j) for i in range(13) for j in range(13 - i)], float) / 12.0
    on = np.einsum("lk,fkd->fld", lattice, corners)  # (f,l,3)
    distance = np.linalg.norm(on[:, :, None, :] - points[None, None], axis=3).min(axis=(1, 2))
    assert np.all(near[distance <= reach])
    assert (~near).sum() > 1000  # most of the faces, far from the 25 points, are left out
