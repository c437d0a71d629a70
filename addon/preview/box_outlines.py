"""Node box outlines over the preview, drawn with Blender's gpu module after the frame (its GL state
restored): the drawn nodes' boxes, the delayed nodes' and those refined after drawing (RARN), as
the panel's Overlay switches choose.
"""
from __future__ import annotations

import numpy as np

from ...hlod_core.model.hierarchy import Hlod
from ...hlod_core.traversal import boxes
from ...hlod_core.traversal.stats import FrameStats

BOX_COLOURS = {"box": (0.9, 0.9, 0.9, 0.6), "delayed": (1.0, 0.85, 0.1, 1.0), "rarn": (0.1, 1.0, 0.2, 1.0)}


def draw_boxes(props, hlod: Hlod, stats: FrameStats) -> None:
    """The boxes of `stats`' node groups that scene.hlod (`props`: show_boxes, show_delayed,
    show_rarn) asks for, one colour per group (BOX_COLOURS), depth-tested against the scene."""
    groups = []
    if props.show_boxes:
        groups.append(("box", stats.drawn))
    if props.show_delayed:
        groups.append(("delayed", stats.delayed))
    if props.show_rarn:
        groups.append(("rarn", stats.refined_after_draw))
    groups = [(name, nodes) for name, nodes in groups if nodes]
    if not groups:
        return
    import gpu
    from gpu_extras.batch import batch_for_shader

    shader = gpu.shader.from_builtin("UNIFORM_COLOR")
    edges = boxes.BOX_EDGES
    gpu.state.depth_test_set("LESS_EQUAL")
    for name, nodes in groups:
        nodes = np.asarray(nodes, np.int64)
        corners = boxes.box_corners(hlod.box_min[nodes][:, None], hlod.box_max[nodes][:, None])  # (n, 8, 3)
        lines = corners[:, edges.ravel()].reshape(-1, 3).astype(np.float32)
        batch = batch_for_shader(shader, "LINES", {"pos": lines})
        shader.uniform_float("color", BOX_COLOURS[name])
        batch.draw(shader)
    gpu.state.depth_test_set("NONE")
