"""The command line's argument types, the option groups several commands share, and the settings
each group makes (argparse Namespace -> BakeSettings / RuntimeSettings)."""
from __future__ import annotations

import argparse
import math

from ..bake.run.cache import DEFAULT_BUDGET_MB
from ..bake.settings import ERROR_MEASURES, BakeSettings, bake_settings
from ..bake.space import partition
from ..core.errors import InputError
from ..render.residency import StreamingSettings
from ..traversal.settings import (
    BATCH_QUERY_MODES,
    MULTIQUERY_MODES,
    PREDICT_NEW_MODES,
    QUERIES_MODES,
    SKIP_QUERY_MODES,
    RuntimeSettings,
)


class Parser(argparse.ArgumentParser):
    """An argument error is one line, `hlod_core: error: ...`, and exit status 2 (argparse's
    default prints the whole usage first). Subcommand parsers are of the same class."""

    def error(self, message: str):
        self.exit(2, f"hlod_core: error: {message} (see {self.prog} --help)\n")


# --- argument types -------------------------------------------------------------------------------

def whole_number(minimum: int):
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


def place_text(text: str):
    """argparse type of --place: export.place.parse's Place, or its NO_PLACE."""
    from ..export.place import parse

    try:
        return parse(text, where=text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_mesh_option(p: argparse.ArgumentParser) -> None:
    """--mesh, the 3D Tiles tile content's encoding (export.formats.MESH_ENCODINGS), and --merge-leaves,
    on parser `p`: the core's export command and the Blender background command share them."""
    from ..export.formats import MESH_ENCODINGS

    p.add_argument("--mesh", choices=MESH_ENCODINGS, default="plain",
                   help="3dtiles: tile content as float32 (plain), with positions and normals quantized "
                        "(KHR_mesh_quantization) or Draco compressed (KHR_draco_mesh_compression; needs "
                        "the DracoPy package)")
    p.add_argument("--merge-leaves", action="store_true",
                   help="3dtiles: a node's leaf children share one tile (fewer, bigger tiles: less JSON per "
                        "triangle and fewer requests; frustum culling of the leaves by their union box)")


def seconds(text: str) -> float:
    """argparse type: a finite number of seconds > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a number of seconds > 0, got {text}")
    return value


def psnr_db(text: str) -> float:
    """argparse type of --psnr-target: dB in the range tuning.check_target accepts."""
    from ..report.tuning import check_target

    try:
        return check_target(text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("PSNR target: ")) from None


def parse_size(text: str) -> tuple[int, int]:
    """--size WxH -> (width, height) pixels, each in 1..16384; InputError otherwise."""
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size {text!r}: expected WxH, e.g. 640x480") from None
    if not (1 <= w <= 16384 and 1 <= h <= 16384):
        raise InputError(f"--size {text!r}: width and height must lie in 1..16384")
    return w, h


# --- the bake's options ---------------------------------------------------------------------------

def bake_options(p: argparse.ArgumentParser) -> None:
    """The options of `bake` and `scene`: the bake's settings and its cache folder."""
    p.add_argument("--target-tris", type=whole_number(1), default=BakeSettings.target_tris)
    p.add_argument("--max-depth", type=whole_number(0), default=BakeSettings.max_depth)
    p.add_argument("--jobs", type=whole_number(0), default=1,
                   help="worker processes (default 1; 0 = all cores but one)")
    p.add_argument("--quality-threshold", type=float, default=BakeSettings.quality_threshold)
    p.add_argument("--preserve-normals", action="store_true", help="forbid face flips during decimation")
    p.add_argument("--error", choices=list(ERROR_MEASURES), default=BakeSettings.error,
                   help="inner nodes' error: exact (against every original triangle below the node; default) or "
                        "bound (against the children's LODs plus their largest error: faster bakes, looser errors, "
                        "more nodes drawn)")
    p.add_argument("--keep-materials", action="store_true",
                   help="every level keeps the sources' materials and textures (default: an inner node whose "
                        "sources have several materials or finer textures than it needs gets one proxy material, "
                        "a UV atlas and one base-colour texture sized by its error)")
    p.add_argument("--texture-cap", type=whole_number(1), default=BakeSettings.texture_cap, metavar="TEXELS",
                   help="the longest side of a proxy texture, texels (default %(default)s)")
    p.add_argument("--texture-floor", type=whole_number(1), default=BakeSettings.texture_floor, metavar="TEXELS",
                   help="the shortest longest side of a proxy texture, texels (default %(default)s)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--cache", metavar="DIR", help="bake cache folder (default OUT.hlod.cache beside the output): "
                                                      "a re-bake takes the unchanged subtrees from it, and keeps the "
                                                      "last bake's frame while the input fits it; safe to delete")
    where.add_argument("--no-cache", action="store_true", help="bake from scratch and keep no cache")
    p.add_argument("--cache-budget", type=megabytes, default=None, metavar="MB",
                   help="the cache folder's size (MB, 2^20 bytes): entries of earlier bakes are kept, the least "
                        "recently used removed past it, never one the bake used; 0 keeps only the last bake's "
                        f"(default {DEFAULT_BUDGET_MB:g})")
    p.add_argument("--frame-from", metavar="EARLIER.hlod",
                   help="bake in the frame of an earlier bake's file (its origin, lattice and root cube) while the "
                        "input fits it, as a re-bake from that bake's cache would, instead of the cache folder's "
                        "last frame; with --no-cache a bake from scratch to compare a re-bake with")


def bake_settings_of(args: argparse.Namespace) -> BakeSettings:
    """The BakeSettings of bake_options' arguments (bake.settings.bake_settings: --jobs 0 = all cores but one)."""
    return bake_settings(target_tris=args.target_tris, max_depth=args.max_depth, jobs=args.jobs,
                         quality_threshold=args.quality_threshold, preserve_normals=args.preserve_normals,
                         error=args.error, proxy_materials=not args.keep_materials, texture_cap=args.texture_cap,
                         texture_floor=args.texture_floor)


def out_of_core_options(p: argparse.ArgumentParser) -> None:
    """`bake --out-of-core [--chunk-tris N]`."""
    p.add_argument("--out-of-core", action="store_true",
                   help="for inputs bigger than memory: stream the inputs (a scene spec one instance at a time) "
                        "through per-cell scratch files in --scratch (default: the temporary folder) instead of "
                        "loading them whole; the same file as an in-memory bake; geometry only, no bake cache")
    p.add_argument("--chunk-tris", type=whole_number(1), default=None, metavar="N",
                   help="with --out-of-core: triangles a pass works on at a time, and buffered before the cell "
                        f"files are written (default {partition.CHUNK_TRIS})")


def cluster_options(p: argparse.ArgumentParser) -> None:
    """`bake --scheduler ADDRESS [--scratch DIR] [--scheduler-timeout S]` (--scratch serves --out-of-core too)."""
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="a Dask scheduler (tcp://HOST:8786): the decimations and measurements run on its workers "
                        "instead of --jobs local processes, for the same file (needs dask[distributed]; "
                        "docs/command-line.md#baking-on-a-dask-cluster)")
    p.add_argument("--scratch", metavar="DIR",
                   help="with --scheduler: an existing folder every worker can read (shared storage on a cluster), "
                        "for the bake's shared arrays (default: the temporary folder, enough for workers on this "
                        "machine); with --out-of-core: where the per-cell files go (room for about 100 bytes an "
                        "input triangle); the bake's subfolders there are removed at the end")
    p.add_argument("--scheduler-timeout", type=seconds, metavar="S",
                   help="with --scheduler: seconds to wait for the scheduler and its first worker (default 10)")


# --- the traversal's options ----------------------------------------------------------------------

def runtime_options(p: argparse.ArgumentParser) -> None:
    """The options of `run` and `evaluate`: the traversal's settings (RuntimeSettings)."""
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
                        "(each is queried on its own when it shows), at once when nothing is in flight; lazy: only "
                        "when a group is full or the traversal would wait; off: each node its own query. Default on")
    p.add_argument("--batch-queries", choices=list(BATCH_QUERY_MODES), default="on",
                   help="CHC++ query batching: on issues the queries of drawn nodes together, all occlusion "
                        "queries then all alpha queries, one state change each (default); off: one by one")
    p.add_argument("--predict-new", choices=list(PREDICT_NEW_MODES), default=RuntimeSettings.predict_new,
                   help="Coh: on draws a node not visited last frame at once, assumed visible and verified by its "
                        "query, where it would stop even fully visible and most such nodes turned out visible; off "
                        f"waits for its query. Default {RuntimeSettings.predict_new}")
    p.add_argument("--measure-every", type=whole_number(1), default=RuntimeSettings.measure_every,
                   help="Coh's measured shift-up: query each refined node every N frames (staggered); 1 keeps the "
                        f"ratios fresh at the cost of more box queries. Default {RuntimeSettings.measure_every}")
    p.add_argument("--queries", choices=list(QUERIES_MODES), default=RuntimeSettings.queries,
                   help="Bool, Simp, Coh: auto draws as VFC, with no queries, where over recent frames they culled "
                        "less than they cost, probing a few every few frames to resume them; always queries every "
                        f"frame. Default {RuntimeSettings.queries}")


def runtime_settings_of(args: argparse.Namespace, *, bias: str = "P") -> RuntimeSettings:
    """The RuntimeSettings of runtime_options' arguments; bias: "P" or "mu" (`run --bias`).
    InputError for a value out of range."""
    return RuntimeSettings(tau=args.tau, s=args.s, t=args.t, k=args.k, bias=bias, alpha=args.alpha,
                           shift_up=args.shift_up, skip_queries=args.skip_queries, multiquery=args.multiquery,
                           batch_queries=args.batch_queries, predict_new=args.predict_new,
                           measure_every=args.measure_every, queries=args.queries)


def gpu_budget_option(p: argparse.ArgumentParser) -> None:
    """--gpu-budget: node geometry and textures streamed under a GPU memory budget (render.residency)."""
    p.add_argument("--gpu-budget", type=megabytes, default=0.0, metavar="MB",
                   help="GPU memory for node geometry and textures, MB (2^20 bytes): nodes are uploaded with their "
                        "textures as the traversal wants them and the least recently used evicted; a coarser "
                        "resident node stands in until they arrive. 0 (default): unlimited, the whole file uploaded "
                        "at the start")


def megabytes(text: str) -> float:
    """argparse type: a finite number of MB >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of MB >= 0, got {text!r}") from None
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"expected a number of MB >= 0, got {text!r}")
    return value


def streaming_of(args: argparse.Namespace) -> StreamingSettings:
    """The StreamingSettings of --gpu-budget."""
    return StreamingSettings.from_megabytes(args.gpu_budget)
