"""Octree partition on tiny literal inputs with exact expected layouts."""
import numpy as np

from hlod_core.bake.run import cache_keys
from hlod_core.bake.space import octree_passes
from hlod_core.bake.space.octree import RootCube, build_octree, build_octree_counted, tight_cube


def _corner_centroids():
    # One centroid in each octant of the cube [-1, 1]^3: octant o has bit a set on the + side of axis a.
    return np.array([[(1 if (o >> a) & 1 else -1) for a in range(3)] for o in range(8)], float)


def test_eight_octants_give_eight_contiguous_leaves():
    layout = build_octree(_corner_centroids(), target_tris=1, max_depth=5)
    assert layout.node_count == 9
    assert layout.child_offset[0] == 1 and layout.child_count[0] == 8
    assert np.all(layout.parent[1:] == 0) and np.all(layout.depth[1:] == 1)
    # octants come out in order 0..7, each leaf holds exactly its triangle
    assert layout.tri_order.tolist() == list(range(8))
    assert layout.tri_begin.tolist() == [0] + list(range(8))
    assert layout.tri_end.tolist() == [8] + list(range(1, 9))


def test_cell_shrinks_instead_of_making_single_child_nodes():
    # Three centroids crowd one corner, one sits far away; then the crowd splits again deep down.
    c = np.array([[0, 0, 0], [0.001, 0, 0], [0, 0.001, 0], [100, 100, 100]], float)
    layout = build_octree(c, target_tris=1, max_depth=10)
    inner = layout.child_count > 0
    assert np.all(layout.child_count[inner] >= 2), "a node with one child would repeat its child's LOD"
    assert int((layout.child_count == 0).sum()) == 4


def test_coincident_centroids_make_one_unsplittable_leaf():
    c = np.zeros((50, 3))
    layout = build_octree(c, target_tris=10, max_depth=12)
    assert layout.node_count == 1 and layout.tri_end[0] == 50


def test_max_depth_zero_is_a_single_leaf():
    layout = build_octree(np.random.default_rng(0).random((100, 3)), target_tris=10, max_depth=0)
    assert layout.node_count == 1


def test_uncounted_triangles_do_not_force_a_split():
    c = np.random.default_rng(1).random((30, 3))
    counted = np.zeros(30, bool)
    counted[:10] = True
    assert build_octree(c, target_tris=10, max_depth=8, counted=counted).node_count == 1
    assert build_octree(c, target_tris=10, max_depth=8).node_count > 1


def test_subtree_ranges_are_contiguous_and_breadth_first_children_contiguous():
    rng = np.random.default_rng(2)
    c = np.concatenate([rng.normal(size=(3000, 3)), rng.normal(size=(500, 3)) * 0.01 + 5])
    layout = build_octree(c, target_tris=100, max_depth=12)
    assert np.array_equal(np.sort(layout.tri_order), np.arange(c.shape[0]))
    for node in np.flatnonzero(layout.child_count):
        kids = np.arange(layout.child_offset[node], layout.child_offset[node] + layout.child_count[node])
        assert np.all(layout.parent[kids] == node)
        assert layout.tri_begin[kids[0]] == layout.tri_begin[node]
        assert layout.tri_end[kids[-1]] == layout.tri_end[node]
        assert np.all(layout.tri_end[kids[:-1]] == layout.tri_begin[kids[1:]])
    leaves = layout.child_count == 0
    assert np.all(layout.tri_end[leaves] - layout.tri_begin[leaves] <= 100)


# --- stable cells -------------------------------------------------------------------------------------

def _subtrees_of(layout, owner: np.ndarray, which: int):
    """{(cell centre, half, level): sorted triangle ids} of the nodes holding only triangles of `which`."""
    out = {}
    for node in range(layout.node_count):
        tris = layout.tri_order[layout.tri_begin[node]:layout.tri_end[node]]
        if np.all(owner[tris] == which):
            out[(tuple(layout.cell_center[node]), float(layout.cell_half[node]), int(layout.cell_level[node]))] = \
                np.sort(tris)
    return out


def _keys_of(layout, centroids, *, owner, which):
    """The bake cache's keys of the nodes holding only `which`'s triangles, with each leaf's 'LOD'
    its centroids (what node_keys hashes for a leaf is the leaf's own data)."""
    lods = [None] * layout.node_count
    for leaf in np.flatnonzero(layout.child_count == 0):
        tris = layout.tri_order[layout.tri_begin[leaf]:layout.tri_end[leaf]]
        lods[leaf] = (centroids[tris].astype(np.float32), np.arange(tris.size, dtype=np.int32), None, None)
    keys = cache_keys.node_keys(layout, lods, origin=np.zeros(3), context=b"context")
    return {keys[n] for n in range(layout.node_count)
            if np.all(owner[layout.tri_order[layout.tri_begin[n]:layout.tri_end[n]]] == which)}


def test_moving_an_object_leaves_another_objects_cells_and_keys_unchanged():
    """Object A (a cloud near one corner) and object B (near the other); B moves by 0.3 inside a
    box C marks (the scene's extent is unchanged, so is the root cell). Every node holding only A's
    triangles keeps its cell, its triangles and its cache key."""
    rng = np.random.default_rng(5)
    a = rng.normal(size=(3000, 3)) * 2 + [5, 5, 5]
    b = rng.normal(size=(3000, 3)) * 2 + [25, 20, 6]
    owner = np.repeat([0, 1], 3000)
    before = np.concatenate([a, b])
    after = np.concatenate([a, b + [0.3, -0.2, 0.1]])
    corners = np.array([[-5.0, -5.0, -5.0], [40.0, 40.0, 40.0]])  # C: two points spanning the scene
    owner = np.concatenate([owner, [2, 2]])
    before, after = np.concatenate([before, corners]), np.concatenate([after, corners])
    for box in (before, after):  # the same root cell before and after the move
        cube = tight_cube(box.min(0), box.max(0))
        assert cube.corner.tolist() == [-5.0] * 3 and cube.side == 45.0
    old = build_octree(before, target_tris=50, max_depth=12)
    new = build_octree(after, target_tris=50, max_depth=12)
    old_a, new_a = _subtrees_of(old, owner, 0), _subtrees_of(new, owner, 0)
    assert len(old_a) > 50 and old_a.keys() == new_a.keys()
    assert all(np.array_equal(old_a[cell], new_a[cell]) for cell in old_a)
    assert _keys_of(old, before, owner=owner, which=0) == _keys_of(new, after, owner=owner, which=0)
    # and B's did change: the keys are not blind
    assert _keys_of(old, before, owner=owner, which=1) != _keys_of(new, after, owner=owner, which=1)


def _cells_by_key(layout) -> dict[tuple, np.ndarray]:
    """{(cell centre, half side): the node's sorted triangle ids} (levels left out: they shift when
    the root cube grows)."""
    return {(tuple(layout.cell_center[n]), float(layout.cell_half[n])):
            np.sort(layout.tri_order[layout.tri_begin[n]:layout.tri_end[n]]) for n in range(layout.node_count)}


def test_a_grown_root_keeps_every_cell_one_level_down_bit_for_bit():
    """A cloud's octree, then the same cloud and a few centroids beyond its cube's +x and -y faces:
    the root cube doubles (root_cube.RootCube.grown_to) and every cell of the first octree is a cell
    of the second with the same float centre and half side and the same triangles, one level down.
    Without the growth chain the old cube's octant would be computed from the grown cube's centre,
    which rounds: its centre would differ in the last bits and no cell would be shared."""
    rng = np.random.default_rng(3)
    cloud = rng.random((20000, 3)) * [3.0, 2.0, 1.0] + [0.3, -5.1, 7.7]
    base = tight_cube(cloud.min(0), cloud.max(0))
    old = build_octree(cloud, target_tris=100, max_depth=12, root=base)
    assert np.allclose(base.corner, [0.3, -5.1, 7.7], atol=1e-3) and abs(base.side - 3.0) < 1e-3  # the box's low corner
    extra = np.array([[3.8, -6.0, 8.2]]) + rng.random((300, 3)) * 0.2  # past +x and -y
    both = np.concatenate([cloud, extra])
    grown = base.grown_to(both.min(0), both.max(0), most=2)
    assert grown.growths == (0b101,)  # toward +x, -y and (where nothing left it) +z
    new = build_octree(both, target_tris=100, max_depth=12, root=grown)
    old_cells, new_cells = _cells_by_key(old), _cells_by_key(new)
    assert old_cells.keys() <= new_cells.keys()
    touched = {cell for cell, tris in old_cells.items() if not np.array_equal(new_cells[cell], tris)}
    assert len(touched) <= 0.05 * len(old_cells)  # only the cells on the way to the new centroids changed
    shared = [n for n in range(new.node_count) if (tuple(new.cell_center[n]), float(new.cell_half[n])) in old_cells]
    assert np.all(new.cell_level[shared] >= 1)
    top = grown.top  # the same cube, its octants computed: on this cloud, not one cell in common
    plain = build_octree(both, target_tris=100, max_depth=12, root=RootCube(top.corner, top.side))
    assert not old_cells.keys() & _cells_by_key(plain).keys()
    # the old cloud alone in the grown root: the root shrinks into the base cube, the same octree
    undone = build_octree(cloud, target_tris=100, max_depth=12, root=grown)
    assert undone.node_count == old.node_count and np.array_equal(undone.tri_order, old.tri_order)
    assert np.array_equal(undone.cell_center[1:], old.cell_center[1:])
    assert np.array_equal(undone.cell_level[1:], old.cell_level[1:] + 1)


def test_a_root_grows_toward_the_side_the_centroids_leave_it_on():
    base = tight_cube(np.zeros(3), np.ones(3))
    assert base.grown_to(np.zeros(3), np.ones(3), most=2) is base  # inside: kept
    assert base.grown_to(np.array([-0.1, 0.0, 0.0]), np.ones(3), most=2).growths == (0b110,)
    grown = base.grown_to(np.array([-0.1, 0.0, 0.0]), np.array([1.2, 1.0, 1.0]), most=2)
    assert grown.growths == (0b110, 0b111)  # -x first, then +x: the cube is 4 sides wide
    assert base.grown_to(np.array([-5.0, 0.0, 0.0]), np.ones(3), most=2) is None  # beyond two doublings
    top = grown.top
    assert top.side == 4.0 and top.contains(np.array([-0.1, 0.0, 0.0]), np.array([1.2, 1.0, 1.0]))


def test_passes_over_chunks_of_one_cell_give_the_octree_from_counts(monkeypatch):
    """Each leaf's centroids in a row (as an object's triangles come) and chunks of 40 rows: most
    chunks lie in one cell, hundreds of cells deep down, and take its planes as scalars
    (octree_passes.ActiveTriangles.octants). The same layout as the octree from counts, and the
    triangles already in leaf order."""
    rng = np.random.default_rng(11)
    c = np.concatenate([rng.normal(size=(4000, 3)) * scale + offset for scale, offset in ((0.1, 0.0), (1.0, 5.0),
                                                                                         (3.0, -8.0))])
    c = c[build_octree(c, target_tris=12, max_depth=12).tri_order]
    root = tight_cube(c.min(axis=0), c.max(axis=0))
    monkeypatch.setattr(octree_passes, "CHUNK", 40)
    got = build_octree(c, target_tris=12, max_depth=12, root=root)
    want = build_octree_counted(lambda query: query.count(c, np.ones(c.shape[0], bool)), root=root,
                                tri_count=c.shape[0], counted_count=c.shape[0], target_tris=12, max_depth=12).layout
    assert got.node_count > 1000
    for name in ("parent", "child_offset", "child_count", "depth", "tri_begin", "tri_end", "cell_center",
                 "cell_half", "cell_level"):
        assert np.array_equal(getattr(got, name), getattr(want, name)), name
    assert np.array_equal(got.tri_order, np.arange(c.shape[0]))
