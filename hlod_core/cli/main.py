"""`python -m hlod_core`: the parser of every command, and `main`, which runs one and keeps the
command line's contract (hlod_core/cli/__init__.py: the JSON last line, the exit statuses)."""
from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import warnings

from ..core.errors import HlodError
from ..core.signals import Terminated, signals_as_exceptions
from . import bake, files, run
from .options import Parser

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


#: Where every command and option is described (the parsers' help is the short form).
DOCS = "docs/command-line.md"


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    """The parser of the command line: every command and option (docs/command-line.md lists them),
    named `prog` in its usage and errors (None: the name it was run by, program_name()). Each
    command's `run` default is the function that carries it out (args -> the JSON summary)."""
    parser = Parser(prog=prog or program_name(), description="Bake and inspect octree HLODs.",
                    epilog=f"Every command, option and input file format: {DOCS} in the source repository.")
    parser.add_argument("-q", "--quiet", action="store_true", help="only errors on stderr")
    sub = parser.add_subparsers(dest="command", required=True)
    for add_command in (bake.add_bake, files.add_info, run.add_run, run.add_evaluate, files.add_export,
                        files.add_view, bake.add_scene):  # the order of `--help`
        add_command(sub)
    return parser


def program_name(argv0: str | None = None) -> str:
    """The name the command line was run by, from `argv0` (default sys.argv[0]): `python -m
    hlod_core` for the module (argv0 is then its __main__.py), else the file name of the script
    (`hlod-core`, pip's entry point)."""
    argv0 = sys.argv[0] if argv0 is None else argv0
    name = os.path.basename(argv0)
    return "python -m hlod_core" if name in ("", "__main__.py") or name.startswith("-") else name


def _log_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """warnings.showwarning for a command: one log line (hidden by -q), not the two-line default.
    (Its positional parameters are warnings.showwarning's.)"""
    log.warning("%s: %s (%s:%d)", category.__name__, message, os.path.basename(filename), lineno)


def _output_of(args) -> str:
    """The file or folder a command writes (for an OSError that names no file)."""
    for name in ("output", "out", "save_path", "save_frames", "file"):
        value = getattr(args, name, None)
        if value is not None:
            return str(value)
    return "hlod_core"
