"""Coarse levels that reach their budget (docs/how-it-works.md#decimating-a-node): only the seams a
node shares with neighbouring cells stay locked, the models' own open boundaries collapse where
the budget needs it, pieces below the error go, and the guarantees hold: seams between nodes of
one level coincide bit for bit, the error bounds what was dropped, every inner node within 1.25 x
target_tris. Inputs are procedural (hlod_core.io.procedural), so they need no files."""
import numpy as np
import pytest

from hlod_core.bake import prepare
from hlod_core.bake.decimate import cell_seams, meshlab, pieces, simplify
from hlod_core.bake.decimate.collapse import OVER_BUDGET_FACTOR
from hlod_core.bake.pipeline import bake
from hlod_core.bake.settings import BakeSettings
from hlod_core.bake.space.octree import build_octree
from hlod_core.core.arrays import compact, concat_indexed
from hlod_core.io import meshes, procedural

#: The pieces scene at a quarter of its size (30k triangles: 2 scans, 2,500 cards, 100 bolts),
#: baked at this target: about 5 s on 2 cores, 5 levels.
PIECES_SCALE, PIECES_TARGET = 0.25, 500


@pytest.fixture(scope="module")
def pieces_bake():
    mesh = procedural.pieces_scene(seed=1, scale=PIECES_SCALE)
    return mesh, bake(mesh, BakeSettings(jobs=2, target_tris=PIECES_TARGET))


def _open_scan_halves():
    """An open scan (open base, 6 holes; 12k triangles) cut at x = 0 by triangle centroid, as a
    cell boundary cuts it: the left half's triangles as two children, and the positions it
    shares with the right half (float32)."""
    rng = np.random.default_rng(3)
    p, f = procedural.open_scan([0.0, 0.0, 0.0], 1.0, rng=rng, segments=96, rings=64, holes=6)
    p = p.astype(np.float32)
    left = p[f].mean(axis=1)[:, 0] < 0
    used = np.zeros((2, p.shape[0]), bool)
    used[0, f[left].ravel()] = True
    used[1, f[~left].ravel()] = True
    half = f[left]
    children = [compact(p, part)[:2] for part in (half[: half.shape[0] // 2], half[half.shape[0] // 2:])]
    return children, p[used[0] & used[1]]


def _keys(positions: np.ndarray) -> set[bytes]:
    return {row.tobytes() for row in np.ascontiguousarray(positions, np.float32)}


def test_cell_seams_stay_bit_identical_while_open_boundaries_collapse_to_the_budget():
    """Half an open scan (4,169 triangles), decimated to 100 triangles: its rims (base and holes,
    87 vertices) and its 91 seam vertices kept in place hold the LOD at 177 triangles, as when
    every open edge was locked (seams=None, a caller that does not know the neighbours). Told which
    positions are cell seams, the node keeps exactly those, bit for bit, and lets its rims collapse
    to the budget."""
    children, seams = _open_scan_halves()
    target = 100
    settings = meshlab.DecimationSettings(target_tris=target)
    welded = simplify.weld(*concat_indexed(children))
    _, rim, border = cell_seams.node_borders(welded[0], welded[1].astype(np.int64), seams)
    assert seams.shape[0] > 50 and rim.sum() > 50  # the half's own open boundaries: base and holes
    all_locked = simplify.decimate_node(children, settings, with_normals=False)
    assert all_locked.faces.shape[0] > 1.5 * target and not all_locked.open_boundaries_freed
    assert _keys(welded[0][border]) <= _keys(all_locked.positions)  # every open-edge vertex stayed
    lod = simplify.decimate_node(children, settings, with_normals=False, seams=seams)
    assert lod.open_boundaries_freed and lod.faces.shape[0] <= OVER_BUDGET_FACTOR * target
    assert lod.locked_vertices == len(_keys(seams))  # the sphere's UV seam repeats a position
    assert _keys(seams) <= _keys(lod.positions)  # the seams, bit for bit
    assert len(_keys(welded[0][rim]) & _keys(lod.positions)) < rim.sum() / 2  # most rim vertices went


def test_a_node_within_budget_keeps_its_open_boundaries_exactly():
    """Where the LOD with the rims in place fits the budget, the rims stay: the same LOD as with
    every open edge locked (the collapse with boundary preservation), bit for bit."""
    children, seams = _open_scan_halves()
    settings = meshlab.DecimationSettings(target_tris=1500)
    lod = simplify.decimate_node(children, settings, with_normals=False, seams=seams)
    locked = simplify.decimate_node(children, settings, with_normals=False)
    assert not lod.open_boundaries_freed and lod.faces.shape[0] <= 1500
    assert np.array_equal(lod.positions, locked.positions) and np.array_equal(lod.faces, locked.faces)


def test_pieces_below_the_error_are_dropped_and_counted():
    """A closed sphere of radius 1 (4,800 triangles) with 60 bolts of 2 cm on its surface (12
    triangles each), decimated to 300 triangles: the sphere's LOD is off by about 0.03, more than a
    bolt's extent, and every bolt lies on the surface, so the bolts go. pruned_pieces counts the
    pieces the LOD lost, which its connected pieces confirm, and pruned_tris their triangles."""
    rng = np.random.default_rng(5)
    parts = [procedural.uv_sphere([0.0, 0.0, 0.0], 1.0, segments=60, rings=40)]
    normal = rng.normal(size=(60, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    parts += [procedural.box(n - 0.01, n + 0.01, 1) for n in normal]
    p, f = concat_indexed(parts)
    positions, faces = simplify.weld(p.astype(np.float32), f)
    lod = simplify.decimate_node([(positions, faces)], meshlab.DecimationSettings(target_tris=300), with_normals=False,
                                 seams=np.zeros((0, 3), np.float32))
    assert lod.pieces == 61 and lod.faces.shape[0] <= 300
    assert lod.pruned_pieces >= 50 and lod.pruned_tris == 12 * lod.pruned_pieces
    labels = pieces.components(lod.faces, lod.positions.shape[0])
    assert np.unique(labels[lod.faces[:, 0]]).size == lod.pieces - lod.pruned_pieces


def test_components_label_pieces_by_their_lowest_vertex():
    """Two triangles sharing vertex 2, a lone triangle, and an unused vertex 7: three pieces."""
    faces = np.array([[4, 2, 3], [0, 1, 2], [5, 6, 8]])
    assert pieces.components(faces, 9).tolist() == [0, 0, 0, 0, 0, 5, 5, 7, 5]


def test_cell_seams_are_the_positions_leaves_inside_and_outside_a_node_share():
    """A strip of 8 x 2 quads (32 triangles) split at 4 triangles per leaf. A node's seams are the
    positions its triangles share with triangles outside it: none for the root, and for every
    other node exactly those (checked against the triangles themselves)."""
    p, f = procedural.grid_patch([0.0, 0.0, 0.0], [8.0, 0.0, 0.0], [0.0, 2.0, 0.5], nu=8, nv=2)
    mesh = meshes.from_arrays(p, f, name="strip")
    prepared = prepare.prepare(mesh)
    layout = build_octree(prepared.centroids, target_tris=4, max_depth=12, counted=prepared.counted,
                          root=prepared.root_cell)
    seams = cell_seams.build(layout, prepare.leaf_lods(layout, prepared))
    assert seams.locked(0).shape == (0, 3)
    for node in range(1, layout.node_count):
        tris = prepared.faces[layout.tri_order[layout.tri_begin[node]:layout.tri_end[node]]]
        inside = _keys(prepared.positions[np.unique(tris)])
        outside = _keys(prepared.positions[np.unique(np.delete(prepared.faces, layout.tri_order[
            layout.tri_begin[node]:layout.tri_end[node]], axis=0))])
        assert _keys(seams.locked(node)) == inside & outside, node
    assert layout.node_count > 8 and sum(seams.locked(n).shape[0] > 0 for n in range(1, layout.node_count)) > 8


def test_every_inner_node_reaches_its_budget_on_open_boundaries_and_pieces(pieces_bake):
    """The pieces scene (open scans, foliage cards, a machine of 60 patches and bolts): every inner
    node within 1.25 x target_tris (no card could collapse and no rim moved before, which held
    nodes of it far over), pieces dropped and counted in meta, the log and the summary, and the
    bake's checks hold."""
    from hlod_core.bake import checks

    mesh, hlod = pieces_bake
    inner = ~hlod.is_leaf
    assert hlod.tri_count[inner].max() <= OVER_BUDGET_FACTOR * PIECES_TARGET
    assert hlod.meta["nodes_over_budget"] == 0 and hlod.summary()["nodes_over_budget"] == 0
    assert hlod.meta["pruned_pieces"] > 100 and hlod.meta["pruned_tris"] >= hlod.meta["pruned_pieces"]
    assert hlod.summary()["pruned_pieces"] == hlod.meta["pruned_pieces"]
    assert any(line.startswith("pruned ") for line in hlod.meta["log"])
    assert all(checks.check(hlod)["checks"].values())


def _node_mesh(hlod, node: int) -> tuple[np.ndarray, np.ndarray]:
    v0, t0 = int(hlod.vertex_offset[node]), int(hlod.tri_offset[node])
    faces = hlod.indices[t0:t0 + int(hlod.tri_count[node])].astype(np.int64) - v0
    return hlod.positions[v0:v0 + int(hlod.vertex_count[node])], faces


def _leaves_below(hlod, node: int) -> np.ndarray:
    below, todo = [], [node]
    while todo:
        n = todo.pop()
        if hlod.child_count[n] == 0:
            below.append(n)
        todo.extend(range(int(hlod.child_offset[n]), int(hlod.child_offset[n] + hlod.child_count[n])))
    return np.array(sorted(below))


def test_the_stored_error_bounds_every_original_vertex_dropped_pieces_included(pieces_bake):
    """Every original vertex below an inner node, those of the pieces its LOD dropped included, lies
    within the node's stored error of its LOD's surface (the exact measure samples every one)."""
    _, hlod = pieces_bake
    for node in np.flatnonzero(~hlod.is_leaf):
        lod_p, lod_f = _node_mesh(hlod, node)
        original = np.concatenate([_node_mesh(hlod, leaf)[0] for leaf in _leaves_below(hlod, node)])
        frame = meshlab.NodeFrame.of(np.concatenate([lod_p, original]))
        distance = meshlab.point_distances(frame.to_local(original), frame.to_local(lod_p), lod_f) / frame.scale
        assert distance.max() <= hlod.error[node] * (1 + 1e-5) + 1e-9 * np.abs(original).max(), node


def _cover(hlod, depth: int) -> np.ndarray:
    """(n,) the node of the cut at `depth` (nodes at that depth, leaves above it) each node lies in."""
    owner = np.arange(hlod.node_count)
    for node in range(hlod.node_count):  # parents come before their children
        if hlod.depth[node] > depth:
            owner[node] = owner[hlod.parent[node]]
    return owner


def _node_edges(hlod, node: int, position_id: np.ndarray) -> np.ndarray:
    """(3m,) int64 keys of a node's edges by the ids of their ends' exact float32 positions, over its
    triangles with three distinct positions (a collapsed one draws nothing, and welding drops it)."""
    t0 = int(hlod.tri_offset[node])
    ids = position_id[hlod.indices[t0:t0 + int(hlod.tri_count[node])].astype(np.int64)]
    ids = ids[(ids[:, 0] != ids[:, 1]) & (ids[:, 1] != ids[:, 2]) & (ids[:, 0] != ids[:, 2])]
    a, b = ids[:, [0, 1, 2]].ravel(), ids[:, [1, 2, 0]].ravel()
    return np.minimum(a, b) * (int(position_id.max()) + 1) + np.maximum(a, b)


@pytest.mark.parametrize("which", ["pieces", "bunny"])
def test_nodes_of_one_level_meet_bit_for_bit_along_their_seams(which, pieces_bake, bakes):
    """At every level (the nodes at one depth, and the leaves above it), each edge the original
    triangles of two of its nodes share is an edge, bit for bit, of both nodes' LODs: no crack."""
    hlod = pieces_bake[1] if which == "pieces" else bakes.baked("bunny")[1]
    bits = np.ascontiguousarray(hlod.positions, np.float32).view(np.dtype((np.void, 12))).ravel()
    position_id = np.unique(bits, return_inverse=True)[1].reshape(-1)
    leaves = np.flatnonzero(hlod.is_leaf)
    leaf_edges = [_node_edges(hlod, leaf, position_id) for leaf in leaves]
    checked = 0
    for depth in range(int(hlod.depth.max())):
        owner = np.repeat(_cover(hlod, depth)[leaves], [e.size for e in leaf_edges])
        pairs = np.unique(np.stack([np.concatenate(leaf_edges), owner], axis=1), axis=0)  # (edge, cover node)
        shared = np.zeros(pairs.shape[0], bool)
        same = pairs[1:, 0] == pairs[:-1, 0]  # one edge in two cover nodes
        shared[1:] |= same
        shared[:-1] |= same
        for node in np.unique(pairs[shared, 1]):
            mine = pairs[shared & (pairs[:, 1] == node), 0]
            assert np.isin(mine, _node_edges(hlod, node, position_id)).all(), (depth, node)
            checked += mine.size
    assert checked > 100


def _keys_of(mesh, *, with_seams: bool) -> list[bytes]:
    """The bake cache's node keys of `mesh` at 4 triangles per leaf (cache_keys.node_keys)."""
    from hlod_core.bake.run import cache_keys

    prepared = prepare.prepare(mesh)
    layout = build_octree(prepared.centroids, target_tris=4, max_depth=12, counted=prepared.counted,
                          root=prepared.root_cell)
    lods = prepare.leaf_lods(layout, prepared)
    seams = cell_seams.build(layout, lods) if with_seams else None
    return cache_keys.node_keys(layout, lods, origin=prepared.origin, context=bytes(32),
                                unit_length=prepared.unit_length, seams=seams)


def test_the_cache_keys_an_inner_node_by_its_seams_too():
    """Two strips of 8 x 2 quads, the same but for one vertex on x = 4, where the halves meet: in the
    second, the right half's triangles use a copy of it moved by 1e-3 along x. The left half's
    nodes keep their cells and triangles, and lose a seam: their keys must change (a node's LOD
    depends on the seams it keeps), and they do only because the keys hash the seams."""
    p, f = procedural.grid_patch([0.0, 0.0, 0.0], [8.0, 0.0, 0.0], [0.0, 2.0, 0.5], nu=8, nv=2)
    meeting = int(np.flatnonzero((p[:, 0] == 4.0) & (p[:, 1] == 0.0))[0])  # on the strip's edge: one left node has it
    right = p[f].mean(axis=1)[:, 0] > 4.0
    moved_p = np.concatenate([p, p[meeting:meeting + 1] + [1e-3, 0.0, 0.0]])
    moved_f = f.copy()
    moved_f[right] = np.where(f[right] == meeting, p.shape[0], f[right])
    a, b = meshes.from_arrays(p, f, name="strip"), meshes.from_arrays(moved_p, moved_f, name="strip")
    plain = [x == y for x, y in zip(_keys_of(a, with_seams=False), _keys_of(b, with_seams=False))]
    seamed = [x == y for x, y in zip(_keys_of(a, with_seams=True), _keys_of(b, with_seams=True))]
    assert len(plain) == len(seamed) and sum(plain) >= 3
    assert sum(seamed) < sum(plain) and all(p_ or not s for p_, s in zip(plain, seamed))


def test_the_log_names_a_node_over_the_budget_and_what_held_it():
    """A LOD of 3,000 triangles at a target of 2,000, held by 2,900 seam vertices: named with them."""
    from hlod_core.bake.meta import lod_notes

    lod = simplify.NodeLod(positions=np.zeros((3, 3), np.float32), faces=np.zeros((3000, 3), np.int32), normals=None,
                           decimated=True, input_tris=12000, locked_vertices=2900, open_boundaries_freed=True,
                           pieces=3, pruned_pieces=1)
    assert lod_notes(7, lod, error=1.0, target_tris=2000) == [
        "node 7: decimation stopped at 3000 triangles, over 1.25 x the target 2000: its 2900 seam vertices "
        "(shared with neighbouring cells) stay in place, and 2 separate pieces remain"]
    within = simplify.NodeLod(positions=np.zeros((3, 3), np.float32), faces=np.zeros((2500, 3), np.int32),
                              normals=None, decimated=True, input_tris=12000)
    assert lod_notes(7, within, error=1.0, target_tris=2000) == []


def test_rims_stay_where_freeing_them_cannot_reach_the_budget():
    """A flat open ground (3,200 triangles) beside a ball whose every vertex is a cell seam (held in
    place): the ball alone keeps the LOD far over 1.25 x target_tris whatever the rims do. Freeing
    the ground's rim would buy no budget, only error (the collapse with free rims flattened such a
    ground to nothing: the root of a textured scene lost its ground that way), so the rims stay:
    every vertex of the ground's rim is in the LOD."""
    ground = procedural.grid_patch([-4.0, -4.0, 0.0], [8.0, 0.0, 0.0], [0.0, 8.0, 0.0], nu=40, nv=40)
    ball = procedural.uv_sphere([0.0, 0.0, 2.0], 1.0, segments=32, rings=24)
    children = [(np.asarray(p, np.float32), np.asarray(f)) for p, f in (ground, ball)]
    seams = np.unique(children[1][0], axis=0)
    target = 200
    settings = meshlab.DecimationSettings(target_tris=target)
    lod = simplify.decimate_node(children, settings, with_normals=False, seams=seams)
    assert lod.faces.shape[0] > 2 * OVER_BUDGET_FACTOR * target  # held by the ball's seams
    assert not lod.open_boundaries_freed and lod.pruned_pieces == 0
    p = children[0][0]
    rim = (np.abs(p[:, 0]) == 4.0) | (np.abs(p[:, 1]) == 4.0)
    assert rim.sum() == 160 and _keys(p[rim]) <= _keys(lod.positions)  # the ground's rim, every vertex
