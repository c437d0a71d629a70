"""simplify.measure's pruned original -> LOD direction (issue 14: the moved re-bake's time went to
measuring the moved object's ancestors against every triangle below them). The pruning must give
the very float the unpruned measure gives, on every inner node of real bakes, and must skip work.
Real pymeshlab: each model (and a herd of cows, whose coarse root is where pruning pays) is baked
(jobs = 1, so measure runs in this process) with measure wrapped to keep the (LOD, original) pairs
the bake measures, then both ways are compared."""
from __future__ import annotations

import numpy as np
import pytest

from hlod_core import meshio, simplify
from hlod_core.bake import BakeSettings, bake

from helpers import load_model


#: The herd: 16 cows (about 10 units long) 12 units apart on a 4 x 4 grid, one mesh of about 93k
#: triangles. Its root's LOD (600 triangles) is far coarser than a cow, the case of the crowd's
#: ancestors, where most original vertices cannot raise the error.
HERD_COWS, HERD_SPACING = 16, 12.0


def _scene(name: str):
    if name != "herd":
        return load_model(name)
    cow, parts = load_model("cow.obj"), []
    for k in range(HERD_COWS):
        m = np.eye(4)
        m[:3, 3] = [HERD_SPACING * (k % 4), HERD_SPACING * (k // 4), 0.0]
        parts.append(meshio.transform_mesh(cow, m, name=f"cow{k}"))
    return meshio.merge(parts, name="herd")


_PAIRS: dict = {}


def _measured_pairs(name: str, target_tris: int) -> list[tuple[tuple, tuple, float]]:
    """Every (lod, original, error) the bake of `name` measures, error as the bake got it (once a
    session per scene)."""
    if (name, target_tris) not in _PAIRS:
        pairs = []
        measure = simplify.measure

        def recording(lod, original, **kwargs):
            error = measure(lod, original, **kwargs)
            pairs.append((lod, original, error))
            return error

        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(simplify, "measure", recording)
            bake(_scene(name), BakeSettings(jobs=1, target_tris=target_tris))
        _PAIRS[name, target_tris] = pairs
    return _PAIRS[name, target_tris]


@pytest.mark.parametrize("name, target_tris",
                         [("cow.obj", 300), ("stanford-bunny.obj", 2000), ("fandisk.obj", 500), ("herd", 600)])
def test_pruned_measure_gives_the_unpruned_float_on_every_inner_node(name, target_tris):
    """Pruned on every node (prune_from=0), not only the large ones the bake prunes: bit-identical
    to measuring every original vertex, and what the bake itself stored."""
    pairs = _measured_pairs(name, target_tris)
    assert len(pairs) >= 3
    for lod, original, error in pairs:
        unpruned = simplify.measure(lod, original, prune_from=None)
        pruned = simplify.measure(lod, original, prune_from=0)
        assert np.isfinite(unpruned)
        assert pruned == unpruned and error == unpruned, (name, original[0].shape, pruned, unpruned, error)


def test_pruning_skips_most_vertices_of_a_large_node(monkeypatch):
    """The herd's root (about 54k original vertices): the pruned direction measures under a quarter of
    them, and the error is the unpruned one."""
    pairs = _measured_pairs("herd", 600)
    lod, original, _ = max(pairs, key=lambda pair: pair[1][0].shape[0])
    assert original[0].shape[0] >= simplify.PRUNE_FROM_VERTICES
    counted = []
    hausdorff_max = simplify._hausdorff_max

    def counting(ms, *, sampled, target, count, save=False):
        if target == 0 and not save:  # original vertices -> LOD
            counted.append(count)
        return hausdorff_max(ms, sampled=sampled, target=target, count=count, save=save)

    monkeypatch.setattr(simplify, "_hausdorff_max", counting)
    pruned = simplify.measure(lod, original)
    pruned_vertices = sum(counted)
    counted.clear()
    unpruned = simplify.measure(lod, original, prune_from=None)
    assert counted == [original[0].shape[0]]
    assert pruned == unpruned
    assert 0 < pruned_vertices < 0.25 * original[0].shape[0], pruned_vertices
