"""The pictures of the docs pages (docs/images/), drawn from the code they show:

    .venv/bin/python scripts/docs_pictures.py [--out docs/images] [--only legend|panel]

- `overlay_legend.png`: the modulation overlay's colour ramp (hlod_core.core.colour, sRGB-encoded as
  the renderer encodes it) over m = 1 - P_{s,t}(mu), with weak / moderate / strong, and m against the
  visible share mu of a node's box at the default (s, t) (matplotlib only).
- `panel_<section>.png`: a diagram of each section of the 3D viewport's sidebar tab "HLOD". Blender's
  UI cannot be screenshotted headless, so each Panel's own `draw()` runs in the bpy module with a
  recording stand-in for `self.layout` (labels, properties, operators, rows and columns, in order);
  the labels, values and greyed-out states are the registered properties' and operators' own, in a
  new scene (nothing baked, preview off). The picture says that it is a diagram.

The other pictures of the docs come from their own scripts: docs/preview_in_place.png
(scripts/preview_in_place.py), docs/viewer.png and docs/viewer_depth.png (scripts/viewer_screenshot.py),
docs/evaluation/*.png (`python -m hlod_core evaluate`, see docs/evaluation.md).
"""
from __future__ import annotations

import argparse
import importlib.util
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

PACKAGE = "hlod_docs"  # the add-on imported from this folder under this name
PANEL_WIDTH_PX = 300
ROW_PX = 22
SCALE = 2.0  # pixels of the picture per diagram pixel

ICON_GLYPHS = {"X": "\u2715", "CANCEL": "\u2715"}  # icon-only buttons: a glyph for the icon
# Blender's default dark theme, approximately
THEME = {"back": "#303030", "header": "#3d3d3d", "widget": "#545454", "widget_on": "#4772b3",
         "text": "#e6e6e6", "tab": "#1d1d1d", "caption": "#9a9a9a"}


# --- the overlay legend -------------------------------------------------------------------------

def draw_legend(out_dir: Path) -> Path:
    """overlay_legend.png: the ramp with its three names, and m(mu) at the default s, t."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hlod_core.cli.main import build_parser
    from hlod_core.core.colour import modulation_colour, srgb_from_linear
    from hlod_core.traversal.metrics import bias

    m = np.linspace(0.0, 1.0, 512)
    ramp = srgb_from_linear(modulation_colour(m))  # (512, 3) as the renderer writes it to the screen
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(6.4, 4.2), dpi=150, gridspec_kw={"height_ratios": [1, 2.2]})
    top.imshow(ramp[None, :, :], aspect="auto", extent=(0.0, 1.0, 0.0, 1.0))
    top.set_yticks([])
    top.set_xticks([0.0, 0.5, 1.0], ["0\nweak", "0.5\nmoderate", "1\nstrong"])
    top.set_title("Modulation overlay: a node's colour shows m = 1 - P, how much occlusion raised its "
                  "allowed error", fontsize=8.5)
    defaults = build_parser().parse_args(["run", "FILE.hlod", "--method", "coh"])  # the command line's s, t
    s, t = defaults.s, defaults.t
    mu = np.linspace(0.0, 1.0, 1001)
    modulation = 1.0 - bias(mu, s, t)
    bottom.scatter(mu, modulation, c=srgb_from_linear(modulation_colour(modulation)), s=4, linewidths=0)
    bottom.set_xlabel("mu: visible share of the node's box (occlusion query q / alpha)", fontsize=8)
    bottom.set_ylabel("m = 1 - P(mu)", fontsize=8)
    bottom.set_title(f"At the defaults s = {s:g}, t = {t:g}: a node less than {t:.0%} visible is modulated "
                     "strongly, a visible one weakly", fontsize=8)
    bottom.set_xlim(0, 1)
    bottom.set_ylim(-0.02, 1.02)
    bottom.tick_params(labelsize=7)
    top.tick_params(labelsize=7.5)
    bottom.grid(alpha=0.3)
    fig.tight_layout()
    path = out_dir / "overlay_legend.png"
    fig.savefig(path)
    plt.close(fig)
    return path


# --- the panel diagram: a recording stand-in for bpy.types.UILayout ----------------------------

@dataclass
class Item:
    """One thing a draw() call put in the layout. kind: label, prop, operator, progress, separator;
    widget (props): check, number, menu, text, pointer."""

    kind: str
    text: str = ""
    value: str = ""
    widget: str = ""
    on: bool = False


class _OperatorProperties:
    """What `layout.operator()` returns: draw code sets the operator's properties on it."""

    def __setattr__(self, name, value):
        object.__setattr__(self, name, value)


@dataclass
class RecordingLayout:
    """Stand-in for bpy.types.UILayout: records what a Panel's draw() puts in it, in order. Only the
    calls the panels make are here; any other raises AttributeError, naming it."""

    horizontal: bool = False
    enabled: bool = True
    active: bool = True
    children: list = field(default_factory=list)
    use_property_split: bool = False
    use_property_decorate: bool = False
    alignment: str = "EXPAND"

    def row(self, *, align: bool = False, heading: str = "", **_) -> "RecordingLayout":
        return self._nest(horizontal=True)

    def column(self, *, align: bool = False, heading: str = "", **_) -> "RecordingLayout":
        return self._nest(horizontal=False)

    def box(self) -> "RecordingLayout":
        return self._nest(horizontal=False)

    def _nest(self, *, horizontal: bool) -> "RecordingLayout":
        child = RecordingLayout(horizontal=horizontal)
        self.children.append(child)
        return child

    def label(self, *, text: str = "", icon: str = "NONE", **_) -> None:
        self.children.append(Item("label", text=text))

    def separator(self, **_) -> None:
        self.children.append(Item("separator"))

    def progress(self, *, factor: float = 0.0, type: str = "BAR", text: str = "") -> None:  # noqa: A002 - Blender's UILayout.progress
        self.children.append(Item("progress", text=text, value=f"{factor:.0%}"))

    def operator(self, idname: str, *, text: str | None = None, icon: str = "NONE", depress: bool = False,
                 **_) -> _OperatorProperties:
        import bpy

        if text is None:
            category, name = idname.split(".")
            text = getattr(getattr(bpy.ops, category), name).get_rna_type().name
        self.children.append(Item("operator", text=text or ICON_GLYPHS.get(icon, icon), on=depress))
        return _OperatorProperties()

    def prop(self, data, name: str, *, text: str | None = None, **_) -> None:
        self.children.append(_prop_item(data, name, text))


def _prop_item(data, name: str, text: str | None) -> Item:
    """The widget Blender draws for property `name` of `data`, with its current value."""
    rna = data.bl_rna.properties[name]
    label = rna.name if text is None else text
    value = getattr(data, name)
    if rna.type == "BOOLEAN":
        return Item("prop", text=label, widget="check", on=bool(value))
    if rna.type == "ENUM":
        shown = next((i.name for i in rna.enum_items if i.identifier == value), str(value))
        return Item("prop", text=label, value=shown, widget="menu")
    if rna.type == "INT":
        return Item("prop", text=label, value=f"{value}", widget="number")
    if rna.type == "FLOAT":
        return Item("prop", text=label, value=f"{value:.{max(int(rna.precision), 0)}f}", widget="number")
    if rna.type == "POINTER":
        return Item("prop", text=label, value=value.name if value is not None else "", widget="pointer")
    return Item("prop", text=label, value=str(value), widget="text")


def _flatten(layout: RecordingLayout, dim: bool = False) -> list:
    """Rows to draw: each a list of (Item, dim) side by side; columns stack their rows."""
    dim = dim or not (layout.enabled and layout.active)
    rows: list = []
    if layout.horizontal:
        cells = []
        for child in layout.children:
            if isinstance(child, RecordingLayout):
                for row in _flatten(child, dim):
                    cells.extend(row)
            else:
                cells.append((child, dim))
        return [cells] if cells else []
    for child in layout.children:
        if isinstance(child, RecordingLayout):
            rows.extend(_flatten(child, dim))
        else:
            rows.append([(child, dim)])
    return rows


def record_panels() -> list[tuple[str, list]]:
    """(section label, rows) of every panel of the sidebar tab HLOD, the main panel first: each
    Panel's draw() run on a RecordingLayout, in the bpy module, the add-on registered from this
    folder."""
    import bpy

    spec = importlib.util.spec_from_file_location(PACKAGE, ROOT / "__init__.py", submodule_search_locations=[str(ROOT)])
    package = importlib.util.module_from_spec(spec)
    sys.modules[PACKAGE] = package
    spec.loader.exec_module(package)
    package.register()
    try:
        panels = [c for c in _all_subclasses(bpy.types.Panel)
                  if c.__module__.startswith(PACKAGE) and getattr(c, "bl_category", "") == "HLOD"]
        sections = []
        for cls in sorted(panels, key=lambda c: getattr(c, "bl_parent_id", "") != ""):  # stable: main first
            stand_in = type("Drawn", (), {"layout": RecordingLayout()})()
            cls.draw(stand_in, bpy.context)
            sections.append((cls.bl_label, _flatten(stand_in.layout)))
        return sections
    finally:
        package.unregister()


def _all_subclasses(cls) -> list:
    out = []
    for sub in cls.__subclasses__():
        out.append(sub)
        out.extend(_all_subclasses(sub))
    return out


def draw_panel(title: str, rows: list, path: Path, *, header_rows: list | None = None) -> Path:
    """A mock-up of one panel section (its header, then its rows), captioned as a diagram."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyBboxPatch, Rectangle

    header_rows = header_rows or []
    lines = 1 + (1 + len(header_rows) if header_rows else 0) + 1 + len(rows) + 1  # tab, main, section, caption
    height = lines * ROW_PX + 14
    fig = plt.figure(figsize=(PANEL_WIDTH_PX * SCALE / 100, height * SCALE / 100), dpi=100)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_xlim(0, PANEL_WIDTH_PX)
    ax.set_ylim(height, 0)
    ax.axis("off")
    ax.add_patch(Rectangle((0, 0), PANEL_WIDTH_PX, height, color=THEME["back"]))
    y = 4.0

    def text(x, yy, s, *, dim=False, bold=False, size=7.2, ha="left", colour=None):
        ax.text(x, yy, s, color=colour or THEME["text"], alpha=0.45 if dim else 1.0, fontsize=size * SCALE / 2,
                fontweight="bold" if bold else "normal", ha=ha, va="center", clip_on=True)

    def header(yy, label):
        ax.add_patch(Rectangle((4, yy), PANEL_WIDTH_PX - 8, ROW_PX - 2, color=THEME["header"]))
        text(10, yy + ROW_PX / 2 - 1, "\u25be  " + label, bold=True)

    def widget(x, yy, w, item: Item, dim: bool):
        box = dict(boxstyle="round,pad=0,rounding_size=3", linewidth=0)
        h = ROW_PX - 5
        mid = yy + ROW_PX / 2 - 1
        if item.kind == "label":
            text(x + 2, mid, item.text, dim=dim)
        elif item.kind == "separator":
            pass
        elif item.kind == "progress":
            ax.add_patch(FancyBboxPatch((x, yy + 2), w, h, color=THEME["widget"], **box))
            text(x + w / 2, mid, item.text or item.value, dim=dim, ha="center")
        elif item.kind == "operator":
            ax.add_patch(FancyBboxPatch((x, yy + 2), w, h, color=THEME["widget_on" if item.on else "widget"],
                                        alpha=0.5 if dim else 1.0, **box))
            text(x + w / 2, mid, item.text, dim=dim, ha="center")
        elif item.widget == "check":
            ax.add_patch(FancyBboxPatch((x + 2, yy + 5), 11, 11, color=THEME["widget_on" if item.on else "widget"],
                                        alpha=0.5 if dim else 1.0, **box))
            if item.on:
                text(x + 7.5, mid, "\u2713", size=6.5, ha="center", dim=dim)
            text(x + 18, mid, item.text, dim=dim)
        elif item.widget == "number":
            ax.add_patch(FancyBboxPatch((x, yy + 2), w, h, color=THEME["widget"], alpha=0.5 if dim else 1.0, **box))
            text(x + 6, mid, item.text, dim=dim)
            text(x + w - 6, mid, item.value, dim=dim, ha="right")
        else:  # menu, text, pointer: the label left of a field
            split = x + min(w * 0.42, 110)
            text(x + 2, mid, item.text + ":", dim=dim)
            ax.add_patch(FancyBboxPatch((split, yy + 2), x + w - split, h, color=THEME["widget"],
                                        alpha=0.5 if dim else 1.0, **box))
            shown = item.value + ("  \u25be" if item.widget == "menu" else "")
            text(split + 5, mid, shown, dim=dim)

    def draw_rows(yy, items):
        for row in items:
            width = (PANEL_WIDTH_PX - 24) / max(len(row), 1)
            for i, (item, dim) in enumerate(row):
                widget(12 + i * width, yy, width - 3, item, dim)
            yy += ROW_PX
        return yy

    ax.add_patch(Rectangle((0, 0), PANEL_WIDTH_PX, ROW_PX, color=THEME["tab"]))
    text(8, ROW_PX / 2, "3D Viewport > Sidebar (N) > HLOD", colour=THEME["caption"])
    y = ROW_PX + 4
    if header_rows:
        header(y, "HLOD")
        y = draw_rows(y + ROW_PX, header_rows)
    header(y, title)
    y = draw_rows(y + ROW_PX, rows) + 6
    text(PANEL_WIDTH_PX / 2, y + ROW_PX / 2, "Diagram drawn from the panel's draw code, not a screenshot",
         colour=THEME["caption"], size=6.3, ha="center")
    fig.savefig(path, facecolor=THEME["back"])
    plt.close(fig)
    return path


def draw_panels(out_dir: Path) -> list[Path]:
    """panel_<section>.png for each section under the main panel (the main panel's own lines on top
    of the first)."""
    sections = record_panels()
    (_, main_rows), children = sections[0], sections[1:]
    paths = []
    for i, (label, rows) in enumerate(children):
        path = out_dir / f"panel_{label.lower().replace(' ', '_')}.png"
        paths.append(draw_panel(label, rows, path, header_rows=main_rows if i == 0 else None))
    return paths


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Draw the docs' pictures into docs/images/.")
    parser.add_argument("--out", default=str(ROOT / "docs" / "images"), help="folder (default docs/images)")
    parser.add_argument("--only", choices=["legend", "panel"], help="draw one kind only")
    args = parser.parse_args(argv)
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    if args.only in (None, "legend"):
        written.append(draw_legend(out_dir))
    if args.only in (None, "panel"):
        written.extend(draw_panels(out_dir))
    for path in written:
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
