"""The texels of a face that holds no texel centre (texels.footprint_samples,
docs/how-it-works.md#proxy-materials-for-the-inner-nodes): a sliver chart's texels take its own
source colour, not its atlas neighbour's through pull-push. Hand-made atlases over real pymeshlab
searches.
"""
from __future__ import annotations

import numpy as np

from hlod_core.bake.appearance.atlas import Atlas
from hlod_core.bake.appearance.proxy import SourceLooks, atlas_texture, source_surface
from hlod_core.bake.appearance.texels import footprint_samples, texel_samples
from hlod_core.model.appearance import AttributeLayout, Material

LAYOUT = AttributeLayout(material=True, uv=True, color=False)
#: In texel units of a 16 x 16 atlas (= model units, the surface lying at z = 0 as it lies in UV):
#: a red square chart, and a green sliver chart 1.6 texels to its right, 0.4 texels high, between two
#: rows of texel centres (y = 3.5 and 4.5), so no texel centre is inside it.
SIDE = 16
SQUARE = np.array([[2.0, 2.0], [8.0, 2.0], [8.0, 8.0], [2.0, 8.0]])
SLIVER = np.array([[9.6, 3.55], [14.4, 3.6], [9.7, 3.95]])


def _sources_and_atlas():
    """The two charts as sources (red square: material 0, green sliver: 1) and as an atlas whose
    UVs are the surface's x, y over SIDE."""
    uv = np.concatenate([SQUARE, SLIVER])
    positions = np.concatenate([uv, np.zeros((uv.shape[0], 1))], axis=1)
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6]], np.int64)  # all counter-clockwise: facing +z
    rows = np.zeros((positions.shape[0], 3), np.float32)
    rows[4:, 0] = 1.0
    looks = SourceLooks(materials={0: Material("red", base_color=(1, 0, 0, 1)),
                                   1: Material("green", base_color=(0, 1, 0, 1))}, chains={})
    surface = source_surface([(positions, faces, rows)], LAYOUT, looks)
    atlas = Atlas(vertex_of=np.arange(positions.shape[0]), faces=faces.astype(np.int32),
                  uvs=(uv / SIDE).astype(np.float32), width=SIDE, height=SIDE, texels_per_unit=1.0, utilization=0.2)
    return positions, surface, atlas


def _bilinear(rgba: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(s,4) bilinear reads of rgba (h,w,4), row 0 at v = 0, at points (s,2) in texel units (a texel's
    centre at column + 0.5, row + 0.5), clamped at the edges as a renderer's sampler is."""
    h, w, _ = rgba.shape
    x, y = points[:, 0] - 0.5, points[:, 1] - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]

    def at(r, c):
        return rgba[np.clip(r, 0, h - 1), np.clip(c, 0, w - 1)]

    return ((1 - fx) * (1 - fy) * at(y0, x0) + fx * (1 - fy) * at(y0, x0 + 1)
            + (1 - fx) * fy * at(y0 + 1, x0) + fx * fy * at(y0 + 1, x0 + 1))


def _points_in(triangle: np.ndarray, n: int) -> np.ndarray:
    """n points (n,2) of a triangle (3,2), its corners among them, the rest spread over it."""
    weights = np.random.default_rng(7).dirichlet(np.ones(3), n - 3)
    return np.concatenate([triangle, weights @ triangle])


def test_a_sliver_chart_takes_its_own_colour_not_its_neighbours():
    positions, surface, atlas = _sources_and_atlas()
    texel, _, _ = texel_samples(atlas.uvs, atlas.faces, SIDE, SIDE)
    assert texel.size == 36  # the square's 6 x 6 texel centres, none in the sliver
    rgba, face, _, _ = atlas_texture(atlas, positions, surface, error=0.5, texel_size=1.0)
    on_sliver = _bilinear(rgba, _points_in(SLIVER, 200))
    # what a renderer reads anywhere on the sliver is its own green, nothing of the red chart
    assert np.allclose(on_sliver, (0.0, 1.0, 0.0, 1.0), atol=1e-6), on_sliver[np.argmax(on_sliver[:, 0])]
    on_square = _bilinear(rgba, _points_in(SQUARE[:3], 200))
    assert np.allclose(on_square, (1.0, 0.0, 0.0, 1.0), atol=1e-6)
    assert (face == 2).any()  # the sliver has samples of its own


def test_every_texel_a_bilinear_read_on_a_face_takes_is_sampled_at_the_nearest_face():
    # thin and tiny triangles at random, and one without area: every texel whose centre is within 1
    # texel (along both axes) of a point of a face holds a sample, the footprint's at its nearest face
    rng = np.random.default_rng(3)
    side = 32
    corners = rng.uniform(2.0, side - 2.0, (40, 1, 2)) + rng.normal(0.0, 1.5, (40, 3, 2)) * [[1.0], [1.0], [0.05]]
    corners[0] = [[5.0, 5.2], [9.0, 5.2], [12.0, 5.2]]  # no area in UV
    uvs = corners.reshape(-1, 2) / side
    faces = np.arange(uvs.shape[0]).reshape(-1, 3)
    texel, _, _ = texel_samples(uvs, faces, side, side)
    filled = np.zeros(side * side, bool)
    filled[texel] = True
    extra, extra_face, extra_bary = footprint_samples(uvs, faces, side, side, filled)
    assert not filled[extra].any() and np.all(np.diff(extra) > 0)
    held = filled.copy()
    held[extra] = True
    for k in range(faces.shape[0]):
        points = _points_in(corners[k], 300)
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                column = np.floor(points[:, 0] - 0.5).astype(int) + (dx > 0) + (dx >= 0) - 1
                row = np.floor(points[:, 1] - 0.5).astype(int) + (dy > 0) + (dy >= 0) - 1
                near = (np.abs(column + 0.5 - points[:, 0]) < 1) & (np.abs(row + 0.5 - points[:, 1]) < 1)
                assert held[(row * side + column)[near]].all(), k
    # each footprint sample is at the point nearest the texel's centre of the faces a read there takes
    centre = np.stack([extra % side + 0.5, extra // side + 0.5], axis=1)
    at = np.einsum("sk,skd->sd", extra_bary, corners[extra_face])
    gap = np.linalg.norm(at - centre, axis=1)
    for k in range(faces.shape[0]):
        offset = centre[:, None, :] - _points_in(corners[k], 2000)[None]
        reads = np.abs(offset).max(axis=2) <= 1.0  # a read at that point of face k takes the texel
        distance = np.where(reads, np.linalg.norm(offset, axis=2), np.inf).min(axis=1)
        assert np.all(gap <= distance + 1e-9), k
