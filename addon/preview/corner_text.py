"""The preview's statistics in the viewport's corner: a few lines of text drawn with blf in a
POST_PIXEL draw handler, in region pixels (origin bottom left), bottom left of the region, above
its margin and right of an overlapping toolbar.

Lines (top to bottom): the method and what it drew (nodes, triangles and their share of the
sources' triangles), the queries and the last frame's milliseconds (of which reading and importing
Blender's depth, in the modes that import it) and where the queries ran when not in Blender's
context, while the method's queries are off (they culled less than they cost) why, under a GPU
budget the node
geometry on the GPU and the nodes waiting for theirs, then a warning when sources changed since
the bake or the file has no record of them.
"""
from __future__ import annotations

FONT_ID = 0  # Blender's built-in UI font
FONT_SIZE_PX = 12.0  # at a UI scale of 1
MARGIN_PX = 12.0
LINE_SPACING = 1.45  # line pitch over the font size
TEXT_COLOUR = (1.0, 1.0, 1.0, 0.95)
WARNING_COLOUR = (1.0, 0.75, 0.2, 1.0)
SHADOW_COLOUR = (0.0, 0.0, 0.0, 0.9)
SHADOW_BLUR = 3  # blf.shadow levels: 0, 3, 5 (6: outline, 5.x)

METHOD_LABELS = {"coh": "Coh", "sw": "SW", "simp": "Simp", "bool": "Bool", "vfc": "VFC", "full": "Full"}
BIASED = {"coh", "sw", "simp"}  # the methods that take the bias P or mu


def method_label(method: str, bias: str) -> str:
    """The report's names: Coh(P), SW(mu), Bool, ..."""
    label = METHOD_LABELS.get(method, method)
    return f"{label}({bias})" if method in BIASED else label


def stale_message(changed: int, total: int) -> str:
    """The panel's and the corner's words for sources changed since the bake."""
    return f"{changed} of {total} baked objects changed since the bake"


def corner_lines(*, label: str, stats, source_tris: int, where: str,
                 changed: int | None, recorded: int, budget_bytes: int = 0) -> list[tuple[str, bool]]:
    """(text, is_warning) per line. stats: the last FrameStats or None; source_tris: triangles
    the bake took; where: where the queries ran ("" in Blender's context, else the mode's words:
    "private context", "CPU occlusion test"); changed: baked objects changed since the bake (None: not tracked);
    recorded: baked objects on record (0: the file's sources are not recorded); budget_bytes: the
    GPU budget for node geometry and textures (0: unlimited, no line about it; the line's resident
    MB counts both)."""
    if stats is None:
        lines = [(f"HLOD {label}: no frame drawn yet", False)]
    else:
        share = f" ({stats.tris / source_tris:.1%} of {source_tris:,})" if source_tris > 0 else ""
        depth = f" (depth {stats.depth_import_ms:.1f} ms)" if stats.depth_import_ms else ""
        timing = f"{stats.queries:,} queries, {stats.frame_ms:.1f} ms{depth}" + (f", {where}" if where else "")
        lines = [(f"HLOD {label}: {stats.dn:,} nodes, {stats.tris:,} triangles{share}", False), (timing, False)]
        if stats.queries_off:
            lines.append((stats.queries_note, False))
        if budget_bytes:
            waiting = f", {stats.waiting:,} nodes waiting" if stats.waiting else ""
            lines.append((f"GPU {stats.resident_bytes / 2**20:.1f} of {budget_bytes / 2**20:.0f} MB{waiting}", False))
    if recorded == 0:
        lines.append(("sources not recorded for this file: they stay visible (re-bake)", True))
    elif changed:
        lines.append((stale_message(changed, recorded), True))
    return lines


def toolbar_width_px(context) -> float:
    """Width of the toolbar where it overlaps the region (Region Overlap on), else 0."""
    if context.area is None or not context.preferences.system.use_region_overlap:
        return 0.0
    return float(next((r.width for r in context.area.regions if r.type == "TOOLS"), 0))


def effective_ui_scale(preferences) -> float:
    """The effective UI scale (display DPI and the Resolution Scale preference); the bpy module,
    with no window, leaves the effective one at 0: then the preference alone."""
    return float(preferences.system.ui_scale or preferences.view.ui_scale or 1.0)


def draw(lines: list[tuple[str, bool]], *, left_px: float = 0.0, ui_scale: float = 1.0) -> None:
    """Draw `lines` at the bottom left of the bound pixel-space projection (POST_PIXEL's)."""
    import blf  # Blender's; the formatting above runs without it

    size = FONT_SIZE_PX * ui_scale
    blf.size(FONT_ID, size)
    blf.enable(FONT_ID, blf.SHADOW)
    blf.shadow(FONT_ID, SHADOW_BLUR, *SHADOW_COLOUR)
    blf.shadow_offset(FONT_ID, 1, -1)
    try:
        x, y = left_px + MARGIN_PX * ui_scale, MARGIN_PX * ui_scale
        for text, warning in reversed(lines):  # bottom line first
            blf.color(FONT_ID, *(WARNING_COLOUR if warning else TEXT_COLOUR))
            blf.position(FONT_ID, x, y, 0.0)
            blf.draw(FONT_ID, text)
            y += size * LINE_SPACING
    finally:
        blf.disable(FONT_ID, blf.SHADOW)
