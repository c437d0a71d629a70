"""The extension in the real bpy module: the Blenders the checks run in, the zip built by
scripts/build_extension.py and installed with each Blender's own extension tool, and one check
script of tests/blender/ run in a Blender process (its JSON result). conftest.py's fixtures `extension_zips`, `repo`
and `versioned_repo` are made of these.

BLENDERS: version "X.Y" -> that environment's Python interpreter (.venv-blender/bpy-X.Y, made by
scripts/bootstrap.sh `ensure_blender_venvs`, one per requirements-bpyXY.txt); the main .venv's bpy
is the Blender of `repo`. Each check runs in its own process: bpy keeps global state, and the
user's Blender configuration is kept out of it (BLENDER_USER_RESOURCES points at a temp dir)."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from helpers import ROOT

BLENDER_VENVS = ROOT / ".venv-blender"
#: The check scripts, each run in a Blender process of its own (and the pytest modules that run them).
CHECKS = ROOT / "tests" / "blender"


def _blenders() -> dict[str, Path]:
    """One Blender per requirements-bpyXY.txt: the bpy pin's major.minor names the folder
    .venv-blender/bpy-X.Y, and bin/python there is its interpreter (Python 3.11 or 3.13)."""
    out = {}
    for req in sorted(ROOT.glob("requirements-bpy*.txt")):
        pin = re.search(r"^bpy==(\d+\.\d+)\.\d+", req.read_text(), re.M)
        assert pin, f"{req.name}: no bpy==X.Y.Z line"
        out[pin.group(1)] = BLENDER_VENVS / f"bpy-{pin.group(1)}" / "bin" / "python"
    return out


BLENDERS = _blenders()  # {"4.2": .venv-blender/bpy-4.2/bin/python, "5.0": ..., "5.2": ...}
#: The Blenders whose checks also run under Blender's Vulkan backend, on Mesa's lavapipe (a CPU
#: Vulkan): 5.0 and 5.2. 4.2's Vulkan backend was experimental (Blender offers Vulkan in its
#: Preferences from 4.5) and crashes in its first render there.
VULKAN_BLENDERS = ("5.0", "5.2")
#: The environment of a check under Vulkan: scripts/blender_gpu_backend.py forces the backend
#: before `import bpy` (blender_gpu_backend.VARIABLE).
VULKAN = {"HLOD_GPU_BACKEND": "vulkan"}
#: Where Debian's mesa-vulkan-drivers puts lavapipe's loader manifest.
LAVAPIPE_ICD = Path("/usr/share/vulkan/icd.d/lvp_icd.x86_64.json")


def blender_python(version: str) -> Path:
    """The interpreter of Blender `version`'s environment; a missing one is an error, never a skip:
    the extension checks must run in every Blender we support."""
    python = BLENDERS[version]
    assert python.is_file(), (f"Blender {version}'s environment is missing ({python}): run `bash test.sh`, "
                              f"which makes it (scripts/bootstrap.sh ensure_blender_venvs)")
    return python


def require_lavapipe() -> None:
    """A missing lavapipe is an error, never a skip: the Vulkan checks must run."""
    assert LAVAPIPE_ICD.is_file(), (f"lavapipe is not installed ({LAVAPIPE_ICD} is missing): run `bash test.sh`, "
                                    "which installs mesa-vulkan-drivers (scripts/bootstrap.sh ensure_vulkan)")


@dataclass(frozen=True)
class Installed:
    """The extension installed for one Blender: base/repo is the extension repository, base/user
    the BLENDER_USER_RESOURCES of its processes, python that Blender's interpreter."""
    version: str
    python: Path
    base: Path

    def __truediv__(self, name: str) -> Path:  # `repo / "user"` as with the main .venv's `repo`
        return self.base / name


#: test.sh sets this to one folder for both of its pytest processes: the zips are built there once
#: per run, by whichever process asks first (`built_zips`).
ZIPS_FOLDER_VARIABLE = "HLOD_TEST_ZIPS"


#: The platform whose zips the Blender checks install: built as a release build is, with CesiumJS
#: (the viewer's files, the same in every zip, checked there). The others' zips are read for their
#: wheels and licence only, and built without it (a few seconds instead of a minute under load).
INSTALLED_PLATFORM = "linux-x64"


def built_zips(platforms: list[str], fallback: Path) -> list[Path]:
    """The zips scripts/build_extension.py makes for `platforms` (each Blender line), built once per
    test run: in $HLOD_TEST_ZIPS where test.sh set it (shared by its two pytest processes), else in
    `fallback` (one folder per pytest session). Each platform is built under a file lock by the first
    process to ask for it; the other takes its zips, building the platforms nobody holds first and
    waiting for the one being built last."""
    import fcntl

    folder = Path(os.environ.get(ZIPS_FOLDER_VARIABLE) or fallback)
    folder.mkdir(parents=True, exist_ok=True)
    zips: dict[str, list[Path]] = {}
    while len(zips) < len(platforms):
        pending = [p for p in platforms if p not in zips]
        for platform in pending:
            with open(folder / f"{platform}.lock", "w") as lock:  # the lock goes when the file closes
                try:
                    fcntl.flock(lock, fcntl.LOCK_EX | (fcntl.LOCK_NB if platform != pending[-1] else 0))
                except BlockingIOError:
                    continue  # being built by the other process: the next pass takes it
                zips[platform] = _zips_of(platform, folder)
    return [z for platform in platforms for z in zips[platform]]


def _zips_of(platform: str, folder: Path) -> list[Path]:
    """`platform`'s zips in `folder`, built there first if missing (the caller holds its lock)."""
    listing = folder / f"{platform}.zips"
    if not listing.exists():
        viewer = [] if platform == INSTALLED_PLATFORM else ["--viewer", "none"]
        build = subprocess.run([sys.executable, str(ROOT / "scripts/build_extension.py"), "--platforms", platform,
                                *viewer, "--output-dir", str(folder / platform)],
                               capture_output=True, text=True, timeout=900)
        assert build.returncode == 0, build.stderr
        listing.write_text(build.stdout)
    return [Path(line) for line in listing.read_text().split()]


def build_extension_zips(zips: list[Path]) -> dict[str, Path]:
    """The linux-x64 zips among `zips` (built_zips), one per Blender line: {python tag ("cp311",
    "cp313"): zip path}."""
    lines = build_extension_script().BLENDER_LINES
    linux = [z for z in zips if z.name.endswith(f"-{INSTALLED_PLATFORM.replace('-', '_')}.zip")]
    assert len(linux) == len(lines), zips
    return {line.python_tag: next(z for z in linux if f"-{line.label}-" in z.name) for line in lines}


def line_of(version: str):
    """The build's BlenderLine of Blender `version` ("X.Y"): the zip that Blender installs."""
    wanted = tuple(int(x) for x in version.split("."))
    for line in build_extension_script().BLENDER_LINES:
        low = tuple(int(x) for x in line.version_min.split("."))[:2]
        high = None if line.version_max is None else tuple(int(x) for x in line.version_max.split("."))[:2]
        if low <= wanted and (high is None or wanted < high):
            return line
    raise AssertionError(f"no Blender line of scripts/build_extension.py takes Blender {version}")


def build_extension_script():
    sys.path.insert(0, str(ROOT / "scripts"))
    import build_extension

    return build_extension


def extension_tool(python: Path) -> Path:
    """blender_ext.py of the bpy installed for `python` (whichever version)."""
    build_extension = build_extension_script()
    platlib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['platlib'])"],
                             capture_output=True, text=True, check=True).stdout.strip()
    return build_extension.blender_ext(platlib)


def install_extension(zip_path: Path, python: Path, base: Path) -> Path:
    """Validate the zip and install it into base/repo with that Blender's own extension tool, as
    Blender does; base/user is its processes' user folder. Returns `base`."""
    (base / "repo").mkdir()
    tool = extension_tool(python)
    for args in (["validate", str(zip_path)], ["install-files", "--local-dir", str(base / "repo"), str(zip_path)]):
        proc = subprocess.run([str(python), str(tool), *args], capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, f"{tool} {args[0]}: {proc.stdout[-2000:]}{proc.stderr[-2000:]}"
    (base / "user").mkdir()
    return base


def blender(repo, check: str, tmp_path, *arguments: str, timeout_s: float = 600, quiet: bool = False,
            script: str = "blender_checks.py", env: dict[str, str] | None = None) -> dict:
    """Run tests/blender/SCRIPT CHECK TMP [ARGUMENTS] in `repo`'s Blender (an Installed; a plain folder is the
    main .venv's); its JSON result. quiet: the process must print nothing on stderr (no warnings).
    env: variables set for that process on top of this one's (read before its GPU starts).
    timeout_s guards against a hang only."""
    python, base = (repo.python, repo.base) if isinstance(repo, Installed) else (Path(sys.executable), Path(repo))
    temp = Path(tmp_path) / "blender-temp"  # Blender's own temp folder (blender_XXXXXX), which a bpy
    temp.mkdir(exist_ok=True)                # process that ends through os._exit leaves behind
    env = {**os.environ, **(env or {}), "BLENDER_USER_RESOURCES": str(base / "user"), "PYTHONPATH": str(ROOT),
           "TMPDIR": str(temp)}
    proc = subprocess.run([str(python), str(CHECKS / script), str(base / "repo"), check, str(tmp_path), *arguments],
                          capture_output=True, text=True, timeout=timeout_s, env=env, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert not (quiet and proc.stderr), proc.stderr[-4000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def all_hold(out: dict, **checks: bool) -> None:
    """Assert every named check of one check's result at once, so a failing run lists every check
    that failed (and the result), not only the first."""
    failed = sorted(name for name, ok in checks.items() if not ok)
    assert not failed, f"failed: {failed}; result: {json.dumps(out, default=str)[:4000]}"
