"""Command line of the core: `python -m hlod_core COMMAND ...` (docs/command-line.md).

Contract (later checks rely on it): the last line of stdout is one JSON object; progress and
messages go to stderr (-q: errors only); bad input, a bad argument or a failed write exits with
status 2 and one line naming the file and the fault. Ctrl-C exits 130 with `hlod_core:
interrupted`, SIGTERM / SIGHUP exit 128 + n with `hlod_core: terminated by SIG...`; either way
after removing scratch files and partial outputs. `-o` of a file refuses a name that ends in a
path separator (it names a folder).

    bake INPUT [INPUT ...] -o OUT.hlod [...]         bake.py (embedded images: io/texture_folder.py)
    scene low|middle|high|default -o OUT.hlod [...]  bake.py
    run FILE.hlod --method M [...]                   run.py
    evaluate FILE.hlod --out DIR [...]               run.py
    info FILE.hlod                                   files.py
    export IN.hlod --format 3dtiles|hlod -o DIR      files.py
    view DIR [--port N] [--no-browser]               files.py
main.py: `main(argv)` (the exit status) and `build_parser()`; options.py: argument types, the
option groups several commands share and the settings they make. This package imports none of its
modules (each imports its siblings): `python -m hlod_core` runs `hlod_core.cli.main.main`.
"""
