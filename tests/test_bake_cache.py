"""The bake cache: a re-bake takes the unchanged subtrees from it and writes the file a
bake from scratch writes; corrupt entries are ignored and rebuilt; settings and versions are in
the key. Real pymeshlab bakes of small meshes; decimations and measurements are counted by wrapping
the real functions (jobs = 1 runs them in this process)."""
from __future__ import annotations

import ast
import logging
import shutil
from pathlib import Path

import numpy as np
import pytest

import rebake_work
from helpers import file_bytes, load_model, model
from hlod_core.bake import checks, prepare
from hlod_core.bake.decimate import meshlab, simplify
from hlod_core.bake.measure import hausdorff
from hlod_core.bake.meta import VOLATILE_META
from hlod_core.bake.pipeline import bake
from hlod_core.bake.run import cache, cache_files, cache_keys, tasks
from hlod_core.bake.settings import BakeSettings
from hlod_core.bake.space.frame import Frame
from hlod_core.bake.space.octree import build_octree
from hlod_core.core.errors import BakeCancelled, InputError
from hlod_core.io import hlod_file, meshes
from hlod_core.model.appearance import AttributeLayout
from processes import hlod, last_json, one_line_error
from rebuilt_nodes import Counted, dfs_ranges, inner_count, subtree_signatures
from sample_meshes import SPHERE_TARGET_TRIS, herd, textured_sphere

CORE = Path(cache.__file__).resolve().parents[2]

COW = BakeSettings(target_tris=300)
HERD = BakeSettings(target_tris=600)


def _assert_same_file(a, b, tmp_path):
    assert set(VOLATILE_META) >= {"bake_seconds", "phase_seconds", "cache", "frame_source"}
    assert file_bytes(a, tmp_path / "a.hlod") == file_bytes(b, tmp_path / "b.hlod")


#: meta["cache"]'s entries about the folder rather than the nodes (cache.BakeCache.prune).
_FOLDER_STATS = ("budget_mb", "size_mb", "evicted_entries")


def _nodes_stats(meta_cache: dict) -> dict:
    """meta["cache"] without the folder's size entries, which are checked on their own."""
    assert meta_cache["budget_mb"] == cache.DEFAULT_BUDGET_MB and meta_cache["size_mb"] > 0
    return {k: v for k, v in meta_cache.items() if k not in _FOLDER_STATS}


def _entries(folder) -> set[str]:
    return {p.name for p in folder.glob(f"*{cache.ENTRY_SUFFIX}")}


def _results(folder) -> set[str]:
    return {p.name for p in folder.glob(f"*{cache.RESULT_SUFFIX}")}


def _remove_results(folder) -> None:
    for name in _results(folder):
        (folder / name).unlink()


# --- the same file, cold or warm ------------------------------------------------------------------

@pytest.mark.parametrize("which, jobs", [("cow", 1), ("textured sphere", 1), ("textured sphere", 2)])
def test_warm_and_cold_bakes_write_the_file_a_bake_from_scratch_writes(which, jobs, tmp_path, monkeypatch):
    mesh, settings = (load_model("cow"), COW) if which == "cow" else \
        (textured_sphere(), BakeSettings(target_tris=SPHERE_TARGET_TRIS, proxy_materials=False))
    settings = BakeSettings(**{**settings.__dict__, "jobs": jobs})
    scratch = bake(mesh, settings)
    assert "cache" not in scratch.meta and inner_count(scratch) >= 3
    folder = tmp_path / "cache"
    cold = bake(mesh, settings, cache_dir=folder)
    assert _nodes_stats(cold.meta["cache"]) == {"nodes": inner_count(cold), "reused_nodes": 0,
                                                "rebuilt_nodes": inner_count(cold), "reused_tris": 0,
                                                "rejected_entries": 0, "reused_result": False}
    assert cold.meta["cache"]["evicted_entries"] == 0
    assert len(_entries(folder)) == inner_count(cold) and len(_results(folder)) == 1
    assert (folder / "CACHEDIR.TAG").is_file()
    counted = Counted(monkeypatch)
    warm = bake(mesh, settings, cache_dir=folder)  # the input is unchanged: the whole result
    _remove_results(folder)
    from_nodes = bake(mesh, settings, cache_dir=folder)  # every inner node from its own entry
    inner = ~warm.is_leaf
    everything = {"nodes": int(inner.sum()), "reused_nodes": int(inner.sum()), "rebuilt_nodes": 0,
                  "reused_tris": int(warm.tri_count[inner].sum()), "rejected_entries": 0}
    assert _nodes_stats(warm.meta["cache"]) == {**everything, "reused_result": True}
    assert _nodes_stats(from_nodes.meta["cache"]) == {**everything, "reused_result": False}
    if jobs == 1:
        assert counted.decimations == 0 and counted.measured == []
    for other in (cold, warm, from_nodes):
        _assert_same_file(scratch, other, tmp_path)
    assert checks.check(from_nodes)["checks"] == {"leaf_tris_equal_input": True, "nested_bounds": True,
                                                  "monotone_error": True, "leaf_budget": True}
    if which != "cow":
        assert warm.uvs is not None and np.array_equal(warm.uvs, scratch.uvs)
        assert warm.materials == scratch.materials and from_nodes.materials == scratch.materials


# --- an edit rebuilds what it touches -------------------------------------------------------------

def _cells(mesh):
    """The octree the bake builds for `mesh` at HERD's settings (its cells, origin-relative)."""
    prepared = prepare.prepare(mesh)
    return build_octree(prepared.centroids, target_tris=HERD.target_tris, max_depth=HERD.max_depth,
                        counted=prepared.counted, root=prepared.root_cell)


def test_moving_one_object_rebuilds_only_the_cells_it_overlaps_and_their_ancestors(tmp_path, monkeypatch):
    """Nine cows; the middle one moves 1.5 units. The re-bake decimates and measures exactly the
    inner nodes whose subtree is not one of the first bake's (signatures from the files), every one
    of them overlaps the cow's old or new box, and the result is the file a bake from scratch of
    the moved herd writes: the origin (the centre of the input's box) and every cell the edit does
    not overlap stay where they were."""
    cows, mover = herd()
    moved, _ = herd(moved_by=(1.5, 0.0, 0.0))
    folder = tmp_path / "cache"
    first = bake(cows, HERD, cache_dir=folder)
    counted = Counted(monkeypatch)
    again = bake(moved, HERD, cache_dir=folder)
    monkeypatch.undo()
    scratch = bake(moved, HERD)
    _assert_same_file(scratch, again, tmp_path)

    old = set(subtree_signatures(first))
    new_sig = subtree_signatures(again)
    changed = {node for node in np.flatnonzero(~again.is_leaf) if new_sig[node] not in old}
    measured = {dfs_ranges(again)[r] for r in counted.measured}
    assert measured == changed and counted.decimations == len(changed) == again.meta["cache"]["rebuilt_nodes"]
    assert again.meta["cache"]["reused_nodes"] == inner_count(again) - len(changed)
    assert 0 < len(changed) <= inner_count(again) // 3, (len(changed), inner_count(again))
    # the edit touches only the cells it overlaps: every rebuilt node's cell meets the cow's old or new box
    assert np.array_equal(first.origin, again.origin)
    cells = _cells(moved)
    assert cells.node_count == again.node_count and np.array_equal(cells.child_count, again.child_count)
    cow_boxes = [(p.min(axis=0), p.max(axis=0)) for p in
                 (cows.positions[cows.faces[mover].ravel()], moved.positions[moved.faces[mover].ravel()])]
    lo_cell = cells.cell_center - cells.cell_half[:, None] + again.origin
    hi_cell = cells.cell_center + cells.cell_half[:, None] + again.origin
    for node in changed:
        assert any(np.all(lo_cell[node] <= hi) and np.all(hi_cell[node] >= lo) for lo, hi in cow_boxes), node
    # most leaves (the other cows') are stored bit for bit as before, relative to the same origin
    kept = set(new_sig) & {s for s, leaf in zip(subtree_signatures(first), first.is_leaf) if leaf}
    assert len(kept) >= first.is_leaf.sum() // 2


# --- keys -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("change", ["quality_threshold", "preserve_normals", "boundary_weight", "target_tris",
                                    "format version", "cache version"])
def test_changed_settings_or_versions_miss(change, tmp_path, monkeypatch):
    cow = load_model("cow")
    folder = tmp_path / "cache"
    first = bake(cow, COW, cache_dir=folder)
    settings = COW
    if change == "format version":
        monkeypatch.setattr(hlod_file, "FORMAT_VERSION", hlod_file.FORMAT_VERSION + 1)
    elif change == "cache version":
        monkeypatch.setattr(cache_files, "CACHE_VERSION", cache_files.CACHE_VERSION + 1)
    else:
        value = {"quality_threshold": 0.5, "preserve_normals": True, "boundary_weight": 2.0, "target_tris": 299}[change]
        settings = BakeSettings(**{**COW.__dict__, change: value})
    hlod = bake(cow, settings, cache_dir=folder)
    # a miss, not a rejection: the old entries sit under other keys (and stay, within the budget)
    assert hlod.meta["cache"]["reused_nodes"] == 0 and hlod.meta["cache"]["rebuilt_nodes"] == inner_count(hlod)
    assert hlod.meta["cache"]["rejected_entries"] == 0
    assert len(_entries(folder)) == inner_count(first) + inner_count(hlod)


def test_jobs_and_an_unreached_max_depth_reuse_everything(tmp_path):
    """Neither changes a LOD or an error: jobs never does, max_depth only through the subtree's shape,
    which the key holds (here the tree stops above both depths)."""
    cow = load_model("cow")
    folder = tmp_path / "cache"
    first = bake(cow, COW, cache_dir=folder)
    assert int(first.depth.max()) < 10
    jobs = bake(cow, BakeSettings(**{**COW.__dict__, "jobs": 2}), cache_dir=folder)
    assert jobs.meta["cache"]["reused_result"]  # jobs is not in the input's key
    depth = bake(cow, BakeSettings(**{**COW.__dict__, "max_depth": 10}), cache_dir=folder)
    assert not depth.meta["cache"]["reused_result"]  # max_depth is, but no node's key has it
    assert depth.meta["cache"]["reused_nodes"] == inner_count(depth) == inner_count(first)


# --- corrupt entries ------------------------------------------------------------------------------

def _corrupt(folder) -> dict[str, str]:
    """Spoil five entries in five ways; returns {entry name: how}."""
    names = sorted(_entries(folder))
    assert len(names) >= 6
    how = {}
    path = folder / names[0]
    path.write_bytes(path.read_bytes()[:-7])
    how[names[0]] = "truncated"
    path = folder / names[1]
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x40
    path.write_bytes(bytes(data))
    how[names[1]] = "a byte flipped"
    key = bytes.fromhex(names[2].removesuffix(cache.ENTRY_SUFFIX))
    faces = np.array([[0, 1], [1, 2]], np.int32)  # (m,2): a well-formed entry of the wrong shape
    bad = simplify.NodeLod(positions=np.zeros((3, 3), np.float32), faces=faces, normals=None, decimated=True,
                           input_tris=5)
    (folder / names[2]).write_bytes(cache_files.node_entry_bytes(key, bad, 0.5))
    how[names[2]] = "wrong-shaped faces"
    key = bytes.fromhex(names[3].removesuffix(cache.ENTRY_SUFFIX))
    bad = simplify.NodeLod(positions=np.zeros((3, 3), np.float32), faces=np.array([[0, 1, 7]], np.int32),
                           normals=None, decimated=True, input_tris=5)
    (folder / names[3]).write_bytes(cache_files.node_entry_bytes(key, bad, 0.5))
    how[names[3]] = "a face outside the LOD"
    shutil.copyfile(folder / names[5], folder / names[4])
    how[names[4]] = "another key's entry"
    (result,) = _results(folder)
    data = bytearray((folder / result).read_bytes())
    data[-100] ^= 0x01
    (folder / result).write_bytes(bytes(data))
    how[result] = "the result entry, a byte flipped"
    return how


@pytest.mark.parametrize("jobs", [1, 2])
def test_corrupt_entries_are_ignored_logged_once_and_rebuilt(jobs, tmp_path, caplog):
    cow = load_model("cow")
    settings = BakeSettings(**{**COW.__dict__, "jobs": jobs})
    scratch = bake(cow, settings)
    folder = tmp_path / "cache"
    bake(cow, settings, cache_dir=folder)
    spoiled = _corrupt(folder)
    with caplog.at_level(logging.WARNING, logger="hlod_core.bake.run.cache"):
        warm = bake(cow, settings, cache_dir=folder)
    assert warm.meta["cache"]["rejected_entries"] == len(spoiled) == warm.meta["cache"]["rebuilt_nodes"] + 1
    assert not warm.meta["cache"]["reused_result"]
    warnings = [r for r in caplog.records if r.name == "hlod_core.bake.run.cache"]
    assert len(warnings) == 1 and f"{len(spoiled)} entries ignored and rebuilt" in warnings[0].getMessage()
    _assert_same_file(scratch, warm, tmp_path)
    _remove_results(folder)
    again = bake(cow, settings, cache_dir=folder)  # the rebuilt entries were written back
    assert again.meta["cache"]["reused_nodes"] == inner_count(again) and again.meta["cache"]["rejected_entries"] == 0


def _cache(folder) -> cache.BakeCache:
    return cache.BakeCache(folder, decimation=meshlab.DecimationSettings(), with_normals=False,
                                row_layout=AttributeLayout(False, False, False))


@pytest.mark.parametrize("spoil, why", [
    (lambda d: d[:10], "truncated"),
    (lambda d: b"NOTANODE" + d[8:], "bad magic"),
    (lambda d: d[:8] + (cache_files.CACHE_VERSION + 1).to_bytes(4, "little") + d[12:], "cache format"),
    (lambda d: d + b"\0", "payload of"),
    (lambda d: d[:-1] + bytes([d[-1] ^ 1]), "digest mismatch"),
])
def test_a_spoiled_entry_is_a_miss_with_its_reason(spoil, why, tmp_path):
    key = bytes(range(32))
    lod = simplify.NodeLod(positions=np.eye(3, dtype=np.float32), faces=np.array([[0, 1, 2]], np.int32), normals=None,
                           decimated=False, input_tris=1)
    folder = _cache(tmp_path)
    folder.store({key: (lod, 0.25)})
    got, error = _cache(tmp_path).load(key)
    assert np.array_equal(got.positions, lod.positions) and np.array_equal(got.faces, lod.faces) and error == 0.25
    folder.path(key).write_bytes(spoil(folder.path(key).read_bytes()))
    spoilt = _cache(tmp_path)
    assert spoilt.load(key) is None and len(spoilt.rejected) == 1 and why in spoilt.rejected[0][1]
    assert spoilt.reused_nodes == 0


# --- the folder -----------------------------------------------------------------------------------

def test_two_bakes_sharing_a_folder_keep_each_others_entries_within_the_budget(tmp_path):
    """A bake of another mesh in the same folder leaves the first mesh's entries there (the budget
    holds both): baking the first again takes its whole result, in the frame it was baked in, and
    is still the file from scratch. The second mesh fits the first one's frame (both are about a
    unit across, at the origin) and is baked in it: the file from scratch in that frame."""
    cow, spot = load_model("cow"), load_model("spot")
    folder = tmp_path / "shared"
    cow_first = bake(cow, COW, cache_dir=folder)
    assert len(_entries(folder)) == inner_count(cow_first) and len(_results(folder)) == 1
    spot_first = bake(spot, COW, cache_dir=folder)
    assert len(_entries(folder)) == inner_count(cow_first) + inner_count(spot_first) and len(_results(folder)) == 2
    assert spot_first.meta["cache"]["reused_nodes"] == 0 and spot_first.meta["cache"]["evicted_entries"] == 0
    cow_again = bake(cow, COW, cache_dir=folder)
    assert cow_again.meta["cache"]["reused_result"]
    assert cow_again.meta["frame_source"]["reason"] == "the input is unchanged: its whole result in an earlier " \
                                                      "cache frame"
    _assert_same_file(cow_first, cow_again, tmp_path)
    assert spot_first.meta["frame"]["origin"] == cow_first.meta["frame"]["origin"]  # the cow's lattice
    cow_frame = Frame.from_meta(cow_first.meta["frame"], where="cow")
    _assert_same_file(spot_first, bake(spot, COW, frame_from=cow_frame), tmp_path)


def _translation(x: float) -> np.ndarray:
    m = np.eye(4)
    m[0, 3] = x
    return m


def _entry_files(folder) -> dict[str, int]:
    """{entry file name: modification time (ns)} of the node and result entries."""
    return {p.name: p.stat().st_mtime_ns for p in folder.iterdir() if p.suffix in (cache.ENTRY_SUFFIX,
                                                                                   cache.RESULT_SUFFIX)}


def test_the_budget_evicts_the_least_recently_used_entries_never_the_bakes_own(tmp_path):
    """Three meshes (far apart: each bakes in its own frame) baked into one folder under a budget
    that holds about two bakes: the third bake evicts the first bake's entries, oldest first, and
    keeps every entry it used; a budget of 0 keeps only the last bake's. The first mesh baked again
    then starts cold, and is still the file from scratch."""
    folder = tmp_path / "cache"
    meshes_ = {name: meshes.transform_mesh(load_model(name), _translation(100.0 * i), name=name)
               for i, name in enumerate(("cow", "spot", "teapot"))}
    sizes, files = {}, {}
    for name, mesh in meshes_.items():  # measure each bake's entries alone
        alone = tmp_path / f"alone-{name}"
        bake(mesh, COW, cache_dir=alone)
        files[name] = set(_entry_files(alone))
        sizes[name] = sum((alone / f).stat().st_size for f in files[name])
    budget_mb = (sizes["spot"] + sizes["teapot"] + 0.5 * sizes["cow"]) / 2**20
    for name in ("cow", "spot"):
        bake(meshes_[name], COW, cache_dir=folder, cache_budget_mb=budget_mb)
    before = _entry_files(folder)
    assert set(before) == files["cow"] | files["spot"]
    third = bake(meshes_["teapot"], COW, cache_dir=folder, cache_budget_mb=budget_mb)
    after = _entry_files(folder)
    evicted = set(before) - set(after)
    assert files["teapot"] <= set(after) and files["spot"] <= set(after)  # the bake's own, and the newer
    assert evicted and evicted <= files["cow"] and third.meta["cache"]["evicted_entries"] == len(evicted)
    # oldest first: every evicted cow entry is at least as old as every cow entry kept
    kept_cow = files["cow"] & set(after)
    assert all(before[e] <= before[k] for e in evicted for k in kept_cow)
    assert third.meta["cache"]["size_mb"] <= budget_mb and third.meta["cache"]["budget_mb"] == budget_mb
    # a budget of 0 keeps only the entries the bake used
    last = bake(meshes_["spot"], COW, cache_dir=folder, cache_budget_mb=0)
    assert last.meta["cache"]["reused_result"] and set(_entry_files(folder)) == set(before) & files["spot"]
    cold = bake(meshes_["cow"], COW, cache_dir=folder, cache_budget_mb=0)
    assert cold.meta["cache"]["reused_nodes"] == 0 and set(_entry_files(folder)) == files["cow"]
    _assert_same_file(bake(meshes_["cow"], COW), cold, tmp_path)


def test_an_entry_read_again_is_kept_over_one_written_later_and_not_read(tmp_path):
    """Least recently *used*, not least recently written: cow baked, then spot, then the cow again
    (its whole result read back, which touches the result and every node entry it used), then the
    teapot under a budget that holds the cow's and the teapot's entries but not the spot's too.
    The spot's entries go, all of them, and the cow's stay, all of them; first in, first out would
    have evicted the cow's, written first."""
    folder = tmp_path / "cache"
    meshes_ = {name: meshes.transform_mesh(load_model(name), _translation(100.0 * i), name=name)
               for i, name in enumerate(("cow", "spot", "teapot"))}
    bake(meshes_["cow"], COW, cache_dir=folder)
    files = {"cow": set(_entry_files(folder))}
    bake(meshes_["spot"], COW, cache_dir=folder)
    again = bake(meshes_["cow"], COW, cache_dir=folder)
    assert again.meta["cache"]["reused_result"]
    files["spot"] = set(_entry_files(folder)) - files["cow"]
    alone = tmp_path / "alone"
    bake(meshes_["teapot"], COW, cache_dir=alone)
    files["teapot"] = set(_entry_files(alone))

    def size(name: str) -> int:  # the bytes of one bake's entries, as written into the shared folder
        return sum((alone if name == "teapot" else folder).joinpath(f).stat().st_size for f in files[name])

    assert files["cow"] and files["spot"] and not files["cow"] & files["spot"]
    others = sum(p.stat().st_size for p in folder.iterdir() if p.name not in files["cow"] | files["spot"])
    smallest_spot = min((folder / f).stat().st_size for f in files["spot"])
    # room for the cow, the teapot and the folder's other files (frame.json grows by one frame:
    # far less than half an entry), and for no spot entry besides
    budget_mb = (size("cow") + size("teapot") + others + smallest_spot // 2) / 2**20
    third = bake(meshes_["teapot"], COW, cache_dir=folder, cache_budget_mb=budget_mb)
    after = set(_entry_files(folder))
    assert files["cow"] <= after, f"the cow's entries, read last, were evicted: {sorted(files['cow'] - after)}"
    assert not files["spot"] & after, f"the spot's entries, not read since written, were kept: " \
                                      f"{sorted(files['spot'] & after)}"
    assert files["teapot"] <= after and third.meta["cache"]["evicted_entries"] == len(files["spot"])


def test_a_budget_smaller_than_the_bake_keeps_the_bakes_entries(tmp_path):
    cow = load_model("cow")
    folder = tmp_path / "cache"
    first = bake(cow, COW, cache_dir=folder, cache_budget_mb=0.001)
    assert first.meta["cache"]["size_mb"] > 0.001 and first.meta["cache"]["evicted_entries"] == 0
    assert len(_entries(folder)) == inner_count(first)
    assert bake(cow, COW, cache_dir=folder, cache_budget_mb=0.001).meta["cache"]["reused_result"]


def test_a_removed_cache_folder_is_a_cold_bake(tmp_path):
    cow = load_model("cow")
    folder = tmp_path / "cache"
    first = bake(cow, COW, cache_dir=folder)
    shutil.rmtree(folder)
    again = bake(cow, COW, cache_dir=folder)
    assert again.meta["cache"]["reused_nodes"] == 0 and len(_entries(folder)) == inner_count(again)
    _assert_same_file(first, again, tmp_path)


def test_a_cancelled_bake_writes_no_cache(tmp_path):
    calls = []

    def cancel():
        return len(calls) >= 3

    with pytest.raises(BakeCancelled):
        bake(load_model("cow"), COW, cache_dir=tmp_path / "cache", cancel=cancel,
             progress=lambda done, total, phase: calls.append(phase))
    assert not (tmp_path / "cache").exists()


def test_a_file_where_the_cache_folder_goes_is_a_clear_error(tmp_path):
    (tmp_path / "cache").write_bytes(b"not a folder")
    with pytest.raises(InputError, match="cache: is a file; the bake cache is a folder"):
        bake(load_model("cow"), COW, cache_dir=tmp_path / "cache")


def test_command_line_keeps_the_cache_beside_the_output(tmp_path):
    out = tmp_path / "cow.hlod"
    first = last_json(hlod("-q", "bake", model("cow"), "-o", out, "--target-tris", "300"))
    folder = tmp_path / "cow.hlod.cache"
    assert first["cache"]["folder"] == str(folder) and first["cache"]["reused_nodes"] == 0
    assert len(_entries(folder)) == first["cache"]["nodes"] > 0
    second = last_json(hlod("-q", "bake", model("cow"), "-o", out, "--target-tris", "300"))
    assert second["cache"]["reused_nodes"] == second["cache"]["nodes"] == first["cache"]["nodes"]
    other = tmp_path / "elsewhere"
    third = last_json(hlod("-q", "bake", model("cow"), "-o", tmp_path / "b.hlod", "--target-tris",
                           "300", "--cache", other))
    assert third["cache"]["folder"] == str(other) and _entries(other) == _entries(folder)
    none = last_json(hlod("-q", "bake", model("cow"), "-o", tmp_path / "c.hlod", "--no-cache"))
    assert none["cache"] is None and not (tmp_path / "c.hlod.cache").exists()
    (tmp_path / "d.hlod.cache").write_bytes(b"x")
    line = one_line_error(hlod("bake", model("cow"), "-o", tmp_path / "d.hlod", check=False))
    assert f"{tmp_path / 'd.hlod.cache'}: is a file; the bake cache is a folder" in line


#: hlod_core modules the bake's code imports that compute nothing a LOD or an error depends on.
_NOT_RESULT_MODULES = {"core.errors", "core.signals", "core.jsonutil", "io.meshes", "io.hlod_file",
                       "bake.run.workers", "bake.run.dask_cluster",  # workers, dask_cluster: where tasks run
                       "bake.space.chunk_store",  # where the early phases' tasks run and how their rows are cut
                       "core.atomic",  # how files are written
                       "bake.run.lod_spill"}  # where LODs wait, bytes unchanged; never in a bake with a cache


def _core_imports(name: str, tree) -> set[str]:
    """The hlod_core modules (dotted, relative to hlod_core) that module `name` imports relatively."""
    package = name.split(".")[:-1]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level:
            base = package[:len(package) - (node.level - 1)]
            stem = base + (node.module.split(".") if node.module else [])
            for alias in node.names:
                full = ".".join(stem + [alias.name])
                out.add(full if (CORE / f"{full.replace('.', '/')}.py").is_file() else ".".join(stem))
    return out


def test_the_cache_key_reads_the_source_of_every_result_module(monkeypatch):
    """context_digest hashes each RESULT_MODULES file it finds (a module it cannot read counts by its
    name only): every path it reads is a file, so none is keyed by its name alone."""
    read, original = [], Path.read_bytes
    monkeypatch.setattr(Path, "read_bytes", lambda self: read.append(self) or original(self))
    cache_keys.context_digest(meshlab.DecimationSettings(), with_normals=False, row_layout=None)
    assert len(read) == len(cache_keys.RESULT_MODULES) and all(path.is_file() for path in read), read


def test_every_module_that_computes_lods_or_errors_keys_the_cache():
    """The cache key holds the source of RESULT_MODULES, so a change to any module that computes
    LODs or errors invalidates every entry (a stale subtree is never served). Every hlod_core module
    those modules import is one of them or names nothing a result depends on."""
    seen, todo = set(), list(cache_keys.RESULT_MODULES)
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        for module in _core_imports(name, ast.parse((CORE / f"{name.replace('.', '/')}.py").read_text())):
            assert module in cache_keys.RESULT_MODULES or module in _NOT_RESULT_MODULES, (name, module)
            todo.extend([module] if module in cache_keys.RESULT_MODULES else [])
    assert "bake.measure.hausdorff" in seen


def test_rebuilt_work_times_every_rebuilt_task_and_restores_the_bake(tmp_path):
    """rebake_work.rebuilt_work (benchmarks/rebake.py --work, the moved re-bake's lower bound): on the
    herd with a moved cow, every rebuilt node is decimated and measured once and timed, the phases
    before the tasks are counted, the result is still the scratch bake's file, and the bake's
    functions are restored."""
    cows, _ = herd()
    moved, _ = herd(moved_by=(1.5, 0.0, 0.0))
    folder = tmp_path / "cache"
    bake(cows, HERD, cache_dir=folder)
    decimate, measure = simplify.decimate_node, tasks.measure_exact
    work = rebake_work.rebuilt_work(moved, BakeSettings(**{**HERD.__dict__, "jobs": 2}), folder)
    assert simplify.decimate_node is decimate and tasks.measure_exact is measure
    assert 0 < work["rebuilt_nodes"] == work["decimations"] == work["measurements"]
    assert work["decimate_s"] > 0 and work["measure_s"] > 0
    assert 0 < work["before_tasks_s"] < work["seconds"]
    assert work["decimate_s"] + work["measure_s"] + work["before_tasks_s"] <= work["seconds"]
    again = bake(moved, HERD, cache_dir=folder)  # the whole result, as the timed re-bake left it
    assert again.meta["cache"]["reused_result"]
    _assert_same_file(bake(moved, HERD), again, tmp_path)
    bound = BakeSettings(**{**HERD.__dict__, "error": "bound"})  # its measure is another task function
    bake(cows, bound, cache_dir=tmp_path / "bound")
    to_children = hausdorff.measure_to_children
    with_bound = rebake_work.rebuilt_work(moved, bound, tmp_path / "bound")
    assert hausdorff.measure_to_children is to_children
    assert 0 < with_bound["rebuilt_nodes"] == with_bound["decimations"] == with_bound["measurements"]
