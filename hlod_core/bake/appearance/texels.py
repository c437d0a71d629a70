"""Where an atlas's texels lie on the LOD, and where the sources are nearest to them: the two
geometric steps of a proxy texture's bake (proxy.py).

A face's texels are those whose centres it covers (`texel_samples`), then those a bilinear read on
it takes that no centre filled (`footprint_samples`, at its point nearest each), so a face thinner
than a texel shows its own colour, not the padding's. A texel takes the nearest source point among
the source faces that face its way (`closest_facing`): the nearest point of all would be the far
side of a part thinner than the LOD's offset from it, or a neighbouring object.
docs/how-it-works.md#proxy-materials-for-the-inner-nodes

Data form: an atlas (atlas.Atlas: uvs (j,2) in [0, 1], GL convention, faces (m,3)) over a
width x height image whose row 0 is the bottom row (v = 0); a texel is its flat index
row * width + column, its centre at ((column + 0.5) / width, (row + 0.5) / height) in UV.
Points are float64 model units; sources are (positions (k,3), faces (f,3)) in the same frame.
"""
from __future__ import annotations

import numpy as np

from ..decimate.meshlab import UNIT_DIAGONAL, NodeFrame

#: Texel centres this far outside a triangle (in barycentric units) still count as inside it, so a
#: texel on a shared chart edge is covered once or twice, never dropped.
INSIDE_SLACK = 1e-7
#: How far (texels, along each axis) from a point a bilinear read takes texels: a triangle's
#: footprint_samples are the texels within it that no triangle's centre sample filled.
BILINEAR_REACH = 1.0
#: Texel candidates (bounding-box texels) rasterised at a time: bounds the temporaries.
_BLOCK = 1 << 21
#: The directions a texel's LOD normal is binned by: its dominant one (the largest dot product).
AXES = np.concatenate([np.eye(3), -np.eye(3)])
#: A source face is searched for the texels of an axis where its normal is within 100 degrees of that
#: axis: a face turned away from a texel's normal (more than about 145 degrees, always past 154.7) is
#: never, a face within 90 degrees of it always (a face without area: in every bin).
FACING_COS = float(np.cos(np.radians(100.0)))
#: The second search's grid cell is at least this quantile of the source triangles' longest edges
#: (faces_near): the few longer triangles are always searched, the cells stay small.
NEAR_EDGE_QUANTILE = 0.9


def texel_samples(uvs: np.ndarray, faces: np.ndarray, width: int, height: int):
    """The texels whose centres the atlas's triangles cover: (texel (s,) int64 flat indices, each
    once, ascending; face (s,) int64 the triangle covering it (the lowest of those that do);
    bary (s,3) float64 its barycentric coordinates there). Vectorised over the triangles' texel
    bounding boxes, a block at a time."""
    uv, f = _texel_space(uvs, faces, width, height)
    a, b, c = uv[f[:, 0]], uv[f[:, 1]], uv[f[:, 2]]
    denominator = (b[:, 1] - c[:, 1]) * (a[:, 0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (a[:, 1] - c[:, 1])
    usable = np.abs(denominator) > 1e-18
    lo = np.clip(np.floor(np.minimum(np.minimum(a, b), c) - 0.5), 0, [width - 1, height - 1]).astype(np.int64)
    hi = np.clip(np.ceil(np.maximum(np.maximum(a, b), c) - 0.5), 0, [width - 1, height - 1]).astype(np.int64)
    texels, owners, barys = [], [], []
    for owner, column, row in _candidates(lo, hi, usable):
        px, py = column + 0.5, row + 0.5
        d = denominator[owner]
        l0 = ((b[owner, 1] - c[owner, 1]) * (px - c[owner, 0]) + (c[owner, 0] - b[owner, 0]) * (py - c[owner, 1])) / d
        l1 = ((c[owner, 1] - a[owner, 1]) * (px - c[owner, 0]) + (a[owner, 0] - c[owner, 0]) * (py - c[owner, 1])) / d
        l2 = 1.0 - l0 - l1
        inside = (l0 >= -INSIDE_SLACK) & (l1 >= -INSIDE_SLACK) & (l2 >= -INSIDE_SLACK)
        texels.append(row[inside] * width + column[inside])
        owners.append(owner[inside])
        barys.append(np.clip(np.stack([l0[inside], l1[inside], l2[inside]], axis=1), 0.0, 1.0))
    texel = np.concatenate(texels) if texels else np.zeros(0, np.int64)
    owner = np.concatenate(owners) if owners else np.zeros(0, np.int64)
    bary = np.concatenate(barys) if barys else np.zeros((0, 3))
    # one triangle per texel, the lowest: written in descending order, the last write wins
    which = np.full(width * height, -1, np.int64)
    reverse = np.arange(texel.size - 1, -1, -1)
    which[texel[reverse]] = reverse
    chosen = which[which >= 0]
    bary = bary[chosen]
    bary /= np.maximum(bary.sum(axis=1, keepdims=True), 1e-300)
    return texel[chosen], owner[chosen], bary


def footprint_samples(uvs: np.ndarray, faces: np.ndarray, width: int, height: int, filled: np.ndarray, *,
                      reach: float = BILINEAR_REACH):
    """The texels a bilinear read at some point of an atlas triangle takes (their centres within
    `reach` texels of it along both axes: the triangle touches the square 2 reach wide about the
    centre) that `filled` (width * height,) bool does not hold: (texel (s,) int64 flat indices, each
    once, ascending; face (s,) int64 the triangle nearest its centre, the lowest of equals; bary (s,3)
    float64 the point of that triangle nearest the centre). So a triangle that holds no texel centre
    (a sliver, or one without area in UV) still has texels of its own colour. Vectorised as
    texel_samples; the overlap is a separating-axis test: the two axes by the candidates' boxes,
    the three edge normals by edge functions moved out by the square's half-width along them."""
    uv, f = _texel_space(uvs, faces, width, height)
    filled = np.asarray(filled, bool).reshape(-1)
    corners = uv[f]  # (m,3,2)
    edge = np.roll(corners, -1, axis=1) - corners  # (m,3,2): corner k to corner k + 1
    twice_area = edge[:, 0, 0] * edge[:, 1, 1] - edge[:, 0, 1] * edge[:, 1, 0]
    length2 = np.einsum("mkd,mkd->mk", edge, edge)
    flat = np.abs(twice_area) <= 1e-12 * np.maximum(length2.max(axis=1), 1e-300)
    # edge k's function nx x + ny y + offset, >= 0 inside; a triangle without area: its longest edge's
    # line, both ways, and a third test that always holds
    normal = np.stack([-edge[..., 1], edge[..., 0]], axis=-1) * np.where(twice_area < 0, -1.0, 1.0)[:, None, None]
    longest = normal[np.arange(f.shape[0]), np.argmax(length2, axis=1)]
    normal[flat] = np.stack([longest[flat], -longest[flat], np.zeros_like(longest[flat])], axis=1)
    offset = -np.einsum("mkd,mkd->mk", normal, np.where(flat[:, None, None], corners[:, :1], corners))
    offset += reach * np.abs(normal).sum(axis=2) * (1.0 + 1e-9)
    offset[flat, 2] = 1.0
    nx, ny = normal[..., 0], normal[..., 1]
    margin = reach * (1.0 + 1e-9)
    lo = np.clip(np.ceil(corners.min(axis=1) - margin - 0.5), 0, [width - 1, height - 1]).astype(np.int64)
    hi = np.clip(np.floor(corners.max(axis=1) + margin - 0.5), -1, [width - 1, height - 1]).astype(np.int64)
    texels, owners, distances, barys = [], [], [], []
    for owner, column, row in _candidates(lo, hi):
        texel = row * width + column
        open_ = ~filled[texel]
        owner, texel = owner[open_], texel[open_]
        px, py = column[open_] + 0.5, row[open_] + 0.5
        touches = np.ones(owner.size, bool)
        for k in range(3):
            touches &= nx[owner, k] * px + ny[owner, k] * py + offset[owner, k] >= 0.0
        owner, texel = owner[touches], texel[touches]
        distance, bary = _nearest_in_triangles(np.stack([px[touches], py[touches]], axis=1), corners[owner],
                                               flat=flat[owner])
        texels.append(texel)
        owners.append(owner)
        distances.append(distance)
        barys.append(bary)
    if not texels:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    texel, owner = np.concatenate(texels), np.concatenate(owners)
    distance, bary = np.concatenate(distances), np.concatenate(barys)
    order = np.lexsort((owner, distance, texel))  # by texel, then nearest, then lowest face
    texel, owner, bary = texel[order], owner[order], bary[order]
    first = np.ones(texel.size, bool)
    first[1:] = texel[1:] != texel[:-1]
    return texel[first], owner[first], bary[first]


def _texel_space(uvs: np.ndarray, faces: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """The atlas's UVs in texel units (j,2) float64 (a texel's centre at column + 0.5, row + 0.5) and
    its faces (m,3) int64."""
    return np.asarray(uvs, np.float64) * np.array([width, height], np.float64), np.asarray(faces, np.int64)


def _candidates(lo: np.ndarray, hi: np.ndarray, keep: np.ndarray | None = None):
    """Yields (face (s,), column (s,), row (s,)) int64: each face (those `keep` marks) with every texel
    of its box, columns and rows lo (m,2) to hi (m,2) int64 inclusive, _BLOCK candidates at a time."""
    span = np.maximum(hi - lo + 1, 0)
    count = span[:, 0] * span[:, 1]
    if keep is not None:
        count = np.where(keep, count, 0)
    ends = np.cumsum(count)
    start = 0
    while start < lo.shape[0]:
        stop = int(np.searchsorted(ends, (ends[start - 1] if start else 0) + _BLOCK, side="right"))
        stop = max(stop, start + 1)
        tri = np.arange(start, stop)
        n = count[tri]
        owner = np.repeat(tri, n)
        rank = np.arange(owner.size) - np.repeat(np.cumsum(n) - n, n)
        width_of = np.maximum(span[owner, 0], 1)
        yield owner, lo[owner, 0] + rank % width_of, lo[owner, 1] + rank // width_of
        start = stop


def _nearest_in_triangles(points: np.ndarray, triangles: np.ndarray, *, flat: np.ndarray):
    """(distance (s,) float64, bary (s,3) float64) of the point of each triangle (s,3,2) nearest each
    point (s,2), `flat` (s,) marking triangles without area: the point itself where it is inside
    (barycentric), elsewhere the nearest point of the three edges (their projections clamped)."""
    s = points.shape[0]
    best = np.full(s, np.inf)
    bary = np.zeros((s, 3))
    rows = np.arange(s)
    for k in range(3):
        a, b = triangles[:, k], triangles[:, (k + 1) % 3]
        ab = b - a
        t = np.einsum("sd,sd->s", points - a, ab) / np.maximum(np.einsum("sd,sd->s", ab, ab), 1e-300)
        t = np.clip(t, 0.0, 1.0)
        gap = np.linalg.norm(a + t[:, None] * ab - points, axis=1)
        better = gap < best
        best = np.where(better, gap, best)
        here = np.zeros((s, 3))
        here[rows, k], here[rows, (k + 1) % 3] = 1.0 - t, t
        bary = np.where(better[:, None], here, bary)
    e0, e1, rel = triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0], points - triangles[:, 0]
    area = e0[:, 0] * e1[:, 1] - e0[:, 1] * e1[:, 0]
    safe = np.where(flat | (area == 0.0), 1.0, area)
    l1 = (rel[:, 0] * e1[:, 1] - rel[:, 1] * e1[:, 0]) / safe
    l2 = (e0[:, 0] * rel[:, 1] - e0[:, 1] * rel[:, 0]) / safe
    inside = ~flat & (area != 0.0) & (l1 >= 0.0) & (l2 >= 0.0) & (l1 + l2 <= 1.0)
    best[inside] = 0.0
    bary[inside] = np.stack([1.0 - l1 - l2, l1, l2], axis=1)[inside]
    return best, bary


def closest_on_sources(points: np.ndarray, sources: tuple[np.ndarray, np.ndarray]):
    """For each point (s,3) float64 model units, the nearest point of the sources' surface:
    (face (s,) int64 into sources' faces, bary (s,3) float64 of that point in that face). With
    pymeshlab's closest-point search (vcglib's uniform grid; `transfer_attributes_per_vertex`
    moving each point onto the source surface and carrying the face number as a constant
    per-face vertex quality), in the unit frame of the sources and points (meshlab.NodeFrame)."""
    import pymeshlab

    positions, faces = np.asarray(sources[0]), np.asarray(sources[1], np.int64)
    if points.shape[0] == 0 or faces.shape[0] == 0:
        return np.zeros(points.shape[0], np.int64), np.tile([1.0, 0.0, 0.0], (points.shape[0], 1))
    frame = NodeFrame.of(np.concatenate([np.asarray(positions, np.float64), points]))
    corners = frame.to_local(positions)[faces]  # (f,3,3): one vertex per corner, so quality is per face
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=corners.reshape(-1, 3),
                               face_matrix=np.arange(3 * faces.shape[0], dtype=np.int32).reshape(-1, 3),
                               v_scalar_array=np.repeat(np.arange(faces.shape[0], dtype=np.float64), 3)))
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=frame.to_local(points)))
    ms.transfer_attributes_per_vertex(sourcemesh=0, targetmesh=1, geomtransfer=True, colortransfer=False,
                                      qualitytransfer=True, upperbound=pymeshlab.PureValue(4.0 * UNIT_DIAGONAL))
    moved = ms.current_mesh()
    face = np.clip(np.round(moved.vertex_scalar_array()).astype(np.int64), 0, faces.shape[0] - 1)
    return face, barycentric(moved.vertex_matrix(), corners[face])


def closest_facing(points: np.ndarray, normals: np.ndarray, sources: tuple[np.ndarray, np.ndarray], *,
                   reach: float):
    """As closest_on_sources, but each point (s,3) takes the nearest point of the source faces that
    face its way: those whose normal is within 100 degrees of the axis (AXES) nearest its normal
    (s,3) float, any length (FACING_COS); a point with no such face within `reach` (model units),
    or with a zero normal, the nearest point of all. Returns (face (s,) int64, bary (s,3) float64,
    facing (s,) bool: the face found faces the point's way). The nearest point of all is searched
    first; only the points whose nearest face is turned away are searched again among their bin's
    faces (the same answer as searching every point there: a nearest face that is in the bin is
    the bin's nearest)."""
    positions, faces = np.asarray(sources[0], np.float64), np.asarray(sources[1], np.int64)
    points = np.asarray(points, np.float64)
    face, bary = closest_on_sources(points, (positions, faces))
    if points.shape[0] == 0 or faces.shape[0] == 0:
        return face, bary, np.zeros(points.shape[0], bool)
    corners = positions[faces]
    face_normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    face_normal /= np.maximum(np.linalg.norm(face_normal, axis=1, keepdims=True), 1e-300)
    member = _along_axes(face_normal) >= FACING_COS  # (f,6): the faces searched for each bin
    normals = np.asarray(normals, np.float64)
    point_bin = np.where(np.abs(normals).max(axis=1) > 0, np.argmax(_along_axes(normals), axis=1), -1)
    facing = (point_bin >= 0) & member[face, np.maximum(point_bin, 0)]
    again = np.flatnonzero((point_bin >= 0) & ~facing)
    if again.size and reach > 0:
        found, found_bary = closest_in_bins(points[again], point_bin[again], corners, member, reach=reach)
        hit = found >= 0
        face[again[hit]], bary[again[hit]] = found[hit], found_bary[hit]
        facing[again[hit]] = True
    return face, bary, facing


def _along_axes(vectors: np.ndarray) -> np.ndarray:
    """(n,6) dot products of vectors (n,3) with AXES (x, y, z, -x, -y, -z), without a BLAS call."""
    return np.concatenate([vectors, -vectors], axis=1)


def closest_in_bins(points: np.ndarray, point_bin: np.ndarray, corners: np.ndarray, member: np.ndarray, *,
                     reach: float) -> tuple[np.ndarray, np.ndarray]:
    """For each point (s,3), the nearest point within `reach` model units of the source triangles
    corners (f,3,3) of its bin (point_bin (s,) into member's columns; member (f,b) bool): (face (s,)
    int64, -1 where none is that near; bary (s,3)). One pymeshlab search for every bin: each bin's
    faces and points moved along x by a slot of their own, far enough apart that no point reaches
    another bin's faces; only the faces that can lie within reach of a point (faces_near) are in it."""
    import pymeshlab

    face = np.full(points.shape[0], -1, np.int64)
    bary = np.tile([1.0, 0.0, 0.0], (points.shape[0], 1))
    near = faces_near(points, corners, reach)
    bins = [k for k in range(member.shape[1]) if (point_bin == k).any()]
    binned_faces = [np.flatnonzero(member[:, k] & near) for k in bins]
    if not sum(f.size for f in binned_faces):
        return face, bary
    used = np.unique(np.concatenate(binned_faces))
    frame = NodeFrame.of(np.concatenate([corners[used].reshape(-1, 3), points]))
    reach_local = min(float(reach) * frame.scale, 4.0 * UNIT_DIAGONAL)
    shift = np.array([2.0 * UNIT_DIAGONAL + 2.0 * reach_local, 0.0, 0.0])  # the box is within 1/2 of 0
    slot = np.searchsorted(bins, point_bin).astype(np.float64)
    local = frame.to_local(corners[used].reshape(-1, 3)).reshape(-1, 3, 3)  # rows of `used`
    vertices = np.concatenate([(local[np.searchsorted(used, f)] + i * shift).reshape(-1, 3)
                               for i, f in enumerate(binned_faces)])
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices,
                               face_matrix=np.arange(vertices.shape[0], dtype=np.int32).reshape(-1, 3),
                               v_scalar_array=np.repeat(np.concatenate(binned_faces).astype(np.float64), 3)))
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=frame.to_local(points) + slot[:, None] * shift,
                               v_scalar_array=np.full(points.shape[0], -1.0)))
    ms.transfer_attributes_per_vertex(sourcemesh=0, targetmesh=1, geomtransfer=True, colortransfer=False,
                                      qualitytransfer=True, upperbound=pymeshlab.PureValue(reach_local))
    moved = ms.current_mesh()
    found = np.round(moved.vertex_scalar_array()).astype(np.int64)
    hit = found >= 0
    face[hit] = np.minimum(found[hit], corners.shape[0] - 1)
    bary[hit] = barycentric(moved.vertex_matrix()[hit] - slot[hit, None] * shift,
                            local[np.searchsorted(used, face[hit])])
    return face, bary


def faces_near(points: np.ndarray, corners: np.ndarray, reach: float) -> np.ndarray:
    """(f,) bool: the triangles corners (f,3,3) that may come within `reach` of some point (s,3), s >=
    1, model units, the others certainly not. On a grid of cells as large as reach and
    NEAR_EDGE_QUANTILE of the triangles' longest edges, a triangle whose edges fit a cell and that
    comes within reach of a point has its first corner within 2 cells of the point's along each
    axis; the longer triangles are all kept."""
    centre = 0.5 * (points.min(axis=0) + points.max(axis=0))
    extent = float(np.abs(points - centre).max())
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    cell = max(float(reach), float(np.quantile(longest, NEAR_EDGE_QUANTILE)), extent / (1 << 19), 1e-300)
    span = np.arange(-2, 3)
    around = np.stack(np.meshgrid(span, span, span, indexing="ij"), axis=-1).reshape(-1, 3)  # (125,3)

    def key(c: np.ndarray) -> np.ndarray:  # cells within 2**20 of the centre's: a unique int64 each
        c = c + (1 << 20)
        return (c[..., 0] << 42) | (c[..., 1] << 21) | c[..., 2]

    marked = np.unique(key(np.floor((points - centre) / cell).astype(np.int64)[:, None, :] + around[None]))
    # a corner further than 2**20 - 8 cells out is far from every point (those are within 2**19)
    corner = np.clip(np.floor((corners[:, 0] - centre) / cell), 8 - (1 << 20), (1 << 20) - 8).astype(np.int64)
    return (longest > cell) | np.isin(key(corner), marked)


def barycentric(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(s,3) barycentric coordinates of points (s,3) projected into triangles (s,3,3), clamped to
    the triangle and summing to 1; a degenerate triangle gives its first corner."""
    a = triangles[:, 0]
    v0, v1, v2 = triangles[:, 1] - a, triangles[:, 2] - a, points - a
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    denominator = d00 * d11 - d01 * d01
    ok = denominator > 1e-30 * np.maximum(d00 * d11, 1e-300)
    safe = np.where(ok, denominator, 1.0)
    out = np.empty((points.shape[0], 3))
    out[:, 1] = (d11 * d20 - d01 * d21) / safe
    out[:, 2] = (d00 * d21 - d01 * d20) / safe
    out[:, 0] = 1.0 - out[:, 1] - out[:, 2]
    np.maximum(out, 0.0, out=out)
    np.minimum(out, 1.0, out=out)
    out /= np.maximum(out.sum(axis=1), 1e-300)[:, None]
    out[~ok] = (1.0, 0.0, 0.0)
    return out


def fill_empty(rgba: np.ndarray, filled: np.ndarray) -> np.ndarray:
    """rgba (h,w,4) float32 with `filled` (h,w) bool texels set: the empty texels filled by pull-push
    (the image averaged down over its filled texels only, level by level to 1 x 1, then each empty
    texel given the level below's value at its place, coarse to fine), so the charts' padding holds
    their border colours and the texture's coarser mip levels mix each chart with its neighbours,
    never with a colour that is nowhere on the surface. Returns a new array."""
    out = np.array(rgba, np.float32)
    have = np.asarray(filled, bool)
    if not have.any():
        return out
    levels = [(out * have[..., None], have.astype(np.float32))]  # (weighted sums, weights)
    while max(levels[-1][1].shape) > 1:
        total, weight = levels[-1]
        h, w = weight.shape
        hh, ww = (h + 1) // 2, (w + 1) // 2
        pad = ((0, 2 * hh - h), (0, 2 * ww - w))
        t = np.pad(total, (*pad, (0, 0))).reshape(hh, 2, ww, 2, 4).sum(axis=(1, 3))
        k = np.pad(weight, pad).reshape(hh, 2, ww, 2).sum(axis=(1, 3))
        levels.append((t, k))
    colour = levels[-1][0] / np.maximum(levels[-1][1], 1e-30)[..., None]
    for total, weight in reversed(levels[:-1]):
        h, w = weight.shape
        up = np.repeat(np.repeat(colour, 2, axis=0), 2, axis=1)[:h, :w]
        colour = np.where(weight[..., None] > 0, total / np.maximum(weight, 1e-30)[..., None], up)
    out[~have] = colour[~have]
    return out
