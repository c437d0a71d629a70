"""Ways to keep only a node's cell seams in place during pymeshlab's quadric collapse, measured on
half of a model with open boundaries (the half a cell boundary at the median x leaves: its seam
vertices are those the other half uses too).

    PYTHONPATH=. .venv/bin/python -m benchmarks.seam_locks [--models bunny teapot]
        [--target-tris 500] [--repeat 3]

Ways (meshlab.quadric_collapse is the last):
    boundary        preserveboundary=True: every open edge stays (the seams and the model's own rims)
    nothing         preserveboundary=False: nothing stays (cracks: seam vertices move)
    ring            selected=True, the faces touching a seam vertex unselected (pymeshlab then
                    freezes every vertex with an unselected face: the seam's whole one-ring)
    zero-area face  selected=True, every real face selected and one unselected zero-area face per
                    seam vertex (meshlab.lock_by_selection): exactly the seam vertices stay
    ... every edge  the same with every vertex on an open edge: boundary's vertex set, to compare
                    the LOD (the same, bit for bit) and the cost of the selected mode
Per way: the triangles reached, the seam vertices found bit-identical in the LOD, the open edges
left off the seam (the model's rims), the symmetric Hausdorff error against the half
(hausdorff.measure, relative to the half's box diagonal) and the collapse's seconds (median).

Then the cost of freeing a model's rims where the budget does not need it: the model baked at
--target-tris, its root's input (the children's LODs, welded) collapsed to the target with its
rims in place (what the bake does) and free at boundary weights 1, 10 and 1000; the error against
that input (hausdorff.measure, model units).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from hlod_core.bake.decimate import meshlab, simplify
from hlod_core.bake.decimate.cell_seams import node_borders
from hlod_core.bake.measure import hausdorff
from hlod_core.core.arrays import compact

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import models  # tests/models.py: the test models by role

ROOT = Path(__file__).resolve().parents[1]


def half_with_seams(name: str):
    """(positions (k,3) f32 welded, faces, seam mask (k,) bool) of the model's half x < median."""
    mesh = models.load(name)
    p = mesh.positions.astype(np.float32)
    centroid_x = p[mesh.faces].mean(axis=1)[:, 0]
    left = centroid_x < np.median(centroid_x)
    positions, faces = simplify.weld(*compact(p, mesh.faces[left])[:2])
    other, _ = simplify.weld(*compact(p, mesh.faces[~left])[:2])
    seam = np.isin(_keys(positions), _keys(other))
    return positions, faces.astype(np.int32), seam


def _keys(positions: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(positions, np.float32).view(np.dtype((np.void, 12))).ravel()


def collapse(way: str, local, faces, seam, settings):
    import pymeshlab

    if way in ("boundary", "nothing"):
        ms = meshlab.mesh_set(local, faces)
        ms.meshing_decimation_quadric_edge_collapse(
            targetfacenum=settings.target_tris, qualitythr=settings.quality_threshold,
            preserveboundary=way == "boundary", boundaryweight=1.0, optimalplacement=True, planarquadric=True,
            autoclean=True)
        return ms
    if way == "ring":
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=local, face_matrix=faces,
                                   f_scalar_array=(~seam[faces].any(axis=1)).astype(np.float64)))
        ms.compute_selection_by_condition_per_face(condselect="fq > 0.5")
        ms.meshing_decimation_quadric_edge_collapse(
            targetfacenum=settings.target_tris, qualitythr=settings.quality_threshold, preserveboundary=False,
            boundaryweight=1.0, optimalplacement=True, planarquadric=True, autoclean=True, selected=True)
        return ms
    if way == "... every edge":
        return meshlab.quadric_collapse(local, faces, settings, optimal_placement=True,
                                        locked=node_borders(local.astype(np.float32), faces, None)[0])
    return meshlab.quadric_collapse(local, faces, settings, optimal_placement=True, locked=seam)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", nargs="+", default=["bunny", "teapot"])
    parser.add_argument("--target-tris", type=int, default=500)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    settings = meshlab.DecimationSettings(target_tris=args.target_tris)
    for name in args.models:
        positions, faces, seam = half_with_seams(name)
        _, rim, _ = node_borders(positions, faces, positions[seam])
        frame = meshlab.NodeFrame.of(positions)
        local = frame.to_local(positions)
        print(f"{name}: half of {faces.shape[0]} triangles, {int(seam.sum())} seam vertices, "
              f"{int(rim.sum())} rim vertices; target {args.target_tris}")
        lods = {}
        for way in ("boundary", "nothing", "ring", "zero-area face", "... every edge"):
            seconds = []
            for _ in range(args.repeat):
                started = time.perf_counter()
                ms = collapse(way, local, faces, seam, settings)
                seconds.append(time.perf_counter() - started)
            lod = ms.current_mesh()
            out = frame.to_model(lod.vertex_matrix(), local, positions)
            kept = np.isin(_keys(positions[seam]), _keys(out))
            lod_f = lod.face_matrix().astype(np.int32)
            lods[way] = (out, lod_f)
            _, lod_rim, _ = node_borders(out, lod_f, positions[seam])
            diagonal = float(np.linalg.norm(np.ptp(positions, axis=0)))
            error = hausdorff.measure((out, lod_f), (positions, faces)) / diagonal
            print(f"  {way:15s} {lod.face_number():5d} triangles, seam vertices kept {int(kept.sum())}/{kept.size}, "
                  f"rim vertices left {int(lod_rim.sum()):4d}, error {error:.5f} of the diagonal, "
                  f"{np.median(seconds):.3f} s")
        same = all(np.array_equal(a, b) for a, b in zip(lods["boundary"], lods["... every edge"]))
        print(f"  the selected mode over every open edge gives boundary's LOD bit for bit: {same}")
    for name in args.models:
        rims_at_the_root(name, args.target_tris * 4)
    return 0


def rims_at_the_root(name: str, target_tris: int) -> None:
    """The root of `name` baked at target_tris, collapsed again from its children with its rims in
    place and free (module docstring)."""
    from hlod_core.bake.pipeline import bake
    from hlod_core.bake.settings import BakeSettings
    from hlod_core.core.arrays import concat_indexed

    hlod = bake(models.load(name), BakeSettings(target_tris=target_tris))
    children = []
    for node in range(int(hlod.child_offset[0]), int(hlod.child_offset[0] + hlod.child_count[0])):
        v0, t0 = int(hlod.vertex_offset[node]), int(hlod.tri_offset[node])
        faces = hlod.indices[t0:t0 + int(hlod.tri_count[node])].astype(np.int64) - v0
        children.append((hlod.positions[v0:v0 + int(hlod.vertex_count[node])], faces))
    positions, faces = simplify.weld(*concat_indexed(children))
    frame = meshlab.NodeFrame.of(positions)
    local = frame.to_local(positions)
    _, rim, _ = node_borders(positions, faces, np.zeros((0, 3), np.float32))
    results = []
    for weight, locked in ((1.0, None), (1.0, np.zeros(rim.size, bool)), (10.0, np.zeros(rim.size, bool)),
                           (1000.0, np.zeros(rim.size, bool))):
        settings = meshlab.DecimationSettings(target_tris=target_tris, boundary_weight=weight)
        ms = meshlab.quadric_collapse(local, faces.astype(np.int32), settings, optimal_placement=True, locked=locked)
        lod = ms.current_mesh()  # the MeshSet must outlive its mesh
        out = frame.to_model(lod.vertex_matrix(), local, positions)
        error = hausdorff.measure((out, lod.face_matrix().astype(np.int32)), (positions, faces.astype(np.int32)))
        results.append(f"{'rims in place' if locked is None else f'rims free, weight {weight:g}'}: "
                       f"{lod.face_number()} triangles, error {error:.5f}")
    print(f"{name} root at {target_tris} ({int(rim.sum())} rim vertices): " + "; ".join(results))


if __name__ == "__main__":
    raise SystemExit(main())
