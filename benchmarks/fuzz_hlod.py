"""Fuzz the .hlod reader: seeded mutations of a small baked file, each opened, summarised, checked
and, when it opens, rendered, in a worker process, so that a crash (signal), a hang or a traceback
is caught and named with the case that causes it.

    python -m benchmarks.fuzz_hlod [--cases N] [--seed S] [--case I] [--timeout SECONDS]
                                   [--keep DIR] [--out FILE.json]

The run is the test suite's (tests/test_fuzz.py), with more cases: the base file and the mutation
kinds are tests/hlod_mutations.py's, the worker and what counts as a failure tests/hlod_fuzz.py's.
Case i of seed S depends on (S, i) alone, so `--seed S --case I` reproduces one case. The last
line of stdout is one JSON summary; failures go to stderr; the exit status is 1 if any case failed.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from hlod_fuzz import fuzz  # the fuzz run, a test helper

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=300, help="mutated files to try")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--case", type=int, action="append", help="run only this case (repeatable)")
    parser.add_argument("--timeout", type=float, default=60.0, help="seconds one case may take")
    parser.add_argument("--keep", type=Path, help="write failing cases' files into this folder")
    parser.add_argument("--out", type=Path, help="also write the summary JSON here")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr, format="fuzz_hlod: %(message)s")
    logging.getLogger("hlod_core").setLevel(logging.WARNING)  # the base bake's progress
    result = fuzz(cases=args.case or list(range(args.cases)), seed=args.seed, timeout_s=args.timeout,
                  keep=args.keep)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=2))
    print(json.dumps(result))
    return 1 if result["failed"] else 0


if __name__ == "__main__":
    sys.exit(main())
