"""Which inner nodes a re-bake rebuilt (tests/test_bake_cache.py, tests/test_frame.py): the real
decimations and measurements of a jobs = 1 bake counted, and each node's subtree from a baked file
alone (its shape and leaf triangles in world coordinates), so two files' subtrees can be matched."""
from __future__ import annotations

import hashlib

import numpy as np

from hlod_core.bake.decimate import simplify
from hlod_core.bake.run import tasks


class Counted:
    """Counts the real decimations and measurements of a jobs = 1 bake, and the nodes measured (by
    their range in the bake's triangle order)."""

    def __init__(self, monkeypatch):
        self.decimations = 0
        self.measured: list[tuple[int, int]] = []
        decimate, measure = simplify.decimate_node, tasks.measure_exact

        def counting_decimate(*args, **kwargs):
            self.decimations += 1
            return decimate(*args, **kwargs)

        def counting_measure(folder, lod, ranges):
            cluster_start = tasks.shared(folder)["start"]  # the node's clusters' face range
            self.measured.append((int(cluster_start[ranges[2]]), int(cluster_start[ranges[3]])))
            return measure(folder, lod, ranges)

        monkeypatch.setattr(simplify, "decimate_node", counting_decimate)
        monkeypatch.setattr(tasks, "measure_exact", counting_measure)


def dfs_ranges(hlod) -> dict[tuple[int, int], int]:
    """{(first, end) range of the node's leaf triangles in depth-first leaf order: node}, the ranges
    the bake measures nodes by."""
    ranges, cursor = {}, 0

    def visit(node):
        nonlocal cursor
        begin = cursor
        if hlod.child_count[node] == 0:
            cursor += int(hlod.tri_count[node])
        for child in range(hlod.child_offset[node], hlod.child_offset[node] + hlod.child_count[node]):
            visit(child)
        ranges[(begin, cursor)] = node

    visit(0)
    return ranges


def subtree_signatures(hlod) -> list[bytes]:
    """Per node, a digest of its subtree's shape and leaf triangles (world coordinates as stored),
    computed from the file alone: equal signatures = the same subtree."""
    sig = [b""] * hlod.node_count
    for node in range(hlod.node_count - 1, -1, -1):
        if hlod.child_count[node] == 0:
            tris = hlod.indices[hlod.tri_offset[node]:hlod.tri_offset[node] + hlod.tri_count[node]]
            world = hlod.positions[tris.ravel()].astype(np.float64) + hlod.origin
            sig[node] = hashlib.sha256(b"leaf" + world.tobytes()).digest()
        else:
            kids = range(hlod.child_offset[node], hlod.child_offset[node] + hlod.child_count[node])
            sig[node] = hashlib.sha256(b"node" + b"".join(sig[k] for k in kids)).digest()
    return sig


def inner_count(hlod) -> int:
    """The inner nodes of an Hlod."""
    return int((~hlod.is_leaf).sum())
