"""The evaluation targets (acceptance thresholds, not product behaviour: a report holds only
measured figures) and which of them an evaluation report meets. benchmarks/evaluation_targets.py
prints them for a report.json; tests/test_evaluate.py checks them on a real report and on literal
figures."""
from __future__ import annotations

import operator
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from hlod_core.core import jsonutil
from hlod_core.core.errors import InputError

NEEDED_METHODS = ("coh_p", "sw_p", "bool")


def _ratio(a: float, b: float, *, when_zero: float | None = None) -> float | None:
    return a / b if b else when_zero


@dataclass(frozen=True)
class Target:
    """`measure(methods) compare threshold`, e.g. DN Coh(P) / SW(P) <= 1.02."""

    name: str
    compare: str  # "<=", "<" or ">="
    threshold: float
    measure: Callable[[dict], float | None]  # report["methods"] -> the measured value (None: not measurable)
    unit: str = ""  # written after the threshold: "%", " dB"

    @property
    def label(self) -> str:
        return f"{self.name} {self.compare} {self.threshold:g}{self.unit}"


_COMPARE = {"<=": operator.le, "<": operator.lt, ">=": operator.ge}

TARGETS = (
    Target("DN Coh(P) / SW(P)", "<=", 1.02, lambda m: _ratio(m["coh_p"]["dn"], m["sw_p"]["dn"])),
    Target("DN Coh(P) / Bool", "<=", 0.85, lambda m: _ratio(m["coh_p"]["dn"], m["bool"]["dn"])),
    # percent; no drawn node means no RARN either
    Target("RARN / DN of Coh(P)", "<=", 0.5,
           lambda m: 100 * _ratio(m["coh_p"]["rarn"], m["coh_p"]["dn"], when_zero=0.0), unit="%"),
    Target("PSNR-Y Coh(P) vs Bool", ">=", 34.0, lambda m: m["coh_p"]["psnr_y_vs_bool"], unit=" dB"),
    Target("frame ms Coh(P) / Bool", "<", 1.0, lambda m: _ratio(m["coh_p"]["frame_ms"], m["bool"]["frame_ms"])),
    Target("frame ms Coh(P) / SW(P)", "<", 1.0, lambda m: _ratio(m["coh_p"]["frame_ms"], m["sw_p"]["frame_ms"])),
    # SW(P) never stalled: Coh(P) cannot do worse than that ratio's ideal, 0
    Target("stall ms Coh(P) / SW(P)", "<=", 0.2,
           lambda m: _ratio(m["coh_p"]["stall_ms"], m["sw_p"]["stall_ms"], when_zero=0.0)),
)


def targets(methods: dict) -> list[dict]:
    """Each target with its measured value and whether it holds (None when it cannot be measured).
    `methods`: report["methods"], which must hold NEEDED_METHODS."""
    missing = [m for m in NEEDED_METHODS if m not in methods]
    if missing:
        raise ValueError(f"the report lacks method(s) {', '.join(missing)} (the targets need "
                         f"{', '.join(NEEDED_METHODS)})")
    rows = []
    for t in TARGETS:
        value = t.measure(methods)
        holds = None if value is None else bool(_COMPARE[t.compare](value, t.threshold))
        rows.append({"target": t.label, "value": value, "holds": holds})
    return rows


def read_report(path: str | Path) -> dict:
    """report.json at `path` (or in the folder `path`); ValueError naming the file when unreadable."""
    path = Path(path)
    if path.is_dir():
        path = path / "report.json"
    try:
        report = jsonutil.read(path, what="the evaluation report")
    except InputError as exc:
        raise ValueError(str(exc)) from None
    if not isinstance(report, dict) or not isinstance(report.get("methods"), dict):
        raise ValueError(f"{path}: not an evaluation report (no \"methods\" table)")
    return report
