"""The `info`, `export` and `view` commands: a .hlod file's counts and checks, its export (3D Tiles
or .hlod), and the local CesiumJS viewer of a 3D Tiles export (export.viewer)."""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from ..bake import checks
from ..core.errors import InputError
from ..export.formats import TEXTURE_ENCODINGS, export_hlod
from ..export.place import chosen
from ..io import hlod_file
from .options import add_mesh_option, place_text, whole_number


def add_info(sub) -> None:
    """The `info` command's parser, on the subparsers `sub`."""
    p = sub.add_parser("info", help="counts and invariant checks of a .hlod file")
    p.add_argument("file", metavar="FILE.hlod")
    p.set_defaults(run=info_command)


def add_export(sub) -> None:
    """The `export` command's parser, on the subparsers `sub`."""
    p = sub.add_parser("export", help="export a .hlod as 3D Tiles 1.1 (tileset.json + one GLB per node) or .hlod")
    p.add_argument("file", metavar="IN.hlod")
    p.add_argument("--format", choices=["3dtiles", "hlod"], default="3dtiles")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder (replaced atomically)")
    p.add_argument("--place", type=place_text, metavar="LON,LAT,HEIGHT[,HEADING]",
                   help="3dtiles: stand the scene's origin at this WGS84 point (degrees, degrees, metres; "
                        "heading in degrees clockwise from north); write --place=-122.4,37.8,0 for a "
                        "negative longitude; none: the local frame (default)")
    add_mesh_option(p)
    p.add_argument("--textures", choices=TEXTURE_ENCODINGS, default="original",
                   help="3dtiles: texture images as they are (original), or re-encoded as JPEG (images with "
                        "transparency stay PNG) or WebP (EXT_texture_webp), each kept where that is not smaller")
    p.set_defaults(run=export_command)


def add_view(sub) -> None:
    """The `view` command's parser, on the subparsers `sub`."""
    p = sub.add_parser("view", help="serve a 3D Tiles export and a CesiumJS viewer page on 127.0.0.1; open the browser")
    p.add_argument("dir", metavar="DIR", help="a 3D Tiles export folder (holding tileset.json)")
    p.add_argument("--port", type=whole_number(0), default=0, help="port on 127.0.0.1 (default 0: a free one)")
    p.add_argument("--no-browser", action="store_true", help="only serve (scripts, remote machines)")
    p.add_argument("--cesium", metavar="DIR",
                   help="CesiumJS's Build/Cesium folder (default: tools/viewer's npm install)")
    p.set_defaults(run=view_command)


def info_command(args: argparse.Namespace) -> dict:
    """`info`: the file's summary, its invariant checks (bake.checks) and what it was baked from."""
    started = time.perf_counter()
    hlod = hlod_file.load(args.file)
    open_seconds = time.perf_counter() - started
    out = hlod.summary()
    out.update(checks.check(hlod))
    out.update(file=str(args.file), open_seconds=open_seconds, target_tris=hlod.meta.get("target_tris"),
               max_depth=hlod.meta.get("max_depth"), sources=hlod.meta.get("sources"),
               has_normals=hlod.normals is not None)
    return out


def export_command(args: argparse.Namespace) -> dict:
    """`export`: the export's summary (export.formats.export_hlod)."""
    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise InputError(f"-o {out}: is a file, expected a folder")
    place = chosen(args.place)
    if place is not None and args.format != "3dtiles":
        raise InputError(f"--place: only for --format 3dtiles (a .hlod has no place on the globe), not {args.format}")
    hlod = hlod_file.load(args.file)
    return export_hlod(hlod, args.format, out, stem=Path(args.file).stem, place=place, mesh=args.mesh,
                       textures=args.textures, merge_leaves=args.merge_leaves)


def view_command(args: argparse.Namespace) -> dict:
    """`view`: serve until Ctrl-C or SIGTERM (a normal end: exit 0). The URL is the first stdout line."""
    from ..export import viewer

    url = viewer.serve_until_stopped(args.dir, port=args.port, cesium_dir=args.cesium,
                                     open_browser=not args.no_browser, on_serving=_print_url)
    return {"url": url, "dir": str(args.dir)}


def _print_url(url: str) -> None:
    """The view command's first stdout line, flushed at once (scripts wait for it)."""
    print(url, flush=True)
