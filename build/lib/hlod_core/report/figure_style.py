"""The look shared by the report's figures: sizes, fonts, one colour, dash pattern and marker per
method and sweep point, and the helpers every figure uses (matplotlib loaded on first use, method
names as shown, atomic PNG writing, a frozen layout, padded axis ranges).

Data form: method keys are evaluate.METHOD_SPECS' ("coh_p"), sweep points "coh_p tau=2"; styles
are matplotlib keyword arguments.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.atomic import atomic_file

DPI = 110
GRID_ALPHA = 0.3  # opacity of the grid lines
LINE_WIDTH_PT = 1.3
FONT_PT = 8.5  # point labels, legends, part names
BAR_LABEL_PT = 7.5
TITLE_CHARS = 105  # a wide figure's title wraps at this many characters a line (9.5 pt on 10 in)
# key -> (colour, dash pattern in points (None: solid), marker): all three differ between methods
METHOD_STYLES = {
    "coh_p": ("#d62728", None, "*"),
    "sw_p": ("#ff7f0e", (6, 2), "^"),
    "bool": ("#1f77b4", (6, 2, 1, 2), "o"),
    "ideal": ("#2ca02c", (1, 1.5), "X"),
    "coh_mu": ("#9467bd", (3, 1), "P"),
    "sw_mu": ("#8c564b", (8, 2, 2, 2, 2, 2), "<"),
    "simp_p": ("#bcbd22", (2, 2), "D"),
    "simp_mu": ("#17becf", (10, 3), "d"),
    "coh_p_alg4": ("#e377c2", (4, 1, 1, 1, 1, 1), "h"),
    "vfc": ("#7f7f7f", (12, 2, 3, 2), "v"),
    "full": ("#000000", (1, 3), "s"),
}
# sweep points, in the sweep's order (at most four values per sweep)
SWEEP_STYLES = (("#800000", (6, 1, 1, 1), "p"), ("#b8860b", (3, 3), ">"), ("#000080", (7, 2, 1, 2, 1, 2), "H"),
                ("#008080", (9, 1), "8"))
RANGE_MARGIN = 0.08  # fraction of a data range added on each side


def pyplot():
    """matplotlib.pyplot on the Agg backend (imported here, on first use: Blender's Python has no
    matplotlib)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def style(key: str, sweep_keys: list[str] = ()) -> dict:
    """Colour, dash pattern and marker of a method key (METHOD_STYLES) or of a sweep point (its
    place in `sweep_keys`), as matplotlib keyword arguments."""
    if key in METHOD_STYLES:
        colour, dashes, marker = METHOD_STYLES[key]
    else:
        colour, dashes, marker = SWEEP_STYLES[list(sweep_keys).index(key) % len(SWEEP_STYLES)]
    return {"color": colour, "linestyle": "-" if dashes is None else (0, dashes), "marker": marker}


def sweep_keys(report: dict) -> list[str]:
    """The report's sweep points, in the sweep's order (empty without a sweep)."""
    return list(report["sweep"]["points"]) if report.get("sweep") else []


def display_name(key: str, labels: dict[str, str]) -> str:
    """A method's label, or a sweep point's ("coh_p s,t=0.6,0.2" -> "Coh(P) s,t=0.6,0.2")."""
    if key in labels:
        return labels[key]
    method, _, value = key.partition(" ")
    return f"{labels.get(method, method)} {value}".strip()


def save(fig, target: Path) -> str:
    """Write `fig` as PNG at DPI (atomically), close it; the file's name."""
    plt = pyplot()
    with atomic_file(target) as f:
        fig.savefig(f, format="png", dpi=DPI)
    plt.close(fig)
    return Path(target).name


def frozen_layout(fig):
    """Run the figure's constrained layout once and keep it: label placement works in the display
    pixels of the final layout. Returns the renderer."""
    fig.canvas.draw()
    fig.set_layout_engine("none")
    return fig.canvas.get_renderer()


def padded_range(values: np.ndarray, margin: float) -> tuple[float, float]:
    """(low, high) of `values` widened by `margin` times their span on each side (a span of 0 counts
    as the largest magnitude, or 1)."""
    lo, hi = float(np.min(values)), float(np.max(values))
    span = hi - lo if hi > lo else max(abs(hi), 1.0)
    return lo - margin * span, hi + margin * span
