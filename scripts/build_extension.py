"""Build the Blender extension zip(s) with Blender's own extension tool.

    .venv/bin/python scripts/build_extension.py [--platforms linux-x64 windows-x64 macos-arm64] [--output-dir dist]

For each platform: download the wheels the manifest lists for it into ./wheels/ (pip, from PyPI,
once; later builds reuse them), stage the package files with a manifest narrowed to that platform
and its wheels, and run `blender_ext.py build` (shipped in the bpy wheel) on the stage, then
`blender_ext.py validate` on the zip. Prints one line per zip: its path.
"""
from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import sysconfig
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WHEELS = ROOT / "wheels"
PACKAGE = ["__init__.py", "blender_manifest.toml", "addon", "operators", "panels", "hlod_core", "LICENSE"]
PIP_PLATFORMS = {
    "linux-x64": ["manylinux_2_35_x86_64", "manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64",
                  "manylinux_2_5_x86_64", "manylinux1_x86_64"],
    "windows-x64": ["win_amd64"],
    "macos-arm64": ["macosx_11_0_arm64"],
}
WHEEL_PLATFORM = {"linux-x64": "linux", "windows-x64": "win_amd64", "macos-arm64": "macosx_11_0_arm64"}


def blender_ext() -> Path:
    """The extension tool inside the installed bpy wheel (found without importing bpy)."""
    tool = Path(sysconfig.get_paths()["platlib"]) / "bpy/5.0/scripts/addons_core/bl_pkg/cli/blender_ext.py"
    if not tool.is_file():
        sys.exit(f"build_extension: Blender's extension tool not found at {tool}")
    return tool


def wheels_for(manifest: dict, platform: str) -> list[str]:
    tag = WHEEL_PLATFORM[platform]
    return [w for w in manifest["wheels"] if tag in Path(w).name]


def download(wheels: list[str], platform: str) -> None:
    missing = [w for w in wheels if not (ROOT / w).is_file()]
    if not missing:
        return
    WHEELS.mkdir(exist_ok=True)
    specs = []
    for w in missing:
        name, version = Path(w).name.split("-")[:2]
        specs.append(f"{name}=={version}")
    cmd = [sys.executable, "-m", "pip", "download", "--disable-pip-version-check", "-q", "--no-deps",
           "--only-binary=:all:", "--python-version", "3.11", "-d", str(WHEELS)]
    for tag in PIP_PLATFORMS[platform]:
        cmd += ["--platform", tag]
    subprocess.run(cmd + specs, check=True)
    still = [w for w in missing if not (ROOT / w).is_file()]
    if still:
        sys.exit(f"build_extension: pip did not produce {', '.join(still)} (update blender_manifest.toml)")


def stage(manifest_text: str, manifest: dict, platform: str, wheels: list[str], where: Path) -> Path:
    if where.exists():
        shutil.rmtree(where)
    where.mkdir(parents=True)
    for name in PACKAGE:
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, where / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        elif src.is_file():
            shutil.copy2(src, where / name)
    (where / "wheels").mkdir()
    for w in wheels:
        (where / w).symlink_to(ROOT / w)
    text = re.sub(r"(?ms)^platforms = \[.*?\]\n", f'platforms = ["{platform}"]\n', manifest_text)
    text = re.sub(r"(?ms)^wheels = \[.*?\]\n", "wheels = [\n" + "".join(f'  "{w}",\n' for w in wheels) + "]\n", text)
    (where / "blender_manifest.toml").write_text(text)
    return where


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--platforms", nargs="+", default=list(PIP_PLATFORMS), choices=list(PIP_PLATFORMS))
    parser.add_argument("--output-dir", default=str(ROOT / "dist"))
    args = parser.parse_args()
    tool = blender_ext()
    manifest_text = (ROOT / "blender_manifest.toml").read_text()
    manifest = tomllib.loads(manifest_text)
    out = Path(args.output_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    for platform in args.platforms:
        wheels = wheels_for(manifest, platform)
        download(wheels, platform)
        where = stage(manifest_text, manifest, platform, wheels, ROOT / "stage" / platform)
        subprocess.run([sys.executable, str(tool), "build", "--source-dir", str(where), "--output-dir", str(out),
                        "--split-platforms"], check=True, stdout=subprocess.DEVNULL)
        zips = sorted(out.glob(f"{manifest['id']}-{manifest['version']}-{platform.replace('-', '_')}.zip"))
        if not zips:
            sys.exit(f"build_extension: no zip for {platform} in {out}")
        subprocess.run([sys.executable, str(tool), "validate", str(zips[-1])], check=True, stdout=subprocess.DEVNULL)
        shutil.rmtree(where)
        print(zips[-1])


if __name__ == "__main__":
    main()
