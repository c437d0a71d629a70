"""The bake's streamed write (bake/assemble.py's Assembled, io/hlod_file.py's StreamedWriter) and its
LOD spill (bake/run/lod_spill.py): the file written a block of nodes at a time is, byte for byte,
the file of the whole arrays in memory; its geometry is the whole-array concatenation the bake made
before it streamed; a failed write leaves no file, and an earlier one untouched; an input handed
over to the bake is freed once the leaves are cut."""
from __future__ import annotations

import gc
import weakref

import numpy as np
import pytest

from hlod_core.bake import pipeline, prepare
from hlod_core.bake.pipeline import bake
from hlod_core.bake.run import lod_spill
from hlod_core.bake.settings import BakeSettings
from hlod_core.io import hlod_file, meshes
from hlod_core.model import appearance
from sample_meshes import SPHERE_CENTER, SPHERE_TARGET_TRIS, sphere, textured_sphere


def _sphere_with_normals() -> meshes.TriangleMesh:
    positions, faces = sphere()
    normals = (positions - SPHERE_CENTER) / np.linalg.norm(positions - SPHERE_CENTER, axis=1, keepdims=True)
    return meshes.from_arrays(positions, faces, normals.astype(np.float32), name="sphere with normals")


#: name -> (mesh, settings): with and without proxies, UVs, colours, materials and normals.
CASES = {
    "proxies": (lambda: textured_sphere(), {}),
    "uvs colours materials": (lambda: textured_sphere(), {"proxy_materials": False}),
    "uvs only": (lambda: textured_sphere(colors=False, materials=False), {}),
    "colours and materials": (lambda: textured_sphere(uvs=False), {"proxy_materials": False}),
    "normals, no appearance": (_sphere_with_normals, {}),
}


def _baked(monkeypatch, name: str):
    """The in-memory bake of CASES[name] and its Assembled (captured from the pipeline)."""
    mesh, options = CASES[name]
    captured = {}
    assemble = pipeline.assemble

    def keep(*args, **kwargs):
        captured["assembled"] = assemble(*args, **kwargs)
        return captured["assembled"]

    monkeypatch.setattr(pipeline, "assemble", keep)
    hlod = bake(mesh(), BakeSettings(target_tris=SPHERE_TARGET_TRIS, jobs=1, **options))
    return hlod, captured["assembled"]


def _whole_arrays(assembled) -> dict:
    """The geometry as the bake made it before it streamed: every LOD concatenated at once, the
    indices offset, the triangles sorted by (node, material) with one lexsort, the rows unpacked."""
    lods = [tuple(lod_spill.loaded(a) for a in lod) for lod in assembled.lods]
    counts = np.array([lod[0].shape[0] for lod in lods])
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
    indices = np.concatenate([lod[1].astype(np.int64) + v for lod, v in zip(lods, offsets)]).astype(np.uint32)
    out = {"positions": np.concatenate([lod[0] for lod in lods]).astype(np.float32),
           "normals": np.concatenate([lod[2] for lod in lods]).astype(np.float32) if assembled.normals else None,
           "uvs": None, "colors": None, "tri_material": None}
    if not assembled.row_layout.empty:
        uvs, colors, face_material = appearance.unpack(assembled.row_layout, np.concatenate([lod[3] for lod in lods]),
                                                       indices)
        out.update(uvs=uvs, colors=colors)
        if face_material is not None:
            tris = np.array([lod[1].shape[0] for lod in lods])
            order = np.lexsort((face_material, np.repeat(np.arange(len(lods)), tris)))
            indices, out["tri_material"] = indices[order], face_material[order].astype(np.uint16)
    out["indices"] = indices
    return out


@pytest.mark.parametrize("name", list(CASES))
def test_streamed_file_is_the_in_memory_file(name, monkeypatch, tmp_path):
    hlod, assembled = _baked(monkeypatch, name)
    present = {k: getattr(hlod, k) is not None for k in ("normals", "uvs", "colors", "tri_material")}
    assert present["normals"] == (name == "normals, no appearance")
    assert present["uvs"] == ("uvs" in name or name == "proxies")
    assert present["tri_material"] == ("materials" in name or name == "proxies")
    if name == "proxies":
        assert len(hlod.materials) > 2  # the inner nodes' proxy materials, after the sphere's two
    hlod_file.save(hlod, tmp_path / "whole.hlod")
    # a block of a few nodes at a time: every node boundary inside the file's arrays is crossed
    monkeypatch.setattr("hlod_core.bake.assemble.BLOCK_VERTICES", 300)
    assembled.write(tmp_path / "streamed.hlod", meta=hlod.meta, materials=hlod.materials)
    assert (tmp_path / "streamed.hlod").read_bytes() == (tmp_path / "whole.hlod").read_bytes()
    whole = _whole_arrays(assembled)
    for key, array in whole.items():
        got = getattr(hlod, key)
        assert (got is None) == (array is None), key
        if array is not None:
            assert got.dtype == array.dtype and np.array_equal(got, array), key


def test_a_bake_to_a_file_writes_the_in_memory_bake(tmp_path):
    mesh = textured_sphere(uvs=False)
    settings = BakeSettings(target_tris=SPHERE_TARGET_TRIS, jobs=1, proxy_materials=False)
    in_memory = bake(mesh, settings)
    mapped = bake(mesh, settings, output=tmp_path / "out.hlod")
    loaded = hlod_file.load(tmp_path / "out.hlod")
    for key in ("positions", "indices", "colors", "tri_material", "error", "sphere_radius", "box_min", "tri_offset"):
        assert np.array_equal(getattr(loaded, key), getattr(in_memory, key)), key
        assert np.array_equal(getattr(mapped, key), getattr(in_memory, key)), key
    assert mapped.summary() == in_memory.summary()
    assert {k: v for k, v in loaded.meta.items() if "seconds" not in k} == \
        {k: v for k, v in in_memory.meta.items() if "seconds" not in k}


def test_the_simplify_phase_spills_every_lod_but_the_roots(monkeypatch):
    _, assembled = _baked(monkeypatch, "colours and materials")
    spilled = [isinstance(lod[0], lod_spill.Spilled) for lod in assembled.lods]
    assert not spilled[0] and all(spilled[1:])
    _, with_proxies = _baked(monkeypatch, "proxies")  # the proxies' plan rewrites LODs after the phase: kept
    assert not any(isinstance(lod[0], lod_spill.Spilled) for lod in with_proxies.lods)


def test_spilled_arrays_come_back_the_same(tmp_path):
    spill = lod_spill.LodSpill(tmp_path)
    rng = np.random.default_rng(3)
    lod = (rng.random((7, 3), np.float32), rng.integers(0, 7, (5, 3)).astype(np.int32), None,
           rng.random((0, 4), np.float32))
    back = spill.put(lod)
    assert back[2] is None and spill.put(back)[0] is back[0]
    for before, after in zip(lod, back):
        if before is not None:
            again = after.load()
            assert again.dtype == before.dtype and again.shape == before.shape and np.array_equal(again, before)
    assert list(tmp_path.iterdir()) == []  # unlinked from the start
    mapped = np.memmap(tmp_path / "leaf.bin", dtype=np.float32, mode="w+", shape=(4, 3))
    view = mapped[1:3]
    assert spill.put((view, None, None, None))[0] is view  # already in a file: left there
    spill.close()


def _shapes(rows: int) -> dict:
    return {"parent": (1,), "origin": (3,), "positions": (rows, 3)}


@pytest.mark.parametrize("fault", ["raised", "short", "long"])
def test_a_failed_write_leaves_no_file(fault, tmp_path):
    path = tmp_path / "out.hlod"
    with pytest.raises(RuntimeError):
        with hlod_file.StreamedWriter(path, _shapes(4), meta={}) as out:
            out.append("parent", np.array([-1]))
            out.append("origin", np.zeros(3))
            out.append("positions", np.ones((2 if fault != "long" else 5, 3)))
            if fault == "raised":
                raise RuntimeError("the next block could not be made")
    assert list(tmp_path.iterdir()) == []


def test_a_failed_write_leaves_the_earlier_file(tmp_path):
    path = tmp_path / "out.hlod"
    path.write_bytes(b"the earlier bake")
    with pytest.raises(RuntimeError):
        with hlod_file.StreamedWriter(path, _shapes(4), meta={}) as out:
            out.append("positions", np.ones((2, 3)))
    assert path.read_bytes() == b"the earlier bake" and len(list(tmp_path.iterdir())) == 1


def test_a_mesh_handed_over_is_freed_once_the_leaves_are_cut(monkeypatch):
    """bake([mesh]) empties the list; with no other reference the input's arrays are gone when the
    simplify phase starts (the leaves hold what the bake reads from there on)."""
    mesh = textured_sphere(uvs=False)
    faces, positions = weakref.ref(mesh.faces), weakref.ref(mesh.positions)  # the prepared ones below
    handed = [mesh]
    del mesh
    alive, prepared = [], []
    simplify_phase, prepare_mesh = pipeline.simplify_phase, prepare.prepare

    def prepared_refs(*args, **kwargs):
        out = prepare_mesh(*args, **kwargs)
        prepared.extend(weakref.ref(a) for a in (out.positions, out.faces, out.rows))
        return out

    def seen(*args, **kwargs):
        gc.collect()
        alive.append([ref() is not None for ref in (faces, positions, *prepared)])
        return simplify_phase(*args, **kwargs)

    monkeypatch.setattr(prepare, "prepare", prepared_refs)
    monkeypatch.setattr(pipeline, "simplify_phase", seen)
    hlod = bake(handed, BakeSettings(target_tris=SPHERE_TARGET_TRIS, jobs=1, proxy_materials=False))
    assert handed == [] and alive == [[False] * 5] and hlod.node_count > 1
