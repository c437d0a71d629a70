"""Which evaluation targets an evaluation report meets (the targets are acceptance thresholds,
not product behaviour: the report itself holds only measured figures).

    .venv/bin/python -m benchmarks.evaluation_targets DIR/report.json [--strict]

Reads the report.json that `python -m hlod_core evaluate` writes (a folder holding one works too),
checks it against the targets of tests/report_targets.py,
prints one JSON line per target ({"target", "value", "holds"}), a Markdown table, and a last JSON
line {"targets_hold": bool}. --strict exits with status 1 when a target fails or cannot be
measured. Needs the methods coh_p, sw_p and bool in the report.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from report_targets import read_report, targets  # the targets, a test helper

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("report", help="report.json of an evaluation, or its folder")
    parser.add_argument("--strict", action="store_true", help="exit 1 unless every target holds")
    args = parser.parse_args(argv)
    try:
        rows = targets(read_report(args.report)["methods"])
    except ValueError as exc:
        print(f"evaluation_targets: {exc}", file=sys.stderr)
        return 2
    for row in rows:
        print(json.dumps(row))
    print("| target | measured | holds |")
    print("|---|---:|---|")
    for row in rows:
        value = "–" if row["value"] is None else f"{row['value']:.3f}"
        print(f"| {row['target']} | {value} | {'yes' if row['holds'] else '**no**'} |")
    holds = all(row["holds"] for row in rows)
    print(json.dumps({"targets_hold": holds}))
    return 1 if args.strict and not holds else 0


if __name__ == "__main__":
    sys.exit(main())
