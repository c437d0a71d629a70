"""The bake's frame (hlod_core/bake/space/frame.py): a re-bake keeps the earlier bake's origin, lattice and
root cube while the edited input fits them, so an edit at the scene's edge keeps every cell and
stored position it does not touch; and a re-bake equals a bake from scratch given that frame.
Real bakes of a small yard: cows on a 3 x 3 grid, edited as an artist would at its edge."""
from __future__ import annotations

import json

import numpy as np
import pytest

from helpers import file_bytes
from hlod_core.bake import prepare
from hlod_core.bake.pipeline import bake
from hlod_core.bake.settings import BakeSettings
from hlod_core.bake.space import frame as frames
from hlod_core.bake.space.frame import Frame, Prior
from hlod_core.bake.space.octree import build_octree
from hlod_core.core.errors import InputError
from hlod_core.io import hlod_file, meshes
from processes import hlod, last_json, one_line_error
from rebuilt_nodes import Counted, dfs_ranges, inner_count, subtree_signatures
from sample_meshes import HERD_SPACING, herd_cow

YARD = BakeSettings(target_tris=600)
GRID = [np.array([HERD_SPACING * (k % 3), HERD_SPACING * (k // 3), 0.0]) for k in range(9)]
#: The yard's extent along x: two spacings and a cow's length (herd_cow is 10 units long).
EXTENT = 2 * HERD_SPACING + 10.0


def _yard(offsets, *, scale: float = 1.0, shift: float = 0.0) -> meshes.TriangleMesh:
    """A cow at each offset, the whole scaled by `scale` and moved by `shift` along every axis."""
    cow = herd_cow()
    parts = []
    for k, offset in enumerate(offsets):
        m = np.eye(4) * scale
        m[3, 3] = 1.0
        m[:3, 3] = scale * np.asarray(offset) + shift
        parts.append(meshes.transform_mesh(cow, m, name=f"cow{k}"))
    return meshes.merge(parts, name="yard")


def _edit(kind: str) -> tuple[list, set]:
    """The grid edited: (offsets, the changed offsets' indices in the original and the edited grid).
    move: the corner cow 0 by a tenth of the extent, outward; add: a cow beside the +x edge reaching
    a tenth of the extent past it; remove: the outermost corner cow 8."""
    if kind == "move":
        return [g - [0.1 * EXTENT, 0.0, 0.0] if k == 0 else g for k, g in enumerate(GRID)], {0}
    if kind == "add":
        return GRID + [np.array([2 * HERD_SPACING + 0.1 * EXTENT, HERD_SPACING / 2, 0.0])], {9}
    return GRID[:8], {8}


def _cow_box(offset, *, scale: float, shift: float) -> tuple[np.ndarray, np.ndarray]:
    p = herd_cow().positions * scale + scale * np.asarray(offset) + shift
    return p.min(axis=0), p.max(axis=0)


@pytest.mark.parametrize("kind, scale, shift", [("move", 1.0, 0.0), ("add", 1.0, 0.0), ("remove", 1.0, 0.0),
                                                ("move", 1.0, 1e6), ("move", 1e-6, 0.0)])
def test_an_edit_at_the_yards_edge_rebuilds_only_what_it_touches(kind, scale, shift, tmp_path, monkeypatch):
    """Before the frame, moving the corner cow reused nothing: the box moved, and with it the origin,
    the lattice and every cell. Now the re-bake keeps the first bake's frame (the root cube grown
    where the edit leaves it), decimates and measures exactly the inner nodes whose subtree is not
    one of the first bake's, each of them a cell the edited cow's old or new box meets, and writes the
    file a bake from scratch in that frame writes; undoing the edit takes the first file back from
    the cache. Also far from the origin (1e6) and at 1e-6 of the size."""
    original = _yard(GRID, scale=scale, shift=shift)
    offsets, changed_cows = _edit(kind)
    edited = _yard(offsets, scale=scale, shift=shift)
    folder = tmp_path / "cache"
    first = bake(original, YARD, cache_dir=folder)
    counted = Counted(monkeypatch)
    again = bake(edited, YARD, cache_dir=folder)
    monkeypatch.undo()
    assert again.meta["frame_source"]["from"] == "cache", again.meta["frame_source"]
    assert again.meta["frame"]["origin"] == first.meta["frame"]["origin"]
    assert again.meta["frame"]["unit_length"] == first.meta["frame"]["unit_length"]
    grew = kind != "remove"  # the box grew past the root cube: one doubling; a removal keeps it
    assert len(again.meta["frame"]["root_growths"]) == int(grew)

    old = set(subtree_signatures(first))
    new_sig = subtree_signatures(again)
    rebuilt = {node for node in np.flatnonzero(~again.is_leaf) if new_sig[node] not in old}
    assert {dfs_ranges(again)[r] for r in counted.measured} == rebuilt
    assert counted.decimations == len(rebuilt) == again.meta["cache"]["rebuilt_nodes"]
    assert 0 < len(rebuilt) <= inner_count(again) // 4, (len(rebuilt), inner_count(again))
    # every rebuilt node's cell meets the edited cow's box (old or new): what the edit touches
    prepared = prepare.prepare(edited, Prior(Frame.from_meta(first.meta["frame"], where="first"), "file"))
    cells = build_octree(prepared.centroids, target_tris=YARD.target_tris, max_depth=YARD.max_depth,
                         counted=prepared.counted, root=prepared.root_cell)
    assert np.array_equal(cells.child_count, again.child_count)
    boxes = [_cow_box(GRID[k] if k < len(GRID) else offsets[k], scale=scale, shift=shift) for k in changed_cows]
    boxes += [_cow_box(offsets[k], scale=scale, shift=shift) for k in changed_cows if k < len(offsets)]
    lo_cell = cells.cell_center - cells.cell_half[:, None] + again.origin
    hi_cell = cells.cell_center + cells.cell_half[:, None] + again.origin
    for node in rebuilt:
        assert any(np.all(lo_cell[node] <= hi) and np.all(hi_cell[node] >= lo) for lo, hi in boxes), node

    # the file a bake from scratch in the first bake's frame writes, byte for byte but timings
    scratch = bake(edited, YARD, frame_from=Frame.from_meta(first.meta["frame"], where="first"))
    assert scratch.meta["frame_source"]["from"] == "file"
    assert file_bytes(again, tmp_path / "a.hlod") == file_bytes(scratch, tmp_path / "b.hlod")
    # undo: the first bake's whole result, its frame, from the cache
    undone = bake(original, YARD, cache_dir=folder)
    assert undone.meta["cache"]["reused_result"] and undone.meta["cache"]["rebuilt_nodes"] == 0
    assert file_bytes(undone, tmp_path / "u.hlod") == file_bytes(first, tmp_path / "f.hlod")


def test_without_the_whole_result_an_undo_reuses_every_node(tmp_path):
    """The result entries removed: the undo re-bakes in the grown frame the edit left, where the
    root cube shrinks into the first one, and every inner node comes from the cache."""
    folder = tmp_path / "cache"
    bake(_yard(GRID), YARD, cache_dir=folder)
    bake(_yard(_edit("move")[0]), YARD, cache_dir=folder)
    for result in folder.glob("*.hlodr"):
        result.unlink()
    undone = bake(_yard(GRID), YARD, cache_dir=folder)
    assert undone.meta["frame_source"] == {"from": "cache", "reason": "the input fits the cache frame"}
    assert undone.meta["cache"]["reused_nodes"] == undone.meta["cache"]["nodes"] == inner_count(undone)


def test_an_input_that_leaves_the_frame_gets_its_own(tmp_path):
    folder = tmp_path / "cache"
    first = bake(_yard(GRID), YARD, cache_dir=folder)
    far = bake(_yard([g - [0.5 * EXTENT, 0.0, 0.0] if k == 0 else g for k, g in enumerate(GRID)]), YARD,
               cache_dir=folder)  # past the margin (a quarter of the unit on each side)
    assert far.meta["frame_source"]["from"] == "input" and "margin" in far.meta["frame_source"]["reason"]
    assert far.meta["frame"]["origin"] != first.meta["frame"]["origin"]
    small = bake(_yard(GRID[:1]), YARD, cache_dir=folder)  # one cow: under half the unit
    assert small.meta["frame_source"]["from"] == "input" and "under 0.5" in small.meta["frame_source"]["reason"]


def test_a_bake_from_scratch_records_the_inputs_own_frame():
    yard = _yard(GRID)
    hlod = bake(yard, YARD)
    used = yard.positions[np.unique(yard.faces)]
    frame = Frame.from_meta(hlod.meta["frame"], where="yard")
    assert np.array_equal(frame.origin, 0.5 * (used.min(axis=0) + used.max(axis=0)))
    assert np.array_equal(frame.origin, hlod.origin) and frame.root.growths == ()
    assert frame.unit_length == float(np.max(used.max(axis=0) - used.min(axis=0)))
    assert hlod.meta["frame_source"] == frames.FROM_SCRATCH.to_meta()
    again = Frame.from_meta(json.loads(json.dumps(hlod.meta["frame"])), where="json")
    assert again.to_meta() == frame.to_meta()  # JSON keeps every float64


@pytest.mark.parametrize("entry, why", [(None, "is missing"), ({"origin": [0, 0]}, "malformed"),
                                        ({"origin": [0, 0, 0], "unit_length": 0, "root_corner": [0, 0, 0],
                                          "root_side": 1, "root_growths": []}, "non-finite or empty"),
                                        ({"origin": [0, 0, 0], "unit_length": 1, "root_corner": [0, 0, 0],
                                          "root_side": 1, "root_growths": [9]}, "growth codes")])
def test_a_bad_frame_entry_is_a_clear_error(entry, why):
    with pytest.raises(InputError, match=f"old.hlod: the bake frame .*{why}"):
        Frame.from_meta(entry, where="old.hlod")


def test_command_line_frame_from_and_cache_budget(tmp_path):
    """--frame-from bakes from scratch in an earlier file's frame: the re-bake's file, byte for
    byte but timings; the JSON line says which frame and why, and the cache's budget."""
    original, moved = tmp_path / "yard.obj", tmp_path / "moved.obj"
    for path, mesh in ((original, _yard(GRID)), (moved, _yard(_edit("move")[0]))):
        _write_obj(path, mesh)
    out = tmp_path / "yard.hlod"
    first = last_json(hlod("-q", "bake", original, "-o", out, "--target-tris", "600", "--cache-budget", "64"))
    assert first["frame"] == frames.FROM_SCRATCH.to_meta() and first["cache"]["budget_mb"] == 64
    kept = tmp_path / "first.hlod"
    kept.write_bytes(out.read_bytes())
    again = last_json(hlod("-q", "bake", moved, "-o", out, "--target-tris", "600"))
    assert again["frame"]["from"] == "cache" and "doubles 1 time" in again["frame"]["reason"]
    assert 0 < again["cache"]["rebuilt_nodes"] <= again["cache"]["nodes"] // 4
    scratch = tmp_path / "scratch.hlod"
    line = last_json(hlod("-q", "bake", moved, "-o", scratch, "--target-tris", "600", "--no-cache",
                          "--frame-from", kept))
    assert line["frame"]["from"] == "file" and line["cache"] is None
    assert file_bytes(hlod_file.load(out), tmp_path / "a") == file_bytes(hlod_file.load(scratch), tmp_path / "b")
    error = one_line_error(hlod("bake", moved, "-o", tmp_path / "x.hlod", "--frame-from", original, check=False))
    assert str(original) in error
    error = one_line_error(hlod("bake", moved, "-o", tmp_path / "x.hlod", "--out-of-core", "--frame-from", kept,
                                check=False))
    assert "--frame-from: out-of-core bakes" in error


def _write_obj(path, mesh) -> None:
    with open(path, "w") as f:
        f.writelines(f"v {x!r} {y!r} {z!r}\n" for x, y, z in mesh.positions)
        f.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in mesh.faces)


def _with_stiff_triangles(yard: meshes.TriangleMesh, at: np.ndarray) -> meshes.TriangleMesh:
    """The yard and, near `at`, 40 zero-area triangles (three corners at one point), 40 slivers (three
    collinear corners) and 40 needles (one edge 1e-7 long)."""
    rng = np.random.default_rng(11)
    points = at + rng.random((40, 3))
    direction = rng.normal(size=(40, 3))
    zero = np.repeat(points, 3, axis=0)
    sliver = np.stack([points, points + direction, points + 2.5 * direction], axis=1).reshape(-1, 3)
    needle = np.stack([points, points + 1e-7 * direction, points + np.cross(direction, [0, 0, 1])], axis=1)
    stiff = np.concatenate([zero, sliver, needle.reshape(-1, 3)])
    faces = np.arange(stiff.shape[0]).reshape(-1, 3)
    return meshes.merge([yard, meshes.from_arrays(stiff, faces, name="stiff")], name="yard and stiff triangles")


def test_stiff_triangles_at_the_edge_keep_the_frames_promises(tmp_path):
    """Degenerate, sliver and needle triangles beside the corner cow that moves: the re-bake still
    equals the bake from scratch in the same frame, and the file passes the bake's checks."""
    from hlod_core.bake import checks

    corner = np.array([-6.0, -3.0, 0.0])
    folder = tmp_path / "cache"
    first = bake(_with_stiff_triangles(_yard(GRID), corner), YARD, cache_dir=folder)
    edited = _with_stiff_triangles(_yard(_edit("move")[0]), corner - [0.1 * EXTENT, 0.0, 0.0])
    again = bake(edited, YARD, cache_dir=folder)
    assert again.meta["frame_source"]["from"] == "cache" and again.meta["cache"]["reused_nodes"] > 0
    scratch = bake(edited, YARD, frame_from=Frame.from_meta(first.meta["frame"], where="first"))
    assert file_bytes(again, tmp_path / "a.hlod") == file_bytes(scratch, tmp_path / "b.hlod")
    assert all(checks.check(again)["checks"].values())


def test_a_scene_of_one_point_bakes_and_rebakes():
    """Every triangle at one point: the root cube has no side, cannot grow, and a point moved away
    gets a root cube of its own within the kept lattice."""
    one = meshes.from_arrays(np.zeros((6, 3)), np.arange(6).reshape(2, 3), name="point")
    first = bake(one, YARD)
    prior = Prior(Frame.from_meta(first.meta["frame"], where="first"), "file")
    assert bake(one, YARD, frame_from=prior.frame).meta["frame_source"]["reason"] == "the input fits the file frame"
    moved = meshes.from_arrays(np.full((6, 3), 0.1), np.arange(6).reshape(2, 3), name="point")
    again = bake(moved, YARD, frame_from=prior.frame)
    assert "a new root cube" in again.meta["frame_source"]["reason"] and again.node_count == 1


def test_the_cache_folder_keeps_the_last_frames_and_ignores_a_spoiled_list(tmp_path, caplog):
    """frame.json lists the last frames, the latest first (at most RECENT_FRAMES); a bake with
    --frame-from records its frame first and keeps the others; a spoiled frame.json is named in the
    log and the bake takes the input's frame."""
    from hlod_core.bake.run import cache

    folder = tmp_path / "cache"
    first = bake(_yard(GRID), YARD, cache_dir=folder)
    far = bake(_yard([g + [0.0, 0.0, 40.0] for g in GRID]), YARD, cache_dir=folder)  # another frame
    listed = json.loads((folder / cache.FRAME_FILE).read_text())["frames"]
    assert listed == [far.meta["frame"], first.meta["frame"]]
    again = bake(_yard(GRID), YARD, cache_dir=folder, frame_from=Frame.from_meta(first.meta["frame"], where="x"))
    assert again.meta["cache"]["reused_result"] and again.meta["frame_source"]["from"] == "file"
    assert json.loads((folder / cache.FRAME_FILE).read_text())["frames"] == [first.meta["frame"], far.meta["frame"]]
    (folder / cache.FRAME_FILE).write_text('{"frames": [{"origin": "x"}]}')
    with caplog.at_level("WARNING", logger="hlod_core.bake.run.cache"):
        fresh = bake(_yard(_edit("move")[0]), YARD, cache_dir=folder)
    assert fresh.meta["frame_source"] == frames.FROM_SCRATCH.to_meta()
    assert any("frame.json ignored" in r.getMessage() for r in caplog.records)
