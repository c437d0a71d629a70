"""The add-on's background command (`blender -b [FILE.blend] --command hlod ...`) through the bpy
module, for machines with the bpy wheel and no Blender install:

    .venv/bin/python scripts/hlod_blender.py bake A.blend B.blend -o OUTDIR --format hlod 3dtiles
    .venv/bin/python scripts/hlod_blender.py export IN.hlod --format 3dtiles -o DIR
    .venv/bin/python scripts/hlod_blender.py --extension-repo REPO_DIR bake ...
    .venv/bin/python scripts/hlod_blender.py --help

Same arguments, output and exit status as the Blender command (addon/cli.py). The add-on comes from
this source folder, or with `--extension-repo REPO_DIR` (first) from an extension repository made by
`blender_ext.py install-files`, enabled as Blender enables it: its dependencies are then the wheels
in its zip, installed by Blender's extension code, as in a Blender without pymeshlab or moderngl.
"""
import importlib
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_preview

REPO_OPTION = "--extension-repo"


def main(argv: list[str]) -> int:
    if argv[:1] == [REPO_OPTION]:
        if len(argv) < 2 or not (Path(argv[1]) / "hlod" / "blender_manifest.toml").is_file():
            where = argv[1] if len(argv) > 1 else "(none given)"
            print(f"hlod_blender: {REPO_OPTION} {where}: not an extension repository holding hlod "
                  "(make one with blender_ext.py install-files --local-dir DIR hlod-*.zip)", file=sys.stderr)
            return 2
        package = blender_preview.enable_from_repo(argv[1])
        argv = argv[2:]
    else:
        package = blender_preview.enable_from_source()
    cli = importlib.import_module(package.__name__ + ".addon.cli")
    try:
        return cli.execute(argv)
    finally:
        package.unregister()


if __name__ == "__main__":
    blender_preview.exit_process(main(sys.argv[1:]))
