"""The nodes Coh draws and SW does not, each put in the first class that fits (benchmarks/dn_excess.py
counts them over a path; the traversal tests check the classes):

    finer          SW drew one of its ancestors (Coh's front is deeper there);
    hidden         SW queried the node this frame and found it hidden (Coh drew it on last
                   frame's visibility: CHC's one frame of lag, longer for a skipped query);
    under hidden   SW found one of its ancestors hidden (so never reached it);
    coarser        SW refined the node (its front is deeper there);
    other          none of these.

`missing` counts the nodes SW draws and Coh does not.
"""
from __future__ import annotations

from collections import Counter

import numpy as np

CLASSES = ("finer", "hidden", "under hidden", "coarser", "other")


def _ancestors(parent: np.ndarray, node: int) -> list[int]:
    out, node = [], int(parent[node])
    while node >= 0:
        out.append(node)
        node = int(parent[node])
    return out


def classify(parent: np.ndarray, *, coh_drawn, sw_drawn, sw_visited: np.ndarray, sw_visible: np.ndarray) -> Counter:
    """The classes (module docstring) of the nodes in coh_drawn but not sw_drawn; `missing` too.
    sw_visited, sw_visible: (n,) bool, SW's visits this frame and their visibility."""
    sw_set, coh_set = set(sw_drawn), set(coh_drawn)
    refined_by_sw = {int(parent[node]) for node in sw_set if parent[node] >= 0}
    out = Counter()
    for node in coh_set - sw_set:
        ancestors = _ancestors(parent, node)
        if any(a in sw_set for a in ancestors):
            out["finer"] += 1
        elif sw_visited[node] and not sw_visible[node]:
            out["hidden"] += 1
        elif any(sw_visited[a] and not sw_visible[a] for a in ancestors):
            out["under hidden"] += 1
        elif node in refined_by_sw or (sw_visited[node] and sw_visible[node]):
            out["coarser"] += 1
        else:
            out["other"] += 1
    out["missing"] = len(sw_set - coh_set)
    return out
