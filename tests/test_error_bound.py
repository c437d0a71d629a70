"""The error bound (`BakeSettings(error="bound")`) against the exact error, real pymeshlab.

docs/how-it-works.md#the-error-bound proves bound(n) = h(n) + max child bound >= H(LOD_n, originals below n)
for the true (continuous) Hausdorff distances. The bake measures both figures from samples (LOD
vertices and hausdorff.FACE_SAMPLES points to the other surface, the other side's vertices to the
LOD), and a sampled figure can only fall short of the true one. Where a node's children are leaves
both measures take the same samples of the same two surfaces: the same float. One level up the
bound's chain passes through the point z of a child's LOD nearest a sample, which is no sample
itself, so the sampled bound may fall short of the sampled exact error by up to the distance from
z to the child's nearest sample: at most its triangle's longest edge / sqrt(3) (the covering radius
of a triangle by its corners), once per level below (`sampling_slack`). That slack is the
tolerance of the guaranteed inequality; on the test models the bound does not even use it
(bound >= exact with no slack on every node; benchmarks/error_bound.py runs every test model).
"""
from __future__ import annotations

import hashlib
import io
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import pytest

from helpers import load_model, model, numeric_library_env
from hlod_core.bake.measure import hausdorff
from hlod_core.bake.pipeline import bake
from hlod_core.bake.settings import BakeSettings
from hlod_core.core.errors import InputError
from hlod_core.io import hlod_file, meshes

ROOT = Path(__file__).resolve().parents[1]
#: Small test models (tests/models.py) and node budgets giving trees three to four levels deep in about a second.
MODELS = [("cow", 300), ("creased", 300)]
#: float32 rounding of pymeshlab's distances (relative), the only slack the no-slack check allows.
F32_RELATIVE = 1e-6
#: The last commit that changed what an exact bake writes (d373408: the root cube's lowest corner at
#: the centroids' box's, which moves the cow's cells; before that eba7dec, the coarse levels' locks
#: and pruning, 103ebcb, the bake's lattice, and the commit before the error bound, b1e28ff): an
#: exact bake must write the bytes it wrote there.
BEFORE_BOUND = "d373408"
#: SHA-256 of the cow (tests/models.py) baked exactly at target_tris 300 (timings zeroed) at BEFORE_BOUND, pinned
#: pymeshlab, on an AMD EPYC machine), for checkouts without that commit; where the
#: commit is there, the old code's own file is compared instead (the digest of floats is per CPU).
FILE_BEFORE_BOUND = "e1012fd048b74d01dc260935d5901711f832c49600eec195347072458438eca2"


@pytest.fixture(scope="module")
def bakes():
    """name -> (exact Hlod, bound Hlod), jobs 1."""
    out = {}
    for name, target in MODELS:
        mesh = load_model(name)
        out[name] = tuple(bake(mesh, BakeSettings(target_tris=target, error=mode)) for mode in ("exact", "bound"))
    return out


def lod(hlod, node: int) -> tuple[np.ndarray, np.ndarray]:
    """Node `node`'s LOD as the bake had it: (positions f32 origin-relative, faces local int32)."""
    v0, t0 = int(hlod.vertex_offset[node]), int(hlod.tri_offset[node])
    faces = hlod.indices[t0:t0 + int(hlod.tri_count[node])].astype(np.int64) - v0
    return hlod.positions[v0:v0 + int(hlod.vertex_count[node])], faces.astype(np.int32)


def children(hlod, node: int) -> range:
    first = int(hlod.child_offset[node])
    return range(first, first + int(hlod.child_count[node]))


def sampling_slack(hlod) -> np.ndarray:
    """(n,) model units: how far the sampled bound may fall below the sampled exact error (module
    docstring): 0 at leaves and at nodes whose children are leaves; else the max over children c of
    slack(c) + longest edge of c's LOD / sqrt(3)."""
    slack = np.zeros(hlod.node_count)
    for node in range(hlod.node_count - 1, -1, -1):  # children have larger ids
        for kid in children(hlod, node):
            if hlod.is_leaf[kid]:
                continue
            p, f = lod(hlod, kid)
            corners = p[f].astype(np.float64)
            edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)
            slack[node] = max(slack[node], slack[kid] + float(edges.max()) / np.sqrt(3.0))
    return slack


@pytest.mark.parametrize("name", [m for m, _ in MODELS])
def test_bound_is_at_least_the_exact_error_on_every_node(bakes, name):
    exact, bound = bakes[name]
    assert np.array_equal(exact.positions, bound.positions) and np.array_equal(exact.indices, bound.indices)
    assert int(exact.depth.max()) >= 2, "the tree must have a level whose children are not leaves"
    assert np.all(bound.error >= exact.error - sampling_slack(exact))
    short = np.flatnonzero(bound.error < exact.error * (1.0 - F32_RELATIVE))
    assert short.size == 0, f"{name}: nodes {short.tolist()} have a bound below their exact error"
    # where the children are leaves both measures take the same samples: the same float
    lowest = np.array([not exact.is_leaf[n] and all(exact.is_leaf[k] for k in children(exact, n))
                       for n in range(exact.node_count)])
    raw_exact = np.array([hausdorff.measure(lod(exact, n), _union(exact, n)) if lowest[n] else 0.0
                          for n in range(exact.node_count)])
    assert np.array_equal(bound.error[lowest], raw_exact[lowest])
    assert np.any(bound.error[~exact.is_leaf & ~lowest] > exact.error[~exact.is_leaf & ~lowest])


def _union(hlod, node: int):
    """The leaves' triangles below `node` (its children here: every child is a leaf)."""
    parts = [lod(hlod, k) for k in children(hlod, node)]
    positions = np.concatenate([p for p, _ in parts])
    offsets = np.cumsum([0] + [p.shape[0] for p, _ in parts[:-1]])
    return positions, np.concatenate([f + o for (_, f), o in zip(parts, offsets)]).astype(np.int32)


@pytest.mark.parametrize("name", [m for m, _ in MODELS])
def test_bound_is_h_plus_the_largest_child_bound_zero_at_leaves(bakes, name):
    """Recomputed from the file's LODs: bound(n) = measure_to_children(LOD_n, children's LODs) +
    max child bound, exactly; finite; 0 at leaves; so never below a child's bound (monotone by
    construction, not by the max _assemble takes)."""
    _, bound = bakes[name]
    assert np.all(np.isfinite(bound.error)) and np.all(bound.error[bound.is_leaf] == 0.0)
    for node in np.flatnonzero(~bound.is_leaf).tolist():
        kids = children(bound, node)
        h = hausdorff.measure_to_children(lod(bound, node), [lod(bound, k) for k in kids])
        assert h >= 0 and bound.error[node] == h + max(bound.error[k] for k in kids), node


def test_error_setting_is_validated_and_recorded():
    with pytest.raises(InputError, match="error must be one of exact, bound, got 'loose'"):
        BakeSettings(error="loose")
    cow = load_model("cow")
    assert bake(cow, BakeSettings(target_tris=1000, error="bound")).meta["settings"]["error"] == "bound"
    assert "error" not in bake(cow, BakeSettings(target_tris=1000)).meta["settings"]  # absent: exact


#: Triangles per node of the herd (three cows, 17k triangles): about 30 nodes.
HERD_TARGET = 600


def _herd(scale_middle: float = 1.0):
    """Three cows in a row, 12 units apart; the middle one scaled about its centre (the box stays)."""
    cow, parts = load_model("cow"), []
    for k in range(3):
        m = np.eye(4)
        m[:3, 3] = [12.0 * k, 0.0, 0.0]
        if k == 1:
            centre = 0.5 * (cow.positions.min(axis=0) + cow.positions.max(axis=0))
            m[:3, :3] *= scale_middle
            m[:3, 3] += (1.0 - scale_middle) * centre
        parts.append(meshes.transform_mesh(cow, m, name=f"cow{k}"))
    return meshes.merge(parts, name="herd")


def _same(a, b) -> bool:
    return all(np.array_equal(x, getattr(b, k)) for k, x in a.node_arrays().items()) \
        and np.array_equal(a.positions, b.positions) and np.array_equal(a.indices, b.indices)


def test_cache_never_serves_one_measure_for_the_other_and_rebakes_bounds_exactly(tmp_path):
    herd, edited = _herd(), _herd(0.98)
    exact_settings, bound_settings = BakeSettings(target_tris=HERD_TARGET), BakeSettings(target_tris=HERD_TARGET,
                                                                                           error="bound")
    folder = tmp_path / "cache"
    exact = bake(herd, exact_settings, cache_dir=folder)
    bound = bake(herd, bound_settings, cache_dir=folder)  # the exact bake's entries must not serve it
    assert bound.meta["cache"]["reused_nodes"] == 0 and not bound.meta["cache"]["reused_result"]
    assert not np.array_equal(exact.error, bound.error)
    bound_first = tmp_path / "bound first"
    bake(herd, bound_settings, cache_dir=bound_first)
    again = bake(herd, exact_settings, cache_dir=bound_first)  # nor the bound's an exact bake
    assert again.meta["cache"]["reused_nodes"] == 0 and _same(again, exact)
    assert bake(herd, exact_settings, cache_dir=folder).meta["cache"]["reused_result"]  # the exact bake's own
    # bounds: a re-bake after an edit mixes cached bounds with rebuilt ones, as a bake from scratch
    bake(herd, bound_settings, cache_dir=folder)
    again = bake(edited, bound_settings, cache_dir=folder)
    assert 0 < again.meta["cache"]["reused_nodes"] < again.meta["cache"]["nodes"]
    scratch = bake(edited, BakeSettings(target_tris=HERD_TARGET, error="bound", jobs=2))  # worker processes too
    assert _same(again, scratch)


def _exact_file(hlod, path: Path) -> bytes:
    """The file's bytes with the timings zeroed and the sources named by file name only (the path
    of the test models depends on where the checkout is)."""
    hlod = hlod.replace(meta={**hlod.meta, "bake_seconds": 0.0, "sources": [Path(s).name for s in hlod.meta["sources"]],
                              "phase_seconds": {k: 0.0 for k in hlod.meta["phase_seconds"]}})
    return hlod_file.save(hlod, path).read_bytes()


def test_exact_bake_writes_the_bytes_it_wrote_before_the_bound(tmp_path):
    """The cow baked exactly: the same .hlod bytes as the bake at BEFORE_BOUND (taken from git into a
    temporary folder, run in its own process, its file re-saved by today's writer)."""
    source = model("cow")
    new = _exact_file(bake(meshes.load_mesh(source), BakeSettings(target_tris=300)), tmp_path / "new.hlod")
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", BEFORE_BOUND, "hlod_core"],
                             capture_output=True)
    if archive.returncode == 0:  # else a checkout without that commit: the digest below
        old = tmp_path / "before"
        with tarfile.open(fileobj=io.BytesIO(archive.stdout)) as tar:
            tar.extractall(old, filter="data")
        script = (
            "import sys\n"
            "from hlod_core.io import hlod_file as fileformat, meshes as meshio\n"
            "from hlod_core.bake.pipeline import bake\n"
            "from hlod_core.bake.settings import BakeSettings\n"
            f"assert fileformat.__file__.startswith({str(old)!r})\n"
            "h = bake(meshio.load_mesh(sys.argv[1]), BakeSettings(target_tris=300))\n"
            "zero = {k: 0.0 for k in h.meta['phase_seconds']}\n"
            "fileformat.save(h.replace(meta={**h.meta, 'bake_seconds': 0.0, 'phase_seconds': zero}), sys.argv[2])\n")
        subprocess.run([sys.executable, "-c", script, str(source), str(tmp_path / "old.hlod")], cwd=old,
                       env={"PATH": "/usr/bin:/bin", "PYTHONPATH": str(old), **numeric_library_env()}, check=True)
        assert new == _exact_file(hlod_file.load(tmp_path / "old.hlod"), tmp_path / "resaved.hlod")
    else:  # the digest was taken on one CPU; pymeshlab's floats differ on another (AMD EPYC vs Intel Xeon)
        assert hashlib.sha256(new).hexdigest() == FILE_BEFORE_BOUND
