"""Batch work from background mode (docs/command-line.md#blender-blender--b---command-hlod): `blender -b
[FILE.blend] --command hlod ...`, registered with `bpy.utils.register_cli_command`, and the same
code through the bpy module (`python scripts/hlod_blender.py ...`, for machines with the bpy wheel
and no Blender install).

    hlod bake [FILE.blend ...] [--collection NAME | --objects A,B] -o OUT [--format hlod 3dtiles]
              [--include-hidden] [--place LON,LAT,HEIGHT[,HEADING] | none] [--mesh plain|quantized|draco]
              [the core's bake options: --target-tris N ... --jobs N --cache DIR | --no-cache]
    hlod export IN.hlod --format 3dtiles|hlod -o DIR [--place LON,LAT,HEIGHT[,HEADING] | none]
                [--mesh plain|quantized|draco]
    hlod view DIR [--port N] [--no-browser] [--cesium CESIUM_DIR]

`bake` takes the core command's bake options (hlod_core/cli/options.py `bake_options`: the same
names, defaults and checks; --jobs 1 by default, 0 = all cores but one) and runs, for each file, the
flow the Bake operator runs (addon/bake/from_scene.py): the scene gathered in Blender, baked in a
child process of Blender's Python; Ctrl-C stops the child and its workers and writes nothing for
that file. The cache is OUT.hlod.cache beside each .hlod (or --cache DIR), so a re-bake redoes only
what changed; --no-cache bakes from scratch and keeps none.
`bake` without .blend files bakes the open file into OUT (a .hlod path); with files, OUT is a
folder and each file FILE.blend gives OUT/FILE.hlod and, with `--format 3dtiles`, OUT/FILE_3dtiles/.
By default a bake takes what the view layer shows (the objects named, or every object of the
scene); --include-hidden takes objects hidden in the viewport too. What it leaves out (hidden
objects, kinds without triangles: addon/scene/objects.py) is named in one stderr line per file.
A file that fails is one stderr line naming it and the reason (never a traceback) and the others
go on. The last stdout line is a JSON summary ({"files": [{"blend", "ok", "outputs", "skipped" |
"error"}], "failed": N}); the exit status is 1 if any failed, 2 for bad arguments.
A 3D Tiles export stands on the globe at --place, else where the scene's Export panel Place says
(addon/scene/place.py; by default the scene's georeference, the custom properties GIS add-ons write:
hlod_core/export/place.py), else in the local frame; a place that cannot be read fails the file
before its bake, one line.
`view` is the core's `view` command (hlod_core.export.viewer.serve_until_stopped, imported only by
this command): the first line it prints is the page's URL (http://127.0.0.1:N/), for scripts; it
serves until Ctrl-C or SIGTERM, then exits 0. A folder without tileset.json, CesiumJS not found or
a port in use is one line on stderr and exit status 2.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import bpy

from ..hlod_core.cli.options import add_mesh_option, bake_options, bake_settings_of, place_text
from ..hlod_core.core.errors import HlodError, InputError
from ..hlod_core.export.formats import export_hlod
from ..hlod_core.export.place import chosen
from ..hlod_core.io import hlod_file
from .bake.from_scene import start_bake
from .materials.cycles_bake import cycles_report
from .scene.objects import HIDDEN, Skipped
from .scene.place import export_place

_cli_command = None  # the handle of the registered command


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse exits the process; Blender's command wants a status
        raise InputError(f"{self.prog}: {message}")


def parser() -> argparse.ArgumentParser:
    """The background command's parser: bake, export and view (docs/command-line.md lists their options)."""
    p = _Parser(prog="blender -b [FILE.blend] --command hlod",
                description="Bake, export and view octree HLODs in batch.")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)
    b = sub.add_parser("bake", help="bake the open file, or each FILE.blend given")
    b.add_argument("blends", nargs="*", metavar="FILE.blend")
    source = b.add_mutually_exclusive_group()
    source.add_argument("--collection", metavar="NAME", help="bake this collection (with its children)")
    source.add_argument("--objects", metavar="A,B", help="bake these objects (comma-separated names)")
    b.add_argument("-o", "--output", required=True, help="OUT.hlod (open file) or a folder (with FILE.blend arguments)")
    b.add_argument("--format", nargs="+", choices=["hlod", "3dtiles"], default=["hlod"],
                   help="outputs per file: hlod (always written) and/or 3dtiles")
    bake_options(b)  # the core command's: --target-tris ... --jobs, --cache DIR | --no-cache
    b.add_argument("--include-hidden", action="store_true",
                   help="bake objects hidden in the viewport too (default: what the view layer shows)")
    _export_arguments(b)
    e = sub.add_parser("export", help="export a baked .hlod")
    e.add_argument("file", metavar="IN.hlod")
    e.add_argument("--format", choices=["3dtiles", "hlod"], required=True)
    e.add_argument("-o", "--output", required=True, metavar="DIR")
    _export_arguments(e)
    v = sub.add_parser("view", help="serve a 3D Tiles export and a CesiumJS viewer on 127.0.0.1 until Ctrl-C")
    v.add_argument("dir", metavar="DIR", help="a 3D Tiles export: the folder holding tileset.json")
    v.add_argument("--port", type=int, default=0, metavar="N", help="the port (default 0: a free one)")
    v.add_argument("--no-browser", action="store_true", help="only serve (scripts, remote machines)")
    v.add_argument("--cesium", metavar="CESIUM_DIR",
                   help="CesiumJS's built files (npm cesium/Build/Cesium; default: the one the extension carries)")
    return p


def _export_arguments(p) -> None:
    add_mesh_option(p)
    p.add_argument("--place", type=place_text, metavar="LON,LAT,HEIGHT[,HEADING]",
                   help="3dtiles: stand the scene's origin at this WGS84 point (degrees, degrees, metres; heading "
                        "in degrees clockwise from north; --place=-122.4,... for a negative longitude); none: the "
                        "local frame; default: the scene's Export panel Place (by default its georeference: "
                        "BlenderGIS, Blosm), if any")


def scene_place(given, scene):
    """The place of a 3D Tiles export of `scene`: `--place`'s value (a Place, or none: the local
    frame), else the scene's Export panel Place (scene/place.py: by default its georeference);
    InputError, one line, for one that cannot be read."""
    if given is None:
        return export_place(scene)
    return chosen(given)


def register() -> None:
    global _cli_command
    _cli_command = bpy.utils.register_cli_command("hlod", execute)


def unregister() -> None:
    global _cli_command
    if _cli_command is not None:
        bpy.utils.unregister_cli_command(_cli_command)
        _cli_command = None


def execute(argv: list[str]) -> int:
    """The registered command: never raises; bake and export print a JSON summary last, view its
    URL first."""
    try:
        args = parser().parse_args(list(argv))
    except SystemExit as exc:  # --help
        return int(exc.code or 0)
    except InputError as exc:
        print(f"hlod: error: {exc}", file=sys.stderr)
        return 2
    if args.command == "view":
        return _view(args)
    if args.command == "export":
        try:
            place = scene_place(args.place, bpy.context.scene) if args.format == "3dtiles" else None
            summary = export_hlod(hlod_file.load(args.file), args.format, Path(args.output), stem=Path(args.file).stem,
                                  place=place, mesh=args.mesh, merge_leaves=args.merge_leaves)
        except (HlodError, OSError) as exc:
            print(f"hlod: error: {exc}", file=sys.stderr)
            return 1
        print(json.dumps(summary))
        return 0
    results = []
    if not args.blends:
        results.append(_bake_current(args, Path(args.output), None))
    else:
        for blend in args.blends:
            results.append(_bake_file(args, Path(blend)))
    failed = sum(1 for r in results if not r["ok"])
    print(json.dumps({"files": results, "failed": failed}))
    return 1 if failed else 0


def _view(args) -> int:
    """Serve until Ctrl-C or SIGTERM, exit status 0 (signals as exceptions from before the URL is
    printed, so a script that stops it once it has read the URL always gets 0); 2 with one line
    on stderr when it cannot serve."""
    from ..hlod_core.core.signals import signals_as_exceptions
    from ..hlod_core.export import viewer  # here: the add-on imports no viewer code until it is used

    with signals_as_exceptions():
        try:
            viewer.serve_until_stopped(args.dir, port=args.port, cesium_dir=args.cesium or None,
                                       open_browser=not args.no_browser, on_serving=_print_url)
        except (HlodError, OSError) as exc:
            print(f"hlod: error: {exc}", file=sys.stderr)
            return 2
    return 0


def _print_url(url: str) -> None:
    """The view command's first stdout line, flushed at once (scripts wait for it)."""
    print(url, flush=True)


def _bake_file(args, blend: Path) -> dict:
    try:
        if not blend.is_file():
            raise InputError("no such .blend file")
        bpy.ops.wm.open_mainfile(filepath=str(blend.resolve()), load_ui=False)
    except (HlodError, RuntimeError) as exc:
        message = _one_line(exc) if isinstance(exc, HlodError) else f"cannot open it: {' '.join(str(exc).split())}"
        print(f"hlod: {blend}: {message}", file=sys.stderr)
        return {"blend": str(blend), "ok": False, "error": message}
    out_dir = Path(args.output)
    return _bake_current(args, out_dir / f"{blend.stem}.hlod", out_dir / f"{blend.stem}_3dtiles")


def _bake_current(args, target: Path, tiles_dir: Path | None) -> dict:
    """Bake the open file into `target` (addon/bake/from_scene.py), then export it as 3D Tiles into
    `tiles_dir` when asked; the file's summary entry (module notes)."""
    blend = bpy.data.filepath or "(unsaved)"
    started = time.perf_counter()
    try:
        if target.suffix != ".hlod":
            raise InputError(f"-o {target}: give a .hlod file name when baking the open file")
        objects = _objects(args)
        place = scene_place(args.place, bpy.context.scene) if "3dtiles" in args.format else None  # before the bake
        target.parent.mkdir(parents=True, exist_ok=True)
        bake = start_bake(bpy.context, objects, target, bake_settings_of(args), use_cache=not args.no_cache,
                          cache_folder=args.cache, include_hidden=args.include_hidden,
                          cache_budget_mb=args.cache_budget, frame_from=args.frame_from)
        if bake.cycles_bakes:  # colours no node tree reading gives
            print(f"hlod: {blend}: {cycles_report(bake.cycles_bakes)}", file=sys.stderr)
        _print_skipped(blend, bake.gathered.skipped)
        try:
            bake.job.join()
        finally:
            bake.finish()
        job = bake.job
        if job.error is not None:
            raise job.error
        outputs = {"hlod": str(target)}
        if "3dtiles" in args.format:
            tiles_dir = tiles_dir or target.with_name(target.stem + "_3dtiles")
            outputs["3dtiles"] = export_hlod(hlod_file.load(target), "3dtiles", tiles_dir, stem=target.stem,
                                             place=place, mesh=args.mesh,
                                             merge_leaves=args.merge_leaves)["output"]
    except Exception as exc:  # noqa: BLE001 - one line per failed file, and the batch goes on
        message = _one_line(exc)
        print(f"hlod: {blend}: {message}", file=sys.stderr)
        return {"blend": blend, "ok": False, "error": message}
    return {"blend": blend, "ok": True, "outputs": outputs, "nodes": job.result.node_count,
            "input_tris": job.result.input_tris, "jobs": job.result.jobs, "cache": job.result.cache,
            "skipped": bake.gathered.skipped.as_dict(), "cycles_bakes": [b.as_dict() for b in bake.cycles_bakes],
            "seconds": time.perf_counter() - started}


def _one_line(exc: BaseException) -> str:
    """An error as one line: the core's typed errors and OS errors as their message, anything else
    with its type's name (a bug or a Blender error, still never a traceback in a batch)."""
    text = " ".join(str(exc).split())
    return text if isinstance(exc, (HlodError, OSError)) else f"{type(exc).__name__}: {text}"


def _print_skipped(blend: str, skipped: Skipped) -> None:
    """What the bake of `blend` left out, one line on stderr (none when nothing)."""
    if skipped:
        hint = " (--include-hidden bakes hidden objects)" if skipped.kinds.get(HIDDEN) else ""
        print(f"hlod: {blend}: {skipped.text()}{hint}", file=sys.stderr)


def _objects(args) -> list:
    if args.collection:
        collection = bpy.data.collections.get(args.collection)
        if collection is None:
            raise InputError(f"--collection {args.collection!r}: no such collection in "
                             f"{bpy.data.filepath or 'the file'}")
        return list(collection.all_objects)
    if args.objects:
        names = [n.strip() for n in args.objects.split(",") if n.strip()]
        missing = [n for n in names if n not in bpy.data.objects]
        if missing:
            raise InputError(f"--objects: no object named {', '.join(missing)} in {bpy.data.filepath or 'the file'}")
        return [bpy.data.objects[n] for n in names]
    objects = list(bpy.context.scene.objects)  # kinds without triangles are named as skipped
    if not objects:
        raise InputError(f"{bpy.data.filepath or 'the file'}: the scene has no objects to bake")
    return objects
