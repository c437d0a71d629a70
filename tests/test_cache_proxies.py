"""The bake cache in bakes that make proxy materials (docs/how-it-works.md#re-bakes-and-the-cache-keys):
a node entry holds the node's proxy, a hit restores it renumbered into the new bake, and the keys
cover the texture settings and the source images' pixels. Real pymeshlab and xatlas bakes of a row
of textured spheres (sample_meshes.textured_sphere), jobs 1, the proxy tasks counted by wrapping
the real function."""
from __future__ import annotations

import contextlib
import resource
import shutil
import signal
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from helpers import file_bytes
from hlod_core.bake.appearance import proxy_task
from hlod_core.bake.appearance.proxy import ProxySettings
from hlod_core.bake.appearance.proxy_plan import ProxyPlan
from hlod_core.bake.decimate.meshlab import DecimationSettings
from hlod_core.bake.pipeline import bake
from hlod_core.bake.run import cache, cache_files, cache_keys, cache_proxies
from hlod_core.bake.run.cache_files import CorruptEntry
from hlod_core.bake.settings import BakeSettings
from hlod_core.bake.space.frame import Frame
from hlod_core.bake.space.octree import OctreeLayout
from hlod_core.core.errors import BakeCancelled
from hlod_core.core.png import png_bytes, png_pixels
from hlod_core.io import meshes
from hlod_core.io.texture_folder import EmbeddedTextures
from hlod_core.model.appearance import Material
from sample_meshes import SPHERE_TARGET_TRIS, textured_sphere

SETTINGS = BakeSettings(target_tris=2 * SPHERE_TARGET_TRIS, texture_cap=32, texture_floor=8)
#: The row's spheres, SPACING model units apart along x; the first one moves.
SPHERES, SPACING = 3, 3.0


def _image(seed: int) -> np.ndarray:
    """(16,16,4) uint8 RGBA noise, opaque."""
    out = np.random.default_rng(seed).integers(0, 256, (16, 16, 4), dtype=np.uint8)
    out[..., 3] = 255
    return out


def _row(moved_by: float = 0.0) -> tuple[meshes.TriangleMesh, dict]:
    """SPHERES textured spheres in a row, each half of each its own textured material (2 k and 2 k + 1),
    the first one moved by `moved_by` along y; and their images (material row -> image)."""
    parts = []
    for k in range(SPHERES):
        sphere = textured_sphere(colors=False)
        sphere = replace(sphere, materials=tuple(Material(f"{half} {k}", base_color=(1.0, 1.0, 1.0, 1.0),
                                                          texture=f"{half}{k}.png") for half in ("west", "east")))
        move = np.eye(4)
        move[:3, 3] = (SPACING * k, moved_by if k == 0 else 0.0, 0.0)
        parts.append(meshes.transform_mesh(sphere, move, name=f"sphere {k}"))
    return meshes.merge(parts, name="row"), {row: _image(row) for row in range(2 * SPHERES)}


class _Textures:
    """Texture folders that name the same final folder (the file's materials name it) and write
    their PNGs each into its own scratch folder (io.texture_folder.EmbeddedTextures' two paths)."""

    def __init__(self, root: Path, final: Path | None = None):
        self.root, self.final = root, final or root / "final"

    def __call__(self, name: str):
        return SimpleNamespace(scratch=self.root / name, final=self.final)

    def files(self, name: str) -> dict[str, bytes]:
        return {p.name: p.read_bytes() for p in sorted((self.root / name).iterdir())}


def _proxies_made(monkeypatch) -> list:
    """The nodes whose proxy task runs in this process's jobs 1 bakes (the list grows as they run)."""
    nodes, make = [], proxy_task.make_proxy

    def counting(*args, node, **kwargs):
        nodes.append(node)
        return make(*args, node=node, **kwargs)

    monkeypatch.setattr(proxy_task, "make_proxy", counting)
    return nodes


@pytest.fixture(scope="module")
def row(tmp_path_factory):
    """The row baked from scratch (no cache) and into a cache folder, each writing its own textures;
    a test copies the folder (`_warm`) before baking into it."""
    root = tmp_path_factory.mktemp("row")
    mesh, images = _row()
    textures = _Textures(root)
    scratch = bake(mesh, SETTINGS, images=images, textures=textures("scratch"))
    first = bake(mesh, SETTINGS, images=images, textures=textures("first"), cache_dir=root / "cache")
    return SimpleNamespace(mesh=mesh, images=images, textures=textures, scratch=scratch, first=first,
                           folder=root / "cache")


def _warm(row, tmp_path: Path) -> tuple[Path, _Textures]:
    """A copy of the row's cache folder, and texture folders in tmp_path naming the row's final one."""
    return Path(shutil.copytree(row.folder, tmp_path / "cache")), _Textures(tmp_path, row.textures.final)


def test_a_warm_cache_gives_the_file_and_textures_of_a_bake_from_scratch(row, tmp_path, monkeypatch):
    """Every inner node from its entry (the whole result removed: an unchanged input takes that)."""
    assert "cache" not in row.scratch.meta and len(row.scratch.meta["proxies"]["nodes"]) >= 3
    folder, textures = _warm(row, tmp_path)
    for result in folder.glob("*.hlodr"):
        result.unlink()
    made = _proxies_made(monkeypatch)
    warm = bake(row.mesh, SETTINGS, images=row.images, textures=textures("warm"), cache_dir=folder)
    inner = int((warm.child_count > 0).sum())
    assert row.first.meta["cache"]["reused_nodes"] == 0
    assert warm.meta["cache"]["reused_nodes"] == inner and warm.meta["cache"]["rejected_entries"] == 0
    assert made == [] and not warm.meta["cache"]["reused_result"]  # every node from its entry, no proxy baked
    expected = file_bytes(row.scratch, tmp_path / "scratch.hlod")
    assert file_bytes(row.first, tmp_path / "first.hlod") == expected == file_bytes(warm, tmp_path / "warm.hlod")
    assert row.textures.files("first") == row.textures.files("scratch") == textures.files("warm")
    # the budget counts the textures: they are inside the node entries, whose bytes the folder's size counts
    stored = [cache_files.unpack(p.read_bytes(), bytes.fromhex(p.stem), "node")[1].get(cache_proxies.PNG)
              for p in folder.glob("*.hlodc")]
    assert sorted(a.tobytes() for a in stored if a is not None) == sorted(textures.files("warm").values())
    assert warm.meta["cache"]["size_mb"] == round(sum(p.stat().st_size for p in folder.iterdir()) / 2**20, 3)


def test_a_moved_sphere_reuses_the_others_proxies_renumbered(row, tmp_path, monkeypatch):
    """The first sphere moves: the re-bake takes the other spheres' nodes and proxies from the cache
    under their new node numbers and writes the file (and textures) a bake from scratch of the moved
    row writes in the same frame."""
    moved, _ = _row(moved_by=0.6)
    folder, textures = _warm(row, tmp_path)
    made = _proxies_made(monkeypatch)
    again = bake(moved, SETTINGS, images=row.images, textures=textures("again"), cache_dir=folder)
    monkeypatch.undo()
    scratch = bake(moved, SETTINGS, images=row.images, textures=textures("scratch"),
                   frame_from=Frame.from_meta(again.meta["frame"], where="the re-bake"))
    assert file_bytes(again, tmp_path / "again.hlod") == file_bytes(scratch, tmp_path / "scratch.hlod")
    assert textures.files("again") == textures.files("scratch")
    stats, proxied = again.meta["cache"], again.meta["proxies"]["nodes"]
    assert stats["reused_nodes"] > 0 and stats["rebuilt_nodes"] > 0
    assert 0 < len(made) < len(proxied)  # some proxies came from the cache
    reused_proxies = sorted(set(proxied) - set(made))
    # the edit renumbered nodes: some reused proxy is under another node number than in the first bake
    first = row.textures.files("first")
    pixels = {node: png_pixels(first[f"proxy_{node}.png"]).tobytes() for node in row.first.meta["proxies"]["nodes"]}
    now = {node: png_pixels(textures.files("again")[f"proxy_{node}.png"]).tobytes() for node in reused_proxies}
    assert any(pixels.get(node) != image for node, image in now.items())
    assert all(image in pixels.values() for image in now.values())


def test_a_repainted_texture_misses_the_nodes_above_it_and_only_those(row, tmp_path, monkeypatch):
    folder, textures = _warm(row, tmp_path)
    repainted = {**row.images, 0: 255 - row.images[0]}  # the first sphere's west half, same file name and fields
    repainted[0][..., 3] = 255
    made = _proxies_made(monkeypatch)
    again = bake(row.mesh, SETTINGS, images=repainted, textures=textures("again"), cache_dir=folder)
    stats = again.meta["cache"]
    assert stats["reused_nodes"] > 0 and stats["rebuilt_nodes"] > 0 and made and not stats["reused_result"]
    # every node above a leaf that shows material 0 is rebuilt, and no other
    leaves_of_0 = [n for n in range(again.node_count) if again.child_count[n] == 0 and np.any(
        again.tri_material[again.tri_offset[n]:again.tri_offset[n] + again.tri_count[n]] == 0)]
    above = set()
    for leaf in leaves_of_0:
        node = int(again.parent[leaf])
        while node >= 0:
            above.add(node)
            node = int(again.parent[node])
    assert stats["rebuilt_nodes"] == len(above) and set(made) <= above
    changed = {name for name, data in textures.files("again").items() if row.textures.files("first")[name] != data}
    assert changed and changed <= {f"proxy_{node}.png" for node in above}


@pytest.mark.parametrize("change", ["texture_cap", "keep materials"])
def test_changed_texture_settings_miss(change, row, tmp_path):
    folder, textures = _warm(row, tmp_path)
    settings = {"texture_cap": replace(SETTINGS, texture_cap=16),
                "keep materials": replace(SETTINGS, proxy_materials=False)}[change]
    again = bake(row.mesh, settings, images=row.images, textures=textures("again"), cache_dir=folder)
    assert again.meta["cache"]["reused_nodes"] == 0 and again.meta["cache"]["rejected_entries"] == 0
    assert not again.meta["cache"]["reused_result"]


def test_every_proxy_setting_is_in_the_key():
    """Each field of ProxySettings (texture cap and floor, tau, on or off) changes the context digest,
    and a bake without proxies has another key than any with them."""
    base = dict(settings=DecimationSettings(), with_normals=False, row_layout=None)
    keys = {cache_keys.context_digest(**base), cache_keys.context_digest(**base, proxies=ProxySettings())}
    for field, value in (("enabled", False), ("texture_cap", 512), ("texture_floor", 8), ("tau_px", 2.0)):
        keys.add(cache_keys.context_digest(**base, proxies=replace(ProxySettings(), **{field: value})))
    assert len(keys) == 6


def _layout() -> OctreeLayout:
    """Root 0 with children 1 and 2; node 2 with children 3 and 4 (leaves 1, 3, 4)."""
    child_count = np.array([2, 0, 2, 0, 0], np.int64)
    return SimpleNamespace(parent=np.array([-1, 0, 0, 2, 2]), child_offset=np.array([1, 0, 3, 0, 0]),
                           child_count=child_count, is_leaf=child_count == 0)


def test_proxy_ids_are_stored_as_paths_below_the_node_and_renumbered_on_reading():
    """A node keeping a descendant's proxy names it by its path; the same subtree under another
    number reads back the proxy ids of the nodes it has there."""
    scene = 3
    rows = np.array([[1.0, 0.5], [scene + 2 * 3 + 1, 0.5], [scene + 2 * 2, 0.25]], np.float32)
    stored, paths = cache_proxies.encode(rows, 2, _layout(), scene_materials=scene, column=0)
    assert paths == [[], [0]] and stored[0, 0] == 1.0 and np.all(stored[1:, 0] < 0)
    moved = SimpleNamespace(parent=np.array([-1, 0, 0, 0, 3, 3]), child_offset=np.array([1, 0, 0, 4, 0, 0]),
                            child_count=np.array([3, 0, 0, 2, 0, 0]))  # that subtree is node 3 here
    back = cache_proxies.decode(stored, paths, 3, moved, scene_materials=scene, column=0)
    assert back[:, 0].tolist() == [1.0, scene + 2 * 4 + 1, scene + 2 * 3]
    assert np.array_equal(cache_proxies.decode(stored, paths, 2, _layout(), scene_materials=scene, column=0), rows)
    with pytest.raises(CorruptEntry):
        cache_proxies.decode(stored, [[], [5]], 2, _layout(), scene_materials=scene, column=0)
    with pytest.raises(CorruptEntry):
        cache_proxies.decode(stored, [[]], 2, _layout(), scene_materials=scene, column=0)


def test_png_pixels_reads_back_what_png_bytes_writes():
    for image in (_image(1), _image(2)[..., :3], np.zeros((1, 7, 4), np.uint8)):
        assert np.array_equal(png_pixels(png_bytes(image, level=1)), image)
    with pytest.raises(ValueError):
        png_pixels(b"not a png")


def test_a_hit_counts_only_where_every_inner_node_below_it_is_a_hit():
    """With proxies a parent's task reads its children's textures: a hit above an inner node that
    missed (an entry evicted or spoilt) is rebuilt too, with every node between them."""
    layout = _layout()
    hits = {0: "root", 2: "inner"}
    assert cache.whole_subtrees(layout, hits) == hits
    assert cache.whole_subtrees(layout, {0: "root"}) == {}  # node 2 missed: the root is rebuilt
    assert cache.whole_subtrees(layout, {2: "inner"}) == {2: "inner"}


# --- the whole result of a bake with proxy materials ---------------------------------------------

def test_an_unchanged_input_takes_the_whole_result_with_its_textures(row, tmp_path, monkeypatch):
    """No node is read nor baked: the result entry gives the file and every texture file of a bake
    from scratch, byte for byte, named from the texture folder of this bake (another output's)."""
    folder, textures = _warm(row, tmp_path)
    made = _proxies_made(monkeypatch)
    warm = bake(row.mesh, SETTINGS, images=row.images, textures=textures("warm"), cache_dir=folder)
    stats = warm.meta["cache"]
    assert stats["reused_result"] and stats["rejected_entries"] == 0 and made == []
    assert file_bytes(warm, tmp_path / "warm.hlod") == file_bytes(row.scratch, tmp_path / "scratch.hlod")
    assert textures.files("warm") == row.textures.files("scratch")
    other = _Textures(tmp_path / "other")  # another output: its file's materials name its own folder
    hit = bake(row.mesh, SETTINGS, images=row.images, textures=other("hit"), cache_dir=folder)
    assert hit.meta["cache"]["reused_result"] and made == []
    monkeypatch.undo()
    scratch = bake(row.mesh, SETTINGS, images=row.images, textures=other("scratch"))
    assert file_bytes(hit, tmp_path / "hit.hlod") == file_bytes(scratch, tmp_path / "scratch2.hlod")
    assert other.files("hit") == other.files("scratch") == row.textures.files("scratch")
    proxies = hit.materials[len(row.mesh.materials):]
    assert proxies and all(Path(m.texture).parent == other.final.resolve() for m in proxies)


def test_a_changed_material_field_misses_the_whole_result(row, tmp_path):
    folder, textures = _warm(row, tmp_path)
    changed = replace(row.mesh, materials=(replace(row.mesh.materials[0], base_color=(1.0, 0.5, 0.5, 1.0)),
                                           *row.mesh.materials[1:]))
    again = bake(changed, SETTINGS, images=row.images, textures=textures("again"), cache_dir=folder)
    stats = again.meta["cache"]
    assert not stats["reused_result"] and stats["rebuilt_nodes"] > 0 and stats["reused_nodes"] > 0
    scratch = bake(changed, SETTINGS, images=row.images, textures=textures("scratch"))
    assert file_bytes(again, tmp_path / "again.hlod") == file_bytes(scratch, tmp_path / "scratch.hlod")
    assert textures.files("again") == textures.files("scratch") != row.textures.files("first")


def _result_pngs(path: Path) -> list[bytes]:
    _, arrays = cache_files.unpack(path.read_bytes(), bytes.fromhex(path.stem), "result")
    return sorted(a.tobytes() for name, a in arrays.items() if name.startswith(cache_proxies.PNG))


def test_the_whole_result_holds_the_textures_and_the_budget_counts_them(row, tmp_path):
    """The result entry holds every texture file the bake wrote (so the folder's size, which the
    budget holds, counts them); a bake of another input with a budget of 0 evicts it whole."""
    folder, textures = _warm(row, tmp_path)
    (result,) = folder.glob("*.hlodr")
    assert _result_pngs(result) == sorted(row.textures.files("first").values())
    moved, _ = _row(moved_by=0.6)
    again = bake(moved, SETTINGS, images=row.images, textures=textures("again"), cache_dir=folder, cache_budget_mb=0)
    stats = again.meta["cache"]
    (kept,) = folder.glob("*.hlodr")
    assert kept != result and stats["evicted_entries"] >= 1
    assert _result_pngs(kept) == sorted(textures.files("again").values())
    assert stats["size_mb"] == round(sum(p.stat().st_size for p in folder.iterdir()) / 2**20, 3)
    assert len(list(folder.glob("*.hlodc"))) == stats["nodes"]  # the entries it used, nothing else


def test_a_whole_result_that_fails_a_check_writes_none_of_its_textures(row, tmp_path, monkeypatch):
    """A result entry with a spoilt texture (its digest redone: only the PNG check finds it) is a
    miss before any of its textures is written; the bake then makes them and gives a bake from
    scratch's files."""
    folder, textures = _warm(row, tmp_path)
    for entry in folder.glob("*.hlodc"):
        entry.unlink()
    (result,) = folder.glob("*.hlodr")
    key = bytes.fromhex(result.stem)
    extra, arrays = cache_files.unpack(result.read_bytes(), key, "result")
    last = f"{cache_proxies.PNG}_{len(extra[cache_proxies.RESULT]['textures']) - 1}"
    arrays[last] = arrays[last][::-1].copy()
    result.write_bytes(cache_files.pack(key, "result", arrays, extra=extra))
    restored = []
    monkeypatch.setattr(ProxyPlan, "restore", lambda plan, node, *a: restored.append(node))
    again = bake(row.mesh, SETTINGS, images=row.images, textures=textures("again"), cache_dir=folder)
    assert again.meta["cache"]["rejected_entries"] == 1 and not again.meta["cache"]["reused_result"]
    assert restored == [] and textures.files("again") == row.textures.files("scratch")
    assert file_bytes(again, tmp_path / "again.hlod") == file_bytes(row.scratch, tmp_path / "scratch.hlod")


@contextlib.contextmanager
def _files_limited_to(size: int):
    """Writes past `size` bytes of a file fail (EFBIG) in this process: a full disk, for real writes."""
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    handler = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (size, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, handler)


def test_a_failed_write_leaves_no_partial_whole_result_nor_output(row, tmp_path, monkeypatch):
    """Writing the result entry fails (its file over the limit, as on a full disk): the bake keeps its
    node entries, no result entry nor temporary file is left, and the next bake takes every node from
    its entry. A hit whose texture write fails leaves the output as it was."""
    entries = [p.stat().st_size for p in row.folder.glob("*.hlodc")]
    (result,) = row.folder.glob("*.hlodr")
    assert result.stat().st_size > max(entries) + 1
    finish = cache.BakeCache.finish

    def finish_on_a_full_disk(self, *args, **kwargs):
        with _files_limited_to(max(entries) + 1):
            return finish(self, *args, **kwargs)

    monkeypatch.setattr(cache.BakeCache, "finish", finish_on_a_full_disk)
    textures = _Textures(tmp_path, row.textures.final)
    folder = tmp_path / "cache"
    bake(row.mesh, SETTINGS, images=row.images, textures=textures("first"), cache_dir=folder)
    monkeypatch.undo()
    assert not list(folder.glob("*.hlodr")) and not list(folder.glob(".*"))
    assert len(list(folder.glob("*.hlodc"))) == len(entries)
    again = bake(row.mesh, SETTINGS, images=row.images, textures=textures("again"), cache_dir=folder)
    assert not again.meta["cache"]["reused_result"] and again.meta["cache"]["rejected_entries"] == 0
    assert file_bytes(again, tmp_path / "again.hlod") == file_bytes(row.scratch, tmp_path / "scratch.hlod")
    # the hit's texture writes fail part way: nothing is published beside the output
    pngs = sorted(len(data) for data in row.textures.files("scratch").values())
    output = tmp_path / "out" / "scene.hlod"
    output.parent.mkdir()
    with pytest.raises(OSError), EmbeddedTextures(output) as published, _files_limited_to(pngs[len(pngs) // 2]):
        bake(row.mesh, SETTINGS, images=row.images, textures=published, cache_dir=folder)
    assert list(output.parent.iterdir()) == []


def test_a_cancelled_bake_with_proxies_writes_no_entry(row, tmp_path):
    """Cancelled once some proxies are made (their PNGs already in the bake's texture folder): no
    node entry and no whole result; a bake into that folder afterwards is a bake from scratch."""
    textures, folder, done = _Textures(tmp_path, row.textures.final), tmp_path / "cache", []

    def progress(finished, total, phase):
        done.append(phase)

    with pytest.raises(BakeCancelled):
        bake(row.mesh, SETTINGS, images=row.images, textures=textures("cancelled"), cache_dir=folder,
             progress=progress, cancel=lambda: done.count("simplify") >= 2)
    assert list((tmp_path / "cancelled").glob("proxy_*.png")) and not folder.exists()
    again = bake(row.mesh, SETTINGS, images=row.images, textures=textures("again"), cache_dir=folder)
    assert again.meta["cache"]["reused_nodes"] == 0 and not again.meta["cache"]["reused_result"]
    assert file_bytes(again, tmp_path / "again.hlod") == file_bytes(row.scratch, tmp_path / "scratch.hlod")
