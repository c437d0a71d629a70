"""The add-on's background command (`blender -b [FILE.blend] --command hlod ...`) through the bpy
module, for machines with the bpy wheel and no Blender install:

    .venv/bin/python scripts/hlod_blender.py bake A.blend B.blend -o OUTDIR --format hlod 3dtiles
    .venv/bin/python scripts/hlod_blender.py export IN.hlod --format 3dtiles -o DIR
    .venv/bin/python scripts/hlod_blender.py --help

Same arguments, output and exit status as the Blender command (addon/cli.py).
"""
import importlib
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_preview  # noqa: E402


def main() -> int:
    package = blender_preview.enable_from_source()
    cli = importlib.import_module(package.__name__ + ".addon.cli")
    try:
        return cli.execute(sys.argv[1:])
    finally:
        package.unregister()


if __name__ == "__main__":
    blender_preview.exit_process(main())
