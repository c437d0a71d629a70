"""Command line of the core: `python -m hlod_core COMMAND ...`.

Contract (later checks rely on it): the last line of stdout is one JSON object; progress and
messages go to stderr (-q: errors only); bad input, a bad argument or a failed write exits with
status 2 and one line naming the file and the fault. Ctrl-C exits 130 with `hlod_core:
interrupted`, SIGTERM / SIGHUP exit 128 + n with `hlod_core: terminated by SIG...`; either way
after removing scratch files and partial outputs. `-o` of a file refuses a name that ends in a
path separator (it names a folder).

    bake INPUT [INPUT ...] -o OUT.hlod [--target-tris 2000] [--max-depth 12] [--jobs N]
              [--cache DIR | --no-cache] [--scheduler ADDRESS [--scratch DIR] [--scheduler-timeout S]]
              [--out-of-core [--scratch DIR] [--chunk-tris N]]
        (images embedded in glTF inputs are written to OUT.textures/ beside OUT.hlod; the bake
        cache, which lets a re-bake redo only what changed, is OUT.hlod.cache/ unless --cache
        names another folder; safe to delete; --scheduler: the decimations and measurements run
        on a Dask cluster's workers, dask_cluster.py, for the same file; --out-of-core: inputs bigger
        than memory, streamed through per-cell scratch files, partition.py, for the same file)
    info FILE.hlod
    scene low|middle|high|default -o OUT.hlod [--seed N] [--scale S] [--jobs N] [--cache DIR | --no-cache]
    run FILE.hlod --method M [...]
    evaluate FILE.hlod --out DIR [...] [--psnr-target DB]
        (--psnr-target: the (s, t) search of hlod_core/report/tuning.py instead of the methods)
    export IN.hlod --format 3dtiles|hlod -o DIR
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import logging
import os
import shutil
import signal
import sys
import time
import warnings
from pathlib import Path

from .bake import cache, checks, partition
from .io import hlod_file, meshes, procedural
from .bake.pipeline import bake, bake_stream
from .bake.settings import ERROR_MEASURES, BakeSettings
from .core.errors import HlodError, InputError
from .export.formats import check_output_file, export_hlod
from .core.signals import Terminated, signals_as_exceptions
from .traversal.settings import BATCH_QUERY_MODES, MULTIQUERY_MODES, PREDICT_NEW_MODES, SKIP_QUERY_MODES, RuntimeSettings

log = logging.getLogger("hlod_core")


def main(argv: list[str] | None = None) -> int:
    """Run one command; returns the exit status: 0, 2 for bad input or a failed write (one line
    on stderr naming the file), 130 for Ctrl-C, 128 + n for signal n (SIGTERM, SIGHUP). Argument
    errors exit 2 through argparse with one line."""
    args = None
    try:
        args = build_parser().parse_args(argv)
        logging.basicConfig(level=logging.ERROR if args.quiet else logging.INFO, stream=sys.stderr,
                            format="hlod_core: %(message)s")
        with warnings.catch_warnings(), signals_as_exceptions():
            warnings.showwarning = _log_warning
            result = args.run(args)
    except HlodError as exc:
        print(f"hlod_core: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        where = exc.filename or _output_of(args)
        print(f"hlod_core: error: {where}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("hlod_core: interrupted", file=sys.stderr)
        return 128 + signal.SIGINT
    except Terminated as exc:
        print(f"hlod_core: terminated by {signal.Signals(exc.signum).name}", file=sys.stderr)
        return 128 + exc.signum
    print(json.dumps(result))
    return 0




def _log_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """warnings.showwarning for a command: one log line (hidden by -q), not the two-line default."""
    log.warning("%s: %s (%s:%d)", category.__name__, message, os.path.basename(filename), lineno)


def _output_of(args) -> str:
    """The file or folder a command writes (for an OSError that names no file)."""
    for name in ("output", "out", "save_path", "save_frames", "file"):
        value = getattr(args, name, None)
        if value is not None:
            return str(value)
    return "hlod_core"


class _Parser(argparse.ArgumentParser):
    """An argument error is one line, `hlod_core: error: ...`, and exit status 2 (argparse's
    default prints the whole usage first). Subcommand parsers are of the same class."""

    def error(self, message: str):
        self.exit(2, f"hlod_core: error: {message} (see {self.prog} --help)\n")


def _whole_number(minimum: int):
    """argparse type: an int >= minimum (a negative --seed reached numpy as a traceback)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected a whole number >= {minimum}, got {value}")
        return value

    return parse


def _psnr_db(text: str) -> float:
    """argparse type of --psnr-target: dB in the range tuning.check_target accepts."""
    from .report.tuning import check_target

    try:
        return check_target(text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("PSNR target: ")) from None


def build_parser() -> argparse.ArgumentParser:
    """The parser of `python -m hlod_core`: every command and option (docs/command-line.md lists them)."""
    parser = _Parser(prog="python -m hlod_core", description="Bake and inspect octree HLODs.")
    parser.add_argument("-q", "--quiet", action="store_true", help="only errors on stderr")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("bake", help="bake mesh files and/or JSON scene specs into one .hlod")
    p.add_argument("inputs", nargs="+", metavar="INPUT", help="OBJ/PLY/STL/GLB file or JSON scene spec")
    p.add_argument("-o", "--output", required=True, metavar="OUT.hlod")
    _bake_options(p)
    _out_of_core_options(p)
    _cluster_options(p)
    p.set_defaults(run=_cmd_bake)

    p = sub.add_parser("info", help="counts and invariant checks of a .hlod file")
    p.add_argument("file", metavar="FILE.hlod")
    p.set_defaults(run=_cmd_info)

    p = sub.add_parser("run", help="run a traversal method over a camera path; print per-frame means")
    p.add_argument("file", metavar="FILE.hlod")
    p.add_argument("--method", required=True, choices=["full", "vfc", "bool", "sw", "simp", "coh", "ideal"])
    p.add_argument("--bias", choices=["P", "mu"], default="P", help="P = P_{s,t}(mu); mu = the visibility itself (s = 0)")
    _runtime_options(p)
    p.add_argument("--path", metavar="PATH.json", help="camera path file (see README)")
    p.add_argument("--seed", type=_whole_number(0), default=1,
                   help="seed of a generated inspection path (without --path)")
    p.add_argument("--frames", type=_whole_number(1), default=60, help="frames of a generated path")
    p.add_argument("--size", default="640x480", help="viewport WxH pixels")
    p.add_argument("--save-frames", metavar="DIR", help="write every frame as PNG")
    p.add_argument("--save-path", metavar="PATH.json", help="write the camera path used")
    p.set_defaults(run=_cmd_run)

    p = sub.add_parser("evaluate", help="all methods on one camera path: report.json, report.md, figures")
    p.add_argument("file", metavar="FILE.hlod")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for report.json, report.md and PNGs")
    p.add_argument("--path", metavar="PATH.json", help="camera path file (see README)")
    p.add_argument("--seed", type=_whole_number(0), default=1,
                   help="seed of a generated inspection path and of the PSNR frames")
    p.add_argument("--frames", type=_whole_number(1), default=60, help="frames of a generated path")
    p.add_argument("--size", default="640x480", help="viewport WxH pixels")
    p.add_argument("--methods", nargs="+", default=None, metavar="M",
                   help="report keys (default all): full vfc bool sw_p sw_mu simp_p simp_mu coh_p coh_mu ideal")
    _runtime_options(p)
    p.add_argument("--repeat", type=_whole_number(1), default=2, help="passes over the path, order alternating")
    p.add_argument("--sweep", choices=["tau", "st", "alpha"], help="add Coh(P) at each value of one parameter")
    p.add_argument("--psnr-frames", type=_whole_number(1), default=20, help="seeded random frames compared by PSNR")
    p.add_argument("--psnr-target", type=_psnr_db, metavar="DB",
                   help="instead of the methods: find the (s, t) with the fewest drawn nodes whose PSNR-Y against Bool "
                        "stays >= DB at every PSNR frame (Bool and Coh(P) candidates only; see README)")
    p.set_defaults(run=_cmd_evaluate)

    p = sub.add_parser("export", help="export a .hlod as 3D Tiles 1.1 (tileset.json + one GLB per node) or .hlod")
    p.add_argument("file", metavar="IN.hlod")
    p.add_argument("--format", choices=["3dtiles", "hlod"], default="3dtiles")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder (replaced atomically)")
    p.set_defaults(run=_cmd_export)

    p = sub.add_parser("view", help="serve a 3D Tiles export and a CesiumJS viewer page on localhost; open the browser")
    p.add_argument("dir", metavar="DIR", help="a 3D Tiles export folder (holding tileset.json)")
    p.add_argument("--port", type=_whole_number(0), default=0, help="port on 127.0.0.1 (default 0: a free one)")
    p.add_argument("--no-browser", action="store_true", help="only serve (scripts, remote machines)")
    p.add_argument("--cesium", metavar="DIR", help="CesiumJS's Build/Cesium folder (default: tools/viewer's npm install)")
    p.set_defaults(run=_cmd_view)

    p = sub.add_parser("scene", help="bake a procedural scene made by the project (no input files)")
    p.add_argument("name", choices=list(procedural.SCENES),
                   help="low / middle / high depth complexity (terrain / sparse town / dense downtown), "
                        "or default (the city block of the main job)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.hlod")
    p.add_argument("--seed", type=_whole_number(0), default=1)
    p.add_argument("--scale", type=float, default=1.0, help="size factor (1 = CI-sized)")
    _bake_options(p)
    p.set_defaults(run=_cmd_scene)
    return parser


def _runtime_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--s", type=float, default=0.9, help="P_{s,t} smoothness in [0, 1]")
    p.add_argument("--t", type=float, default=0.05, help="P_{s,t} turnover in [0, 1]")
    p.add_argument("--k", type=float, default=float("inf"), help="sigmoid steepness; inf = step (default)")
    p.add_argument("--tau", type=float, default=1.0, help="screen-space error threshold, pixels")
    p.add_argument("--alpha", choices=["query", "projected", "cube"], default="query", help="alpha estimator")
    p.add_argument("--skip-queries", choices=list(SKIP_QUERY_MODES), default=RuntimeSettings.skip_queries,
                   help="draw a visible node without a query where the query does not pay (the renderer's measured "
                        "costs): off, cheap (its draw costs less than the query), expected (the draw times the share "
                        "of queries that changed something costs less); re-checked every 5 frames. "
                        f"Default {RuntimeSettings.skip_queries}")
    p.add_argument("--shift-up", choices=["measured", "children"], default="measured",
                   help="Coh's shift-up: measured (default; refined nodes are queried too) or children "
                        "(the dissertation's Algorithm 4 alone)")
    p.add_argument("--multiquery", choices=list(MULTIQUERY_MODES), default="on",
                   help="CHC++ multiqueries: on tests nodes hidden last frame together, one query over their boxes "
                        "(each is queried on its own when it shows), at once when nothing is in flight; lazy: only when "
                        "a group is full or the traversal would wait; off: each node its own query. Default on")
    p.add_argument("--batch-queries", choices=list(BATCH_QUERY_MODES), default="on",
                   help="CHC++ query batching: on issues the queries of drawn nodes together, all occlusion "
                        "queries then all alpha queries, one state change each (default); off: one by one")
    p.add_argument("--predict-new", choices=list(PREDICT_NEW_MODES), default=RuntimeSettings.predict_new,
                   help="Coh: on draws a node not visited last frame at once, assumed visible and verified by its "
                        "query, where it would stop even fully visible and most such nodes turned out visible; off "
                        f"waits for its query. Default {RuntimeSettings.predict_new}")
    p.add_argument("--measure-every", type=_whole_number(1), default=RuntimeSettings.measure_every,
                   help="Coh's measured shift-up: query each refined node every N frames (staggered); 1 keeps the "
                        f"ratios fresh at the cost of more box queries. Default {RuntimeSettings.measure_every}")


def _bake_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--target-tris", type=_whole_number(1), default=BakeSettings.target_tris)
    p.add_argument("--max-depth", type=_whole_number(0), default=BakeSettings.max_depth)
    p.add_argument("--jobs", type=_whole_number(0), default=1, help="worker processes (default 1; 0 = one per core)")
    p.add_argument("--quality-threshold", type=float, default=BakeSettings.quality_threshold)
    p.add_argument("--preserve-normals", action="store_true", help="forbid face flips during decimation")
    p.add_argument("--error", choices=list(ERROR_MEASURES), default=BakeSettings.error,
                   help="inner nodes' error: exact (against every original triangle below the node; default) or "
                        "bound (against the children's LODs plus their largest error: faster bakes, looser errors, "
                        "more nodes drawn)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--cache", metavar="DIR", help="bake cache folder (default OUT.hlod.cache beside the output): "
                                                      "a re-bake takes the unchanged subtrees from it; safe to delete")
    where.add_argument("--no-cache", action="store_true", help="bake from scratch and keep no cache")


def _out_of_core_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out-of-core", action="store_true",
                   help="for inputs bigger than memory: stream the inputs (a scene spec one instance at a time) "
                        "through per-cell scratch files in --scratch (default: the temporary folder) instead of "
                        "loading them whole; the same file as an in-memory bake; geometry only, no bake cache")
    p.add_argument("--chunk-tris", type=_whole_number(1), default=None, metavar="N",
                   help="with --out-of-core: triangles a pass works on at a time, and buffered before the cell "
                        f"files are written (default {partition.CHUNK_TRIS})")


def _cluster_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="a Dask scheduler (tcp://HOST:8786): the decimations and measurements run on its workers "
                        "instead of --jobs local processes, for the same file (needs dask[distributed]; see README)")
    p.add_argument("--scratch", metavar="DIR",
                   help="with --scheduler: an existing folder every worker can read (shared storage on a cluster), "
                        "for the bake's shared arrays (default: the temporary folder, enough for workers on this "
                        "machine); with --out-of-core: where the per-cell files go (room for about 100 bytes an "
                        "input triangle); the bake's subfolders there are removed at the end")
    p.add_argument("--scheduler-timeout", type=_seconds, metavar="S",
                   help="with --scheduler: seconds to wait for the scheduler and its first worker (default 10)")


def _seconds(text: str) -> float:
    """argparse type: a finite number of seconds > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a number of seconds > 0, got {text}")
    return value


@contextlib.contextmanager
def _cluster(args):
    """The distributed.Client of --scheduler (None without it), connected and checked (its workers
    run this code and read --scratch) before any input is read or output written; each fault is
    one line naming the option. Closed when the block exits."""
    if args.scheduler is None:
        for name, value in (("--scratch", None if args.out_of_core else args.scratch),
                            ("--scheduler-timeout", args.scheduler_timeout)):
            if value is not None:
                raise InputError(f"{name}: only with --scheduler (a local bake's workers use $TMPDIR)")
        yield None
        return
    from .bake import dask_cluster

    # distributed's own INFO lines (one per connection) stay off stderr; its warnings show, not under -q
    logging.getLogger("distributed").setLevel(max(logging.WARNING, logging.getLogger().level))
    try:
        if args.scratch is not None:
            dask_cluster.check_scratch(args.scratch)
        client = dask_cluster.connect(args.scheduler, timeout_s=args.scheduler_timeout or dask_cluster.CONNECT_TIMEOUT_S)
    except dask_cluster.ClusterError as exc:
        raise InputError(f"--{exc}") from None
    with contextlib.closing(client):
        try:
            with dask_cluster.on_cluster(client, scratch_dir=args.scratch):  # the checks, in a folder of their own
                pass
        except dask_cluster.ClusterError as exc:
            raise InputError(f"--{exc}") from None
        yield client


def _settings(args) -> BakeSettings:
    jobs = args.jobs if args.jobs > 0 else (os.cpu_count() or 1)
    return BakeSettings(target_tris=args.target_tris, max_depth=args.max_depth, jobs=jobs,
                        quality_threshold=args.quality_threshold, preserve_normals=args.preserve_normals,
                        error=args.error)


def _cache_dir(args) -> Path | None:
    """The bake's cache folder: --cache, else OUT.hlod.cache beside the output; None with --no-cache."""
    return cache.folder_for(args.output, folder=args.cache, enabled=not args.no_cache)


def _bake_and_save(mesh, args, sources, *, scheduler=None) -> dict:
    """mesh: a TriangleMesh, or a partition.TriangleSource (--out-of-core: bake_stream,
    no cache); scheduler: the distributed.Client of `_cluster` (None: local workers)."""
    settings = _settings(args)
    streamed = not isinstance(mesh, meshes.TriangleMesh)
    cache_dir = None if streamed else _cache_dir(args)
    started = time.perf_counter()
    if streamed:
        hlod = bake_stream(mesh, settings, progress=_Progress(), sources=sources, scheduler=scheduler,
                           scratch_dir=args.scratch, chunk_tris=args.chunk_tris or partition.CHUNK_TRIS)
    else:
        hlod = bake(mesh, settings, progress=_Progress(), sources=sources, cache_dir=cache_dir, scheduler=scheduler,
                    scratch_dir=getattr(args, "scratch", None))
    hlod_file.save(hlod, args.output)
    seconds = time.perf_counter() - started
    for line in hlod.meta["log"]:
        log.info(line)
    summary = hlod.summary()
    summary.update(output=str(args.output), jobs=settings.jobs, seconds=seconds,
                   phase_seconds=hlod.meta["phase_seconds"],
                   tris_per_second=summary["input_tris"] / seconds if seconds > 0 else None,
                   cache=None if cache_dir is None else {"folder": str(cache_dir), **hlod.meta["cache"]})
    if scheduler is not None:
        summary["scheduler"] = {"address": args.scheduler, "worker_threads": sum(scheduler.nthreads().values())}
    return summary


def _cmd_bake(args) -> dict:
    check_output_file(args.output)
    if args.out_of_core:
        return _cmd_bake_out_of_core(args)
    if args.chunk_tris is not None:
        raise InputError("--chunk-tris: only with --out-of-core")
    cache.check_folder(_cache_dir(args))
    with _cluster(args) as client:
        started = time.perf_counter()
        with _EmbeddedTextures(Path(args.output)) as textures:
            mesh = textures.relocate(meshes.load_inputs(args.inputs, texture_dir=textures.scratch))
            load_seconds = time.perf_counter() - started
            summary = _bake_and_save(mesh, args, [str(p) for p in args.inputs], scheduler=client)
            summary["texture_folder"] = textures.publish()
    summary["load_seconds"] = load_seconds
    return summary


def _cmd_bake_out_of_core(args) -> dict:
    """bake --out-of-core: the inputs streamed (partition.SceneSource), never loaded whole."""
    if args.cache is not None:
        raise InputError("--cache: out-of-core bakes keep no bake cache (leave out --cache, or bake in memory)")
    if args.scratch is not None and not Path(args.scratch).is_dir():
        raise InputError(f"--scratch {args.scratch}: no such folder")
    with _cluster(args) as client:
        started = time.perf_counter()
        source = partition.SceneSource(args.inputs)
        load_seconds = time.perf_counter() - started
        summary = _bake_and_save(source, args, [str(p) for p in args.inputs], scheduler=client)
    summary.update(load_seconds=load_seconds, texture_folder=None, out_of_core=True)
    return summary


class _EmbeddedTextures:
    """Where a bake writes the images embedded in its glTF inputs: OUT.textures/ beside OUT.hlod
    (the .hlod refers to them by relative path). They are written into a hidden scratch folder
    beside it, made only when an image is written; `publish`, after the .hlod is saved, renames
    it to OUT.textures (replacing the one an earlier bake to OUT left). A failed or interrupted
    bake removes the scratch folder and leaves OUT.textures as it was. No embedded image: nothing
    is written and an existing OUT.textures is left alone."""

    def __init__(self, output: Path):
        self.final = output.with_suffix(".textures")
        if self.final == output:  # -o NAME.textures
            self.final = output.with_name(output.name + ".textures")
        self.scratch = output.parent / f".{self.final.name}.partial-{os.getpid()}"

    def __enter__(self) -> "_EmbeddedTextures":
        return self

    def __exit__(self, kind, exc, tb) -> None:
        shutil.rmtree(self.scratch, ignore_errors=True)

    def relocate(self, mesh):
        """The mesh with its texture paths in the scratch folder moved to the final folder."""
        if not self.scratch.is_dir():
            return mesh
        if self.final.exists() and not self.final.is_dir():
            raise InputError(f"{self.final}: is a file; the bake writes the inputs' embedded images into a folder "
                             "of that name")
        scratch = str(self.scratch.resolve())
        moved = tuple(dataclasses.replace(m, texture=str(self.final.resolve() / Path(m.texture).name))
                      if m.texture is not None and str(Path(m.texture).parent) == scratch else m
                      for m in mesh.materials)
        return dataclasses.replace(mesh, materials=moved)

    def publish(self) -> str | None:
        """Rename the scratch folder to OUT.textures; returns its path, or None when nothing was written."""
        if not self.scratch.is_dir():
            return None
        old = self.final.parent / f".{self.final.name}.old-{os.getpid()}"
        if self.final.is_dir():
            os.replace(self.final, old)
        os.replace(self.scratch, self.final)
        shutil.rmtree(old, ignore_errors=True)
        log.info("embedded images: %s", self.final)
        return str(self.final)


def _cmd_scene(args) -> dict:
    check_output_file(args.output)
    cache.check_folder(_cache_dir(args))
    if not 0 < args.scale <= 64:
        raise InputError(f"--scale {args.scale}: expected a factor in (0, 64]")
    mesh = procedural.SCENES[args.name](seed=args.seed, scale=args.scale)
    summary = _bake_and_save(mesh, args, [mesh.name])
    summary["scene"] = args.name
    return summary


def _cmd_export(args) -> dict:
    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise InputError(f"-o {out}: is a file, expected a folder")
    hlod = hlod_file.load(args.file)
    return export_hlod(hlod, args.format, out, stem=Path(args.file).stem)


def _cmd_view(args) -> dict:
    """Serve until Ctrl-C or SIGTERM (a normal end: exit 0). The URL is the first stdout line."""
    import webbrowser

    from .export import viewer

    with viewer.serve(args.dir, port=args.port, cesium_dir=args.cesium) as server:
        print(server.url, flush=True)
        if not args.no_browser and not webbrowser.open(server.url):
            log.info("no web browser found: open %s", server.url)
        try:
            server.serve_forever()
        except (KeyboardInterrupt, Terminated):
            pass
    return {"url": server.url, "dir": str(args.dir)}


def _cmd_info(args) -> dict:
    started = time.perf_counter()
    hlod = hlod_file.load(args.file)
    open_seconds = time.perf_counter() - started
    out = hlod.summary()
    out.update(checks.check(hlod))
    out.update(file=str(args.file), open_seconds=open_seconds, target_tris=hlod.meta.get("target_tris"),
               max_depth=hlod.meta.get("max_depth"), sources=hlod.meta.get("sources"),
               has_normals=hlod.normals is not None)
    return out


def _parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size {text!r}: expected WxH, e.g. 640x480") from None
    if not (1 <= w <= 16384 and 1 <= h <= 16384):
        raise InputError(f"--size {text!r}: width and height must lie in 1..16384")
    return w, h


def _runtime_setup(args, bias: str = "P"):
    """(hlod, settings, path, size) of the run and evaluate commands, validated before any GL work."""
    from .model.camera_path import inspection_path, load_path
    from .traversal.settings import RuntimeSettings

    size = _parse_size(args.size)
    settings = RuntimeSettings(tau=args.tau, s=args.s, t=args.t, k=args.k, bias=bias, alpha=args.alpha,
                               shift_up=args.shift_up, skip_queries=args.skip_queries, multiquery=args.multiquery,
                               batch_queries=args.batch_queries, predict_new=args.predict_new,
                               measure_every=args.measure_every)  # raises InputError
    hlod = hlod_file.load(args.file)
    path = load_path(args.path) if args.path else inspection_path(hlod, seed=args.seed, frames=args.frames)
    return hlod, settings, path, size


def _cmd_evaluate(args) -> dict:
    from .report import evaluate

    methods = args.methods or list(evaluate.METHOD_SPECS)
    unknown = [m for m in methods if m not in evaluate.METHOD_SPECS]
    if unknown:
        raise InputError(f"--methods: unknown {', '.join(unknown)}; expected some of {', '.join(evaluate.METHOD_SPECS)}")
    out_dir = Path(args.out)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"--out {out_dir}: is a file, expected a folder")
    if args.psnr_target is not None:
        return _cmd_tune(args, out_dir)
    hlod, settings, path, size = _runtime_setup(args)
    report = evaluate.evaluate(hlod, path, size, methods=methods, settings=settings, repeat=args.repeat,
                               sweep=args.sweep, out_dir=out_dir, psnr_frames=args.psnr_frames, seed=args.seed)
    log.info("report: %s", out_dir / "report.md")
    return evaluate.summary_line(report, out_dir)


def _cmd_tune(args, out_dir: Path) -> dict:
    """evaluate --psnr-target: the (s, t) search (hlod_core/report/tuning.py) instead of the methods."""
    from .report import evaluate, tuning

    given = [name for name, value in (("--methods", args.methods), ("--sweep", args.sweep)) if value]
    if given:
        raise InputError(f"--psnr-target runs Bool and the Coh(P) candidates only; leave out {' and '.join(given)} "
                         "(evaluate the chosen --s and --t without --psnr-target for the other methods)")
    hlod, settings, path, size = _runtime_setup(args)
    report = tuning.tune(hlod, path, size, target_db=args.psnr_target, settings=settings, repeat=args.repeat,
                         out_dir=out_dir, psnr_frames=args.psnr_frames, seed=args.seed)
    log.info("report: %s", out_dir / "report.md")
    return evaluate.summary_line(report, out_dir) | {"psnr_target": tuning.summary(report)}


def _cmd_run(args) -> dict:
    from .report.runner import run_path

    if args.save_path:
        check_output_file(args.save_path, "--save-path", "path.json")
    hlod, settings, path, size = _runtime_setup(args, args.bias)
    if args.save_path:
        path.save(args.save_path)
    out = run_path(hlod, args.method, settings, path=path, size=size, save_frames=args.save_frames)
    out.update(method=args.method, bias=args.bias, size=list(size), alpha=args.alpha, tau=args.tau)
    return out


class _Progress:
    """Reports bake progress to the log every 10%."""

    def __init__(self):
        self._next = 0.0

    def __call__(self, done: int, total: int, phase: str) -> None:
        fraction = done / total if total else 1.0
        if fraction >= self._next or phase == "done":
            log.info("bake %s: %d/%d nodes (%.0f%%)", phase, done, total, 100 * fraction)
            self._next = fraction + 0.1
