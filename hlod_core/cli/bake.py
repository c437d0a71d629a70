"""The `bake` and `scene` commands: inputs (files and scene specs, streamed with --out-of-core, or a
procedural scene) -> one .hlod, its cache folder and the folder of its inputs' embedded images;
the bake runs on local worker processes or on a Dask cluster's workers (--scheduler)."""
from __future__ import annotations

import argparse
import contextlib
import logging
import time
from pathlib import Path

from ..bake.pipeline import bake, bake_stream
from ..bake.run import cache
from ..bake.space import frame as frames
from ..bake.space import partition
from ..bake.space.frame import Frame
from ..core import heap
from ..core.errors import InputError
from ..export.formats import check_output_file
from ..io import meshes, procedural
from ..io.texture_folder import EmbeddedTextures
from ..io.textures import load_material_images
from .options import bake_options, bake_settings_of, cluster_options, out_of_core_options, whole_number

log = logging.getLogger("hlod_core")


def add_bake(sub) -> None:
    """The `bake` command's parser, on the subparsers `sub`."""
    p = sub.add_parser("bake", help="bake mesh files and/or JSON scene specs into one .hlod")
    p.add_argument("inputs", nargs="+", metavar="INPUT", help="OBJ/PLY/STL/GLB file or JSON scene spec")
    p.add_argument("-o", "--output", required=True, metavar="OUT.hlod")
    bake_options(p)
    out_of_core_options(p)
    cluster_options(p)
    p.set_defaults(run=bake_command)


def add_scene(sub) -> None:
    """The `scene` command's parser, on the subparsers `sub`."""
    p = sub.add_parser("scene", help="bake a procedural scene made by the project (no input files)")
    p.add_argument("name", choices=list(procedural.SCENES),
                   help="low / middle / high depth complexity (terrain / sparse town / dense downtown), "
                        "default (the city block of the main job), or pieces (open scans, foliage cards, "
                        "a model in many parts)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.hlod")
    p.add_argument("--seed", type=whole_number(0), default=1)
    p.add_argument("--scale", type=float, default=1.0, help="size factor (1 = CI-sized)")
    bake_options(p)
    p.set_defaults(run=scene_command)


def bake_command(args: argparse.Namespace) -> dict:
    """`bake`: the summary line (hlod.summary() with the output, jobs, timings, cache and texture folder)."""
    check_output_file(args.output)
    heap.return_freed_buffers()
    if args.out_of_core:
        return _bake_out_of_core(args)
    if args.chunk_tris is not None:
        raise InputError("--chunk-tris: only with --out-of-core")
    cache_dir, frame_from = _cache_dir(args), _frame_from(args)
    with _cluster(args) as client:
        started = time.perf_counter()
        with EmbeddedTextures(Path(args.output)) as textures:
            loaded = meshes.load_inputs(args.inputs, texture_dir=textures.scratch)
            # the proxies' sources, read while the embedded images are still where the bake wrote them
            images = load_material_images(loaded.materials) if not args.keep_materials else {}
            handed = [textures.relocate(loaded)]  # the bake takes the only reference: the input goes after the leaves
            del loaded
            load_seconds = time.perf_counter() - started
            summary = _bake_and_save(handed, args, sources=[str(p) for p in args.inputs], cache_dir=cache_dir,
                                     scheduler=client, frame_from=frame_from, textures=textures, images=images)
            summary["texture_folder"] = textures.publish()
    summary["load_seconds"] = load_seconds
    return summary


def _bake_out_of_core(args: argparse.Namespace) -> dict:
    """bake --out-of-core: the inputs streamed (partition.SceneSource), never loaded whole; no cache."""
    for name, value in (("--cache", args.cache), ("--cache-budget", args.cache_budget),
                        ("--frame-from", args.frame_from)):
        if value is not None:
            raise InputError(f"{name}: out-of-core bakes keep no bake cache and bake in the input's frame "
                             f"(leave out {name}, or bake in memory)")
    if args.scratch is not None and not Path(args.scratch).is_dir():
        raise InputError(f"--scratch {args.scratch}: no such folder")
    with _cluster(args) as client:
        started = time.perf_counter()
        source = partition.SceneSource(args.inputs)
        load_seconds = time.perf_counter() - started
        summary = _bake_and_save(source, args, sources=[str(p) for p in args.inputs], scheduler=client)
    summary.update(load_seconds=load_seconds, texture_folder=None, out_of_core=True)
    return summary


def scene_command(args: argparse.Namespace) -> dict:
    """`scene`: the summary line of the bake of a procedural scene (procedural.SCENES)."""
    check_output_file(args.output)
    heap.return_freed_buffers()
    cache_dir, frame_from = _cache_dir(args), _frame_from(args)
    if not 0 < args.scale <= 64:
        raise InputError(f"--scale {args.scale}: expected a factor in (0, 64]")
    mesh = procedural.SCENES[args.name](seed=args.seed, scale=args.scale)
    summary = _bake_and_save(mesh, args, sources=[mesh.name], cache_dir=cache_dir, frame_from=frame_from)
    summary["scene"] = args.name
    return summary


def _cache_dir(args: argparse.Namespace) -> Path | None:
    """The bake's cache folder: --cache, else OUT.hlod.cache beside the output; None with --no-cache.
    InputError when it names a file (cache.folder_for), or for --cache-budget with --no-cache."""
    if args.no_cache and args.cache_budget is not None:
        raise InputError("--cache-budget: a budget of the bake cache, which --no-cache turns off")
    return cache.folder_for(args.output, folder=args.cache, enabled=not args.no_cache)


def _frame_from(args: argparse.Namespace) -> Frame | None:
    """The frame of --frame-from's file (its meta["frame"]); InputError naming it when it has none."""
    if args.frame_from is None:
        return None
    return frames.of_file(args.frame_from, where=f"--frame-from {args.frame_from}")


def _bake_and_save(mesh, args: argparse.Namespace, *, sources: list[str], cache_dir: Path | None = None,
                   scheduler=None, frame_from: Frame | None = None, textures: EmbeddedTextures | None = None,
                   images: dict | None = None) -> dict:
    """Bake, save to --output and summarise. mesh: a TriangleMesh or a one-item list holding one (handed over:
    pipeline.bake), or a partition.TriangleSource (--out-of-core: bake_stream, no cache); scheduler: the
    distributed.Client of `_cluster` (None: local workers); frame_from: --frame-from's frame; textures: the bake's
    texture folder (the proxy materials' textures go there); images: the materials' texture images the proxies are
    baked from (None: read from the materials' files with Pillow, io.textures)."""
    settings = bake_settings_of(args)
    streamed = not isinstance(mesh, (meshes.TriangleMesh, list))
    started = time.perf_counter()
    if streamed:
        hlod = bake_stream(mesh, settings, progress=_Progress(), sources=sources, scheduler=scheduler,
                           scratch_dir=args.scratch, chunk_tris=args.chunk_tris or partition.CHUNK_TRIS,
                           output=args.output)
    else:
        budget = cache.DEFAULT_BUDGET_MB if args.cache_budget is None else args.cache_budget
        if images is None:
            materials = (mesh[0] if isinstance(mesh, list) else mesh).materials
            images = load_material_images(materials) if settings.proxy_materials else {}
        hlod = bake(mesh, settings, progress=_Progress(), sources=sources, cache_dir=cache_dir, scheduler=scheduler,
                    scratch_dir=getattr(args, "scratch", None), frame_from=frame_from, cache_budget_mb=budget,
                    images=images, textures=textures, output=args.output)
    seconds = time.perf_counter() - started
    for line in hlod.meta["log"]:
        log.info(line)
    summary = hlod.summary()
    summary.update(output=str(args.output), jobs=settings.jobs, seconds=seconds,
                   phase_seconds=hlod.meta["phase_seconds"],
                   tris_per_second=summary["input_tris"] / seconds if seconds > 0 else None,
                   cache=None if cache_dir is None or "cache" not in hlod.meta
                   else {"folder": str(cache_dir), **hlod.meta["cache"]},
                   frame=hlod.meta["frame_source"])
    if scheduler is not None:
        summary["scheduler"] = {"address": args.scheduler, "worker_threads": sum(scheduler.nthreads().values())}
    return summary


@contextlib.contextmanager
def _cluster(args: argparse.Namespace):
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
    from ..bake.run import dask_cluster

    # distributed's own INFO lines (one per connection) stay off stderr; its warnings show, not under -q
    logging.getLogger("distributed").setLevel(max(logging.WARNING, logging.getLogger().level))
    try:
        if args.scratch is not None:
            dask_cluster.check_scratch(args.scratch)
        client = dask_cluster.connect(args.scheduler,
                                      timeout_s=args.scheduler_timeout or dask_cluster.CONNECT_TIMEOUT_S)
    except dask_cluster.ClusterError as exc:
        raise InputError(f"--{exc}") from None
    with contextlib.closing(client):
        try:
            with dask_cluster.on_cluster(client, scratch_dir=args.scratch):  # the checks, in a folder of their own
                pass
        except dask_cluster.ClusterError as exc:
            raise InputError(f"--{exc}") from None
        yield client


class _Progress:
    """Reports bake progress to the log every 10%."""

    def __init__(self):
        self._next = 0.0

    def __call__(self, done: int, total: int, phase: str) -> None:
        fraction = done / total if total else 1.0
        if fraction >= self._next or phase == "done":
            log.info("bake %s: %d/%d nodes (%.0f%%)", phase, done, total, 100 * fraction)
            self._next = fraction + 0.1
