"""Build the Blender extension zip(s) with Blender's own extension tool.

    .venv/bin/python scripts/build_extension.py [--platforms linux-x64 windows-x64 macos-arm64] [--output-dir dist]
                                                [--viewer auto|bundle|none] [--cesium CESIUM_DIR] [--download-only]

One zip per platform and Blender line: Blender 4.2 to 5.0 run Python 3.11, 5.1 and later 3.13
(BLENDER_LINES), and a zip carries the wheels of its line's Python only, with blender_version_min
and blender_version_max set so that Blender offers each Blender the zip it can load (the extension
platform lists both; Install from Disk of the other one is refused by Blender). First the wheels
the manifest lists for the platforms are downloaded into ./wheels/ (pip, from PyPI, once, every
platform and Python at once; later builds reuse them; --download-only stops there). For each
platform and line, stage the package files with a manifest narrowed to that platform, that
line's wheels and versions, and run `blender_ext.py build` (shipped in the bpy wheel of the
interpreter running this script, whichever Blender version that is) on the stage, then
`blender_ext.py validate` on the zip, check that its glcontext wheel holds the modules the GL context
imports on that platform (`gl_modules`), and name it hlod-VERSION-LINE-PLATFORM.zip (e.g.
hlod-0.1.0-blender-4.2-5.0-linux_x64.zip). Prints one line per zip: its path.

The 3D Tiles viewer: CesiumJS's built files (npm `cesium/Build/Cesium`, installed into
tools/viewer by scripts/bootstrap.sh, or --cesium) go into the zip as viewer/cesium/, where
hlod_core.export.viewer.find_cesium looks in an installed extension, with Cesium's licence, less its
JavaScript-module entry points (index.js, index.cjs: the page loads Cesium.js). About 6 MB zipped;
nothing of it is read unless View in Browser or `--command hlod view` is used. --viewer auto (the
default) bundles it when found and otherwise builds without it, saying so on stderr; --viewer
bundle stops the build when it is not found; --viewer none leaves it out.
"""
from __future__ import annotations

import argparse
import csv
import io
import re
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import tomllib
import zipfile
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from hlod_core.core.atomic import atomic_file  # the project's one atomic write
from zip_rename import copy_renamed  # scripts/ is on the path: this script's folder

ROOT = Path(__file__).resolve().parents[1]

WHEELS = ROOT / "wheels"
FLAT_WHEELS = WHEELS / "flat"  # wheels rewritten for Blender 4.2's installer (see blender_ready)
PACKAGE = ["__init__.py", "blender_manifest.toml", "addon", "operators", "panels", "hlod_core", "LICENSE"]
PIP_PLATFORMS = {
    "linux-x64": ["manylinux_2_35_x86_64", "manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64",
                  "manylinux_2_5_x86_64", "manylinux1_x86_64"],
    "windows-x64": ["win_amd64"],
    "macos-arm64": ["macosx_11_0_arm64"],
}
WHEEL_PLATFORM = {"linux-x64": "linux", "windows-x64": "win_amd64", "macos-arm64": "macosx_11_0_arm64"}
#: sys.platform on each platform: which branch of hlod_core.render.gl_platform runs there, and so which
#: glcontext modules the zip's glcontext wheel must hold (`gl_modules`).
SYS_PLATFORM = {"linux-x64": "linux", "windows-x64": "win32", "macos-arm64": "darwin"}
# The Pythons of the Blenders we support, as wheel tags: 3.11 (Blender 4.2 LTS to 5.0), 3.13 (5.1 on).
PYTHON_TAGS = {"cp311": "3.11", "cp313": "3.13"}


@dataclass(frozen=True)
class BlenderLine:
    """The Blenders of one Python: the zip's name part and its manifest's version range
    (blender_version_max is exclusive, as Blender reads it; None: open)."""

    label: str
    python_tag: str
    version_min: str
    version_max: str | None


BLENDER_LINES = (BlenderLine("blender-4.2-5.0", "cp311", "4.2.0", "5.1.0"),
                 BlenderLine("blender-5.1", "cp313", "5.1.0", None))
#: in the zip: where hlod_core.export.viewer.find_cesium looks (<hlod_core>/../viewer/cesium)
VIEWER_CESIUM = "viewer/cesium"
CESIUM_LEFT_OUT = ("index.js", "index.cjs")  # Build/Cesium's module entry points (9 MB); the page loads Cesium.js
# The extension tool inside a bpy wheel: bpy/<major.minor>/scripts/addons_core/bl_pkg/cli/blender_ext.py
BLENDER_EXT_GLOB = "bpy/[0-9]*.[0-9]*/scripts/addons_core/bl_pkg/cli/blender_ext.py"


def blender_ext(platlib: str | None = None) -> Path:
    """The extension tool inside the bpy wheel installed for this interpreter (or in `platlib`),
    found without importing bpy; its folder is named after the bpy version (4.2, 5.0, 5.2, ...)."""
    site = Path(platlib or sysconfig.get_paths()["platlib"])
    tools = sorted(site.glob(BLENDER_EXT_GLOB))
    if len(tools) != 1:
        sys.exit(f"build_extension: {site}: expected one bpy wheel with blender_ext.py, found {len(tools)}")
    return tools[0]


def wheel_tags(wheel: str) -> tuple[str, str]:
    """(distribution name, Python tag) of a wheel file name (name-ver[-build]-python-abi-platform.whl)."""
    parts = Path(wheel).name[:-len(".whl")].split("-")
    return parts[0], parts[-3]


def wheels_for(manifest: dict, platform: str) -> list[str]:
    """The platform's wheels; exits naming the manifest if a dependency lacks a wheel for one of the
    PYTHON_TAGS there (a Blender with that Python could not load the extension)."""
    tag = WHEEL_PLATFORM[platform]
    wheels = [w for w in manifest["wheels"] if tag in Path(w).name]
    have = {wheel_tags(w) for w in wheels}
    names = sorted({name for name, _ in have})
    missing = [f"{name} {python}" for name in names for python in PYTHON_TAGS if (name, python) not in have]
    if not wheels or missing:
        sys.exit(f"build_extension: blender_manifest.toml: {platform} lacks wheels for "
                 f"{', '.join(missing) or 'every dependency'}")
    return wheels


def download(wanted: dict[str, list[str]]) -> None:
    """pip-download the missing wheels of each platform ({platform: its wheels}): one pip call per
    platform and Python tag (pip resolves for one platform and Python), all at once (each waits
    mostly on the network, and each writes other files)."""
    missing = {platform: [w for w in wheels if not (ROOT / w).is_file()] for platform, wheels in wanted.items()}
    calls = []
    for platform, wheels in missing.items():
        for python_tag, python_version in PYTHON_TAGS.items():
            specs = [f"{wheel_tags(w)[0]}=={Path(w).name.split('-')[1]}" for w in wheels
                     if wheel_tags(w)[1] == python_tag]
            if not specs:
                continue
            cmd = [sys.executable, "-m", "pip", "download", "--disable-pip-version-check", "-q", "--no-deps",
                   "--only-binary=:all:", "--python-version", python_version, "-d", str(WHEELS)]
            for tag in PIP_PLATFORMS[platform]:
                cmd += ["--platform", tag]
            calls.append(cmd + specs)
    if not calls:
        return
    WHEELS.mkdir(exist_ok=True)
    running = [subprocess.Popen(cmd) for cmd in calls]
    failed = [cmd for cmd, process in zip(calls, running) if process.wait() != 0]
    if failed:
        sys.exit(f"build_extension: pip download failed: {' '.join(failed[0][-3:])}")
    still = [w for wheels in missing.values() for w in wheels if not (ROOT / w).is_file()]
    if still:
        sys.exit(f"build_extension: pip did not produce {', '.join(still)} (update blender_manifest.toml)")


def blender_ready(wheel: Path, flat_dir: Path = FLAT_WHEELS) -> Path:
    """The wheel in a form every supported Blender installs. Blender 4.2 LTS's extension wheel
    installer (`_bpy_internal/extensions/wheel_manager.py`) unzips a wheel into site-packages as it
    is: unlike pip (and Blender 5.0's installer) it does not move a `<dist>.data/purelib/` or
    `platlib/` payload to the root, and pymeshlab 2025.7.post1 ships its package there, so in 4.2
    `import pymeshlab` failed. Such a wheel is rewritten once into `flat_dir` under the same name:
    the same files with the payload at the root and RECORD's paths to match. Other wheels are used as
    they are; a wheel with other `.data` folders (scripts, headers, data) stops the build."""
    with zipfile.ZipFile(wheel) as src:
        names = src.namelist()
        data_dir = next((n.split("/")[0] for n in names if n.split("/")[0].endswith(".data")), None)
        if data_dir is None:
            return wheel
        payload = (f"{data_dir}/purelib/", f"{data_dir}/platlib/")
        other = sorted({n.split("/")[1] for n in names if n.startswith(data_dir + "/") and not n.startswith(payload)})
        if other:
            sys.exit(f"build_extension: {wheel.name}: .data folders {', '.join(other)} are not installed by Blender")
        flat = flat_dir / wheel.name
        if flat.is_file() and flat.stat().st_mtime >= wheel.stat().st_mtime:
            return flat
        flat.parent.mkdir(exist_ok=True)

        def moved(name: str) -> str:
            return next((name[len(p):] for p in payload if name.startswith(p)), name)

        def record(data: bytes) -> bytes:  # CSV: path, hash, size
            rows = [[moved(row[0]), *row[1:]] for row in csv.reader(io.StringIO(data.decode("utf-8"))) if row]
            text = io.StringIO()
            csv.writer(text, lineterminator="\n").writerows(rows)
            return text.getvalue().encode("utf-8")

        # atomic: builds running at once each write a private temporary file, then rename it; the members'
        # compressed bytes are copied, not deflated again (zip_rename)
        with atomic_file(flat) as f:
            copy_renamed(wheel, f, moved, lambda name: record if name.endswith(".dist-info/RECORD") else None)
    return flat


def check_zip(zip_path: Path, wheels: list[str]) -> None:
    """The zip holds every file and folder of PACKAGE (the licence among them) and exactly `wheels`
    (its platform's, of its Blender line's Python)."""
    names = zipfile.ZipFile(zip_path).namelist()
    left_out = [p for p in PACKAGE if p not in names and not any(n.startswith(f"{p}/") for n in names)]
    if left_out:
        sys.exit(f"build_extension: {zip_path}: lacks {', '.join(left_out)} (listed to ship in PACKAGE)")
    held = sorted(n for n in names if n.startswith("wheels/") and n.endswith(".whl"))
    want = sorted(f"wheels/{Path(w).name}" for w in wheels)
    if held != want:
        sys.exit(f"build_extension: {zip_path}: holds wheels {held}, the manifest lists {want}")


def gl_modules(platform: str) -> list[str]:
    """The glcontext modules the standalone GL context imports on `platform`, in the order it tries
    them (hlod_core.render.gl_platform.STANDALONE_BACKENDS): e.g. ["glcontext.egl", "glcontext.x11"]."""
    from hlod_core.render.gl_platform import STANDALONE_BACKENDS, platform_family

    return [f"glcontext.{name}" for name in STANDALONE_BACKENDS[platform_family(SYS_PLATFORM[platform])]]


def compiled_modules(wheel: zipfile.ZipFile, python_tag: str) -> set[str]:
    """The extension modules in a wheel built for `python_tag` ("cp311"), as dotted names: a
    `pkg/name.cpython-311-....so` or `pkg/name.cp311-....pyd` file gives "pkg.name"."""
    abi = (f"cpython-{python_tag[2:]}", python_tag)
    found = set()
    for name in wheel.namelist():
        stem, _, suffix = name.rpartition("/")[2].partition(".")
        if suffix.startswith(abi) and suffix.endswith((".so", ".pyd")):
            found.add(name.rpartition("/")[0].replace("/", ".") + "." + stem)
    return found


def check_gl_modules(zip_path: Path, platform: str, python_tag: str) -> None:
    """The zip's glcontext wheel holds every module `gl_modules(platform)` names, built for
    `python_tag`: without them the preview, Benchmark and Tune to PSNR would have no GL context."""
    with zipfile.ZipFile(zip_path) as z:
        wheels = [n for n in z.namelist() if n.startswith("wheels/glcontext-") and n.endswith(".whl")]
        if len(wheels) != 1:
            sys.exit(f"build_extension: {zip_path}: expected one glcontext wheel, found {wheels}")
        with zipfile.ZipFile(io.BytesIO(z.read(wheels[0]))) as wheel:
            held = compiled_modules(wheel, python_tag)
    missing = [m for m in gl_modules(platform) if m not in held]
    if missing:
        sys.exit(f"build_extension: {zip_path}: {wheels[0]} lacks {', '.join(missing)} ({python_tag}), which the GL "
                 f"context imports on {platform} (it holds {', '.join(sorted(held)) or 'none'})")


def cesium_build(mode: str, explicit: str | None) -> Path | None:
    """The CesiumJS folder to bundle (mode "auto", "bundle", "none"), found as the extension finds
    it at run time (hlod_core.export.viewer.find_cesium: --cesium, $HLOD_CESIUM_DIR, tools/viewer's npm
    install); None to build without it. Exits naming where it looked when "bundle" finds none."""
    if mode == "none":
        return None
    if explicit:
        if not (Path(explicit) / "Cesium.js").is_file():
            sys.exit(f"build_extension: --cesium {explicit}: no Cesium.js there (give npm's cesium/Build/Cesium)")
        return Path(explicit).resolve()
    from hlod_core.core.errors import InputError
    from hlod_core.export import viewer

    try:
        return viewer.find_cesium()
    except InputError as exc:
        if mode == "bundle":
            sys.exit(f"build_extension: --viewer bundle: {exc}")
        print(f"build_extension: building without the 3D Tiles viewer's CesiumJS ({exc}); "
              "View in Browser will then need $HLOD_CESIUM_DIR", file=sys.stderr)
        return None


def stage_cesium(cesium: Path, where: Path) -> None:
    """Copy the CesiumJS build to where/viewer/cesium (less CESIUM_LEFT_OUT at its top) with the
    npm package's licence (Apache-2.0) beside it."""
    def ignore(folder: str, names: list[str]) -> list[str]:
        return [n for n in names if n in CESIUM_LEFT_OUT or n == "__pycache__"] if Path(folder) == cesium else []

    target = where / VIEWER_CESIUM
    shutil.copytree(cesium, target, ignore=ignore)
    for licence in ("LICENSE.md", "ThirdParty.json"):
        if (cesium.parents[1] / licence).is_file():  # cesium/Build/Cesium -> cesium/
            shutil.copy2(cesium.parents[1] / licence, target / licence)


def stage(manifest_text: str, platform: str, wheels: list[str], *, where: Path, cesium: Path | None = None,
          line: BlenderLine | None = None) -> Path:
    """A fresh staging folder `where` of the package files, the wheels (as blender_ready gives them)
    and the manifest narrowed to that platform, those wheels and `line`'s Blender versions, with
    CesiumJS when `cesium` is given; returns it. Exits naming any file of PACKAGE that is missing."""
    if where.exists():
        shutil.rmtree(where)
    where.mkdir(parents=True)
    missing = [name for name in PACKAGE if not (ROOT / name).exists()]
    if missing:
        sys.exit(f"build_extension: {', '.join(missing)}: listed to ship (PACKAGE) but missing in {ROOT}")
    for name in PACKAGE:
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, where / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            shutil.copy2(src, where / name)
    (where / "wheels").mkdir()
    for w in wheels:
        (where / w).symlink_to(blender_ready(ROOT / w))
    text = re.sub(r"(?ms)^platforms = \[.*?\]\n", f'platforms = ["{platform}"]\n', manifest_text)
    text = re.sub(r"(?ms)^wheels = \[.*?\]\n", "wheels = [\n" + "".join(f'  "{w}",\n' for w in wheels) + "]\n", text)
    if line is not None:
        versions = f'blender_version_min = "{line.version_min}"\n'
        if line.version_max is not None:
            versions += f'blender_version_max = "{line.version_max}"\n'
        text = re.sub(r"(?m)^blender_version_min = .*\n(blender_version_max = .*\n)?", versions, text)
    (where / "blender_manifest.toml").write_text(text)
    if cesium is not None:
        stage_cesium(cesium, where)
    return where


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--platforms", nargs="+", default=list(PIP_PLATFORMS), choices=list(PIP_PLATFORMS))
    parser.add_argument("--output-dir", default=str(ROOT / "dist"))
    parser.add_argument("--viewer", choices=["auto", "bundle", "none"], default="auto",
                        help="bundle CesiumJS for View in Browser: when found (auto), or stop if not found (bundle)")
    parser.add_argument("--cesium", metavar="CESIUM_DIR", help="CesiumJS's Build/Cesium folder (default: found)")
    parser.add_argument("--download-only", action="store_true",
                        help="only download the platforms' wheels into wheels/ (as test.sh's set-up does)")
    args = parser.parse_args()
    manifest_text = (ROOT / "blender_manifest.toml").read_text()
    manifest = tomllib.loads(manifest_text)
    wanted = {platform: wheels_for(manifest, platform) for platform in args.platforms}
    download(wanted)
    if args.download_only:
        return
    tool = blender_ext()
    cesium = cesium_build(args.viewer, args.cesium)
    out = Path(args.output_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    for platform, wheels in wanted.items():
        for line in BLENDER_LINES:
            print(build_zip(manifest_text, manifest, platform, line=line, wheels=wheels, out=out, tool=tool,
                            cesium=cesium))


def build_zip(manifest_text: str, manifest: dict, platform: str, *, line: BlenderLine, wheels: list[str], out: Path,
              tool: Path, cesium: Path | None) -> Path:
    """Build, validate and check the zip of one platform and Blender line; its path in `out`."""
    line_wheels = [w for w in wheels if wheel_tags(w)[1] == line.python_tag]
    name = f"{manifest['id']}-{manifest['version']}-{line.label}-{platform.replace('-', '_')}.zip"
    # a private staging and output folder: test runs of several Blender versions may build at once
    with tempfile.TemporaryDirectory(prefix=f"hlod-stage-{platform}-{line.python_tag}-") as tmp:
        where = stage(manifest_text, platform, line_wheels, where=Path(tmp) / "hlod", cesium=cesium, line=line)
        built_dir = Path(tmp) / "dist"
        built_dir.mkdir()
        subprocess.run([sys.executable, str(tool), "build", "--source-dir", str(where), "--output-dir", str(built_dir),
                        "--split-platforms"], check=True, stdout=subprocess.DEVNULL)
        built = sorted(built_dir.glob("*.zip"))
        if len(built) != 1:
            sys.exit(f"build_extension: expected one zip for {platform} {line.label}, got {[b.name for b in built]}")
        subprocess.run([sys.executable, str(tool), "validate", str(built[0])], check=True, stdout=subprocess.DEVNULL)
        check_zip(built[0], line_wheels)
        check_gl_modules(built[0], platform, line.python_tag)
        target = out / name
        shutil.move(built[0], target)
    return target

if __name__ == "__main__":
    main()
