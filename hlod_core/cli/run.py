"""The `run` and `evaluate` commands: traversal methods over a camera path through a .hlod, drawn
with OpenGL (report.runner, report.evaluate; `evaluate --psnr-target`: report.tuning)."""
from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from ..core.errors import InputError
from ..export.formats import check_output_file
from ..io import hlod_file
from .options import (
    gpu_budget_option,
    parse_size,
    psnr_db,
    runtime_options,
    runtime_settings_of,
    streaming_of,
    whole_number,
)

log = logging.getLogger("hlod_core")

METHODS = ["full", "vfc", "bool", "sw", "simp", "coh", "ideal"]


def add_run(sub) -> None:
    """The `run` command's parser, on the subparsers `sub`."""
    p = sub.add_parser("run", help="run a traversal method over a camera path; print per-frame means")
    p.add_argument("file", metavar="FILE.hlod")
    p.add_argument("--method", required=True, choices=METHODS)
    p.add_argument("--bias", choices=["P", "mu"], default="P",
                   help="P = P_{s,t}(mu); mu = the visibility itself (s = 0)")
    runtime_options(p)
    p.add_argument("--path", metavar="PATH.json", help="camera path file (docs/command-line.md#camera-paths)")
    p.add_argument("--seed", type=whole_number(0), default=1,
                   help="seed of a generated inspection path (without --path)")
    p.add_argument("--frames", type=whole_number(1), default=60, help="frames of a generated path")
    p.add_argument("--size", default="640x480", help="viewport WxH pixels")
    p.add_argument("--save-frames", metavar="DIR", help="write every frame as PNG")
    p.add_argument("--save-path", metavar="PATH.json", help="write the camera path used")
    gpu_budget_option(p)
    p.add_argument("--compare-unlimited", action="store_true",
                   help="also draw each frame without a GPU budget; report the median PSNR-Y against those "
                        "frames after the tenth (psnr_y_vs_unlimited_median)")
    p.set_defaults(run=run_command)


def add_evaluate(sub) -> None:
    """The `evaluate` command's parser, on the subparsers `sub`."""
    p = sub.add_parser("evaluate", help="all methods on one camera path: report.json, report.md, figures")
    p.add_argument("file", metavar="FILE.hlod")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for report.json, report.md and PNGs")
    p.add_argument("--path", metavar="PATH.json", help="camera path file (docs/command-line.md#camera-paths)")
    p.add_argument("--seed", type=whole_number(0), default=1,
                   help="seed of a generated inspection path and of the PSNR frames")
    p.add_argument("--frames", type=whole_number(1), default=60, help="frames of a generated path")
    p.add_argument("--size", default="640x480", help="viewport WxH pixels")
    p.add_argument("--methods", nargs="+", default=None, metavar="M",
                   help="report keys (default all): full vfc bool sw_p sw_mu simp_p simp_mu coh_p coh_mu ideal")
    runtime_options(p)
    p.add_argument("--repeat", type=whole_number(1), default=2, help="passes over the path, order alternating")
    p.add_argument("--sweep", choices=["tau", "st", "alpha"], help="add Coh(P) at each value of one parameter")
    p.add_argument("--psnr-frames", type=whole_number(1), default=20, help="seeded random frames compared by PSNR")
    p.add_argument("--psnr-target", type=psnr_db, metavar="DB",
                   help="instead of the methods: find the (s, t) with the fewest drawn nodes whose PSNR-Y against Bool "
                        "stays >= DB at every PSNR frame (Bool and Coh(P) candidates only; "
                        "docs/how-it-works.md#tuning-s-and-t-to-a-psnr-target)")
    gpu_budget_option(p)
    p.set_defaults(run=evaluate_command)


def _runtime_setup(args: argparse.Namespace, *, bias: str = "P"):
    """(hlod, settings, path, size) of the run and evaluate commands, validated before any GL work."""
    from ..model.camera_path import inspection_path, load_path

    size = parse_size(args.size)
    settings = runtime_settings_of(args, bias=bias)  # raises InputError
    hlod = hlod_file.load(args.file)
    path = load_path(args.path) if args.path else inspection_path(hlod, seed=args.seed, frames=args.frames)
    return hlod, settings, path, size


def run_command(args: argparse.Namespace) -> dict:
    """`run`: the per-frame means of one method's counters (report.runner.run_path)."""
    from ..report.runner import run_path

    if args.save_path:
        check_output_file(args.save_path, "--save-path", "path.json")
    streaming = streaming_of(args)
    started = time.perf_counter()  # first_frame_ms counts the file's opening
    hlod, settings, path, size = _runtime_setup(args, bias=args.bias)
    if args.save_path:
        path.save(args.save_path)
    if args.compare_unlimited:
        started = None  # the unlimited pass runs first: the first frame counts from the renderer's creation
    out = run_path(hlod, args.method, settings, path=path, size=size, save_frames=args.save_frames,
                   streaming=streaming, compare_unlimited=args.compare_unlimited, started_s=started)
    out.update(method=args.method, bias=args.bias, size=list(size), alpha=args.alpha, tau=args.tau)
    return out


def evaluate_command(args: argparse.Namespace) -> dict:
    """`evaluate`: the methods' report in --out (report.evaluate), or with --psnr-target the (s, t) search."""
    from ..report import evaluate

    methods = args.methods or list(evaluate.METHOD_SPECS)
    unknown = [m for m in methods if m not in evaluate.METHOD_SPECS]
    if unknown:
        raise InputError(f"--methods: unknown {', '.join(unknown)}; "
                         f"expected some of {', '.join(evaluate.METHOD_SPECS)}")
    out_dir = Path(args.out)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"--out {out_dir}: is a file, expected a folder")
    if args.psnr_target is not None:
        return _tune(args, out_dir)
    hlod, settings, path, size = _runtime_setup(args)
    report = evaluate.evaluate(hlod, path, size, methods=methods, settings=settings, repeat=args.repeat,
                               sweep=args.sweep, out_dir=out_dir, psnr_frames=args.psnr_frames, seed=args.seed,
                               streaming=streaming_of(args))
    log.info("report: %s", out_dir / "report.md")
    return evaluate.summary_line(report, out_dir)


def _tune(args: argparse.Namespace, out_dir: Path) -> dict:
    """evaluate --psnr-target: the (s, t) search (report.tuning) instead of the methods."""
    from ..report import evaluate, tuning

    given = [name for name, value in (("--methods", args.methods), ("--sweep", args.sweep)) if value]
    if given:
        raise InputError(f"--psnr-target runs Bool and the Coh(P) candidates only; leave out {' and '.join(given)} "
                         "(evaluate the chosen --s and --t without --psnr-target for the other methods)")
    hlod, settings, path, size = _runtime_setup(args)
    report = tuning.tune(hlod, path, size, target_db=args.psnr_target, settings=settings, repeat=args.repeat,
                         out_dir=out_dir, psnr_frames=args.psnr_frames, seed=args.seed, streaming=streaming_of(args))
    log.info("report: %s", out_dir / "report.md")
    return evaluate.summary_line(report, out_dir) | {"psnr_target": tuning.summary(report)}
