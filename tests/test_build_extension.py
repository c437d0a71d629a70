"""scripts/build_extension.py on tiny literal inputs: the manifest's wheels per platform and Python,
the extension tool found in any bpy version, wheels rewritten for Blender 4.2's installer, and the
licence in the zip (a file listed to ship and missing stops the build); and on every zip it builds:
the glcontext modules the GL context imports on each platform are in its wheel."""
import csv
import io
import sys
import tomllib
import types
import zipfile

import pytest

from helpers import ROOT

sys.path.insert(0, str(ROOT / "scripts"))
import build_extension

DEPENDENCIES = {"pymeshlab", "moderngl", "glcontext", "xatlas"}


def test_manifest_lists_cp311_and_cp313_wheels_of_every_dependency_for_every_platform():
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    for platform in manifest["platforms"]:
        tags = {build_extension.wheel_tags(w) for w in build_extension.wheels_for(manifest, platform)}
        assert tags == {(name, python) for name in DEPENDENCIES for python in ("cp311", "cp313")}, platform


def test_a_platform_without_a_python_stops_the_build_naming_the_manifest():
    manifest = {"wheels": ["./wheels/moderngl-5.13.0-cp311-cp311-win_amd64.whl"]}
    with pytest.raises(SystemExit) as stop:
        build_extension.wheels_for(manifest, "windows-x64")
    assert str(stop.value) == "build_extension: blender_manifest.toml: windows-x64 lacks wheels for moderngl cp313"


def test_extension_tool_found_in_any_bpy_version_and_only_one(tmp_path):
    tool = tmp_path / "bpy/4.2/scripts/addons_core/bl_pkg/cli/blender_ext.py"
    tool.parent.mkdir(parents=True)
    tool.write_text("")
    assert build_extension.blender_ext(str(tmp_path)) == tool
    (tmp_path / "bpy/5.2/scripts/addons_core/bl_pkg/cli").mkdir(parents=True)
    (tmp_path / "bpy/5.2/scripts/addons_core/bl_pkg/cli/blender_ext.py").write_text("")
    with pytest.raises(SystemExit, match="expected one bpy wheel with blender_ext.py, found 2"):
        build_extension.blender_ext(str(tmp_path))


def _wheel(path, files: dict[str, bytes]):
    record = io.StringIO()
    csv.writer(record, lineterminator="\n").writerows([[name, "sha256=x", len(data)] for name, data in files.items()])
    with zipfile.ZipFile(path, "w") as z:
        for name, data in files.items():
            z.writestr(name, data)
        z.writestr("demo-1.0.dist-info/RECORD", record.getvalue() + "demo-1.0.dist-info/RECORD,,\n")
    return path


def test_a_data_payload_moves_to_the_wheel_root_for_blender_4_2(tmp_path):
    """pymeshlab's layout: the package under demo-1.0.data/purelib/. Blender 4.2 unzips wheels as
    they are, so the package must sit at the root; same bytes, RECORD paths to match."""
    src = _wheel(tmp_path / "demo-1.0-cp311-cp311-linux_x86_64.whl",
                 {"demo-1.0.data/purelib/demo/__init__.py": b"X = 1\n", "demo-1.0.data/platlib/demo_c.so": b"\0elf"})
    flat = build_extension.blender_ready(src, tmp_path / "flat")
    assert flat == tmp_path / "flat" / src.name
    with zipfile.ZipFile(flat) as z:
        assert sorted(z.namelist()) == ["demo-1.0.dist-info/RECORD", "demo/__init__.py", "demo_c.so"]
        assert z.read("demo/__init__.py") == b"X = 1\n" and z.read("demo_c.so") == b"\0elf"
        rows = list(csv.reader(io.StringIO(z.read("demo-1.0.dist-info/RECORD").decode())))
    assert [r[0] for r in rows] == ["demo/__init__.py", "demo_c.so", "demo-1.0.dist-info/RECORD"]
    assert build_extension.blender_ready(src, tmp_path / "flat") == flat  # made once, then reused


def test_members_are_copied_renamed_with_their_bytes_dates_and_attributes(tmp_path):
    """zip_rename copies members compressed as they are (deflated, stored, written with a data
    descriptor through an unseekable stream, a non-ASCII name); Python's zipfile reads the copy back,
    CRCs included, and only the rewritten member has new content."""
    from zip_rename import copy_renamed

    class Unseekable(io.RawIOBase):  # zipfile then writes each member's sizes in a data descriptor
        def __init__(self, target):
            self.target = target

        def writable(self):
            return True

        def write(self, data):
            return self.target.write(data)

    src = tmp_path / "src.zip"
    members = {"pkg.data/platlib/a.py": (b"A = 1\n" * 500, zipfile.ZIP_DEFLATED),
               "pkg.data/platlib/b.bin": (bytes(range(256)) * 40, zipfile.ZIP_STORED),
               "pkg.data/platlib/ünï.txt": ("café".encode() * 100, zipfile.ZIP_DEFLATED),
               "pkg-1.0.dist-info/RECORD": (b"old\n", zipfile.ZIP_DEFLATED)}
    with open(src, "wb") as f, zipfile.ZipFile(Unseekable(f), "w") as z:
        for number, (name, (data, method)) in enumerate(members.items()):
            info = zipfile.ZipInfo(name, (2020, 1 + number, 2, 3, 4, 6))
            info.compress_type, info.external_attr = method, (0o755 if number == 0 else 0o644) << 16
            z.writestr(info, data)
    with open(tmp_path / "copy.zip", "wb") as f:
        copy_renamed(src, f, lambda name: name.replace("pkg.data/platlib/", ""),
                     lambda name: (lambda data: data.upper()) if name.endswith("RECORD") else None)
    with zipfile.ZipFile(src) as before, zipfile.ZipFile(tmp_path / "copy.zip") as after:
        assert after.testzip() is None
        assert after.namelist() == ["a.py", "b.bin", "ünï.txt", "pkg-1.0.dist-info/RECORD"]
        for old, new in zip(before.infolist(), after.infolist()):
            expected = before.read(old).upper() if new.filename.endswith("RECORD") else before.read(old)
            assert after.read(new) == expected
            assert (new.date_time, new.external_attr) == (old.date_time, old.external_attr)
            if not new.filename.endswith("RECORD"):
                assert (new.compress_type, new.compress_size) == (old.compress_type, old.compress_size)


def test_a_plain_wheel_is_used_as_it_is_and_other_data_folders_stop_the_build(tmp_path):
    plain = _wheel(tmp_path / "demo-1.0-py3-none-any.whl", {"demo/__init__.py": b""})
    assert build_extension.blender_ready(plain, tmp_path / "flat") == plain
    scripts = _wheel(tmp_path / "demo-1.0-cp313-cp313-win_amd64.whl", {"demo-1.0.data/scripts/demo": b"#!"})
    with pytest.raises(SystemExit, match="demo-1.0-cp313-cp313-win_amd64.whl: .data folders scripts"):
        build_extension.blender_ready(scripts, tmp_path / "flat")


# --- the GL context's glcontext modules in every zip ----------------------------------------------------

def _imported_by_gl_context(platform: str, monkeypatch) -> list[str]:
    """The glcontext modules hlod_core's standalone GL context imports on `platform` (a build
    platform), in order: its branch run with a stand-in for every glcontext module, each refusing
    to make a context so that the next one is tried."""
    from hlod_core.core.errors import GLUnavailable
    from hlod_core.render import gl_platform

    imported = []

    def stand_in(name):
        def create_context(**kwargs):
            imported.append(name)
            raise Exception("a stand-in makes no context")
        return types.SimpleNamespace(create_context=create_context)

    for name in ("egl", "x11", "wgl", "darwin"):
        monkeypatch.setitem(sys.modules, f"glcontext.{name}", stand_in(f"glcontext.{name}"))
    with pytest.raises(GLUnavailable):
        gl_platform.standalone_context(platform=build_extension.SYS_PLATFORM[platform])
    return imported


@pytest.mark.slow  # every_zip: each platform's zips (without test.sh's set-up, their wheels downloaded first)
def test_every_zip_holds_the_glcontext_modules_its_platform_imports(every_zip, monkeypatch):
    """For each zip the build makes (linux-x64, windows-x64, macos-arm64, each for both Blender lines):
    the glcontext modules the GL context's branch for that platform imports (run, not read) are
    compiled modules of that zip's glcontext wheel, for that line's Python."""
    made = {(line.python_tag, platform) for line in build_extension.BLENDER_LINES
            for platform in build_extension.PIP_PLATFORMS}
    seen = set()
    expected = {"linux-x64": ["glcontext.egl", "glcontext.x11"], "windows-x64": ["glcontext.wgl"],
                "macos-arm64": ["glcontext.darwin"]}
    for platform in build_extension.PIP_PLATFORMS:
        imported = _imported_by_gl_context(platform, monkeypatch)
        assert imported == expected[platform] == build_extension.gl_modules(platform), platform
        for line in build_extension.BLENDER_LINES:
            name = f"-{line.label}-{platform.replace('-', '_')}.zip"
            zip_path = next(z for z in every_zip if z.name.endswith(name))
            with zipfile.ZipFile(zip_path) as z:
                [wheel_name] = [n for n in z.namelist() if n.startswith("wheels/glcontext-")]
                with zipfile.ZipFile(io.BytesIO(z.read(wheel_name))) as wheel:
                    files = wheel.namelist()
            for module in imported:
                stem = module.replace(".", "/") + "."
                built = [f for f in files if f.startswith(stem) and f.endswith((".so", ".pyd"))]
                assert len(built) == 1 and line.python_tag[2:] in built[0], (zip_path.name, module, files)
            seen.add((line.python_tag, platform))
    assert seen == made and len(every_zip) == len(made)


def test_a_zip_whose_glcontext_lacks_the_platforms_module_stops_the_build(tmp_path):
    """A glcontext wheel with only the Linux modules in a Windows zip: the build names what is missing."""
    wheel = io.BytesIO()
    with zipfile.ZipFile(wheel, "w") as w:
        w.writestr("glcontext/__init__.py", b"")
        w.writestr("glcontext/egl.cpython-311-x86_64-linux-gnu.so", b"\0")
    zip_path = tmp_path / "hlod-windows.zip"
    with zipfile.ZipFile(zip_path, "w") as z:
        z.writestr("wheels/glcontext-3.1.0-cp311-cp311-win_amd64.whl", wheel.getvalue())
    with pytest.raises(SystemExit) as stop:
        build_extension.check_gl_modules(zip_path, "windows-x64", "cp311")
    assert str(stop.value) == (f"build_extension: {zip_path}: wheels/glcontext-3.1.0-cp311-cp311-win_amd64.whl lacks "
                               "glcontext.wgl (cp311), which the GL context imports on windows-x64 (it holds "
                               "glcontext.egl)")


@pytest.mark.slow  # every_zip: each platform's zips (without test.sh's set-up, their wheels downloaded first)
def test_the_licence_ships_in_every_zip_the_build_makes(every_zip):
    """LICENSE, the full GPL v3 text the manifest's GPL-3.0-or-later refers to, is in every zip the
    build makes with Blender's own tool (check_zip holds every release zip to the same list)."""
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    assert manifest["license"] == ["SPDX:GPL-3.0-or-later"]
    for zip_path in every_zip:
        with zipfile.ZipFile(zip_path) as z:
            licence = z.read("LICENSE").decode()
        assert licence == (ROOT / "LICENSE").read_text(), zip_path.name
    assert licence.lstrip().startswith("GNU GENERAL PUBLIC LICENSE\n                       Version 3, 29 June 2007")
    assert "END OF TERMS AND CONDITIONS" in licence and "How to Apply These Terms to Your New Programs" in licence


def test_a_listed_file_that_is_missing_stops_the_build(tmp_path, monkeypatch):
    monkeypatch.setattr(build_extension, "PACKAGE", [*build_extension.PACKAGE, "NOTICE"])
    with pytest.raises(SystemExit, match=r"build_extension: NOTICE: listed to ship \(PACKAGE\) but missing"):
        build_extension.stage("", "linux-x64", [], where=tmp_path / "stage")
    assert not (tmp_path / "stage").exists() or not any((tmp_path / "stage").iterdir())


def test_a_zip_without_a_listed_file_is_refused(tmp_path):
    zip_path = tmp_path / "hlod.zip"
    with zipfile.ZipFile(zip_path, "w") as z:
        for name in build_extension.PACKAGE:
            if name != "LICENSE":
                z.writestr(f"{name}/__init__.py" if "." not in name else name, "")
    with pytest.raises(SystemExit, match=r"hlod\.zip: lacks LICENSE \(listed to ship in PACKAGE\)"):
        build_extension.check_zip(zip_path, [])
    with zipfile.ZipFile(zip_path, "a") as z:
        z.writestr("LICENSE", "")
    build_extension.check_zip(zip_path, [])
