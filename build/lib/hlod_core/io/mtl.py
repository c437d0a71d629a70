"""An OBJ's material library (MTL), as Blender's OBJ importer reads it.

Data form: an MTL file in; appearance.Material rows by name out. Kd (linear RGB, as Blender reads
and writes it), d (alpha; or 1 - Tr), Pr / Pm (roughness, metallic), else roughness from Ns as
Blender's exporter writes it (Ns = 1000 (1 - roughness)^2), map_Kd (options skipped; path relative
to the MTL). With map_Kd the base colour is white (Blender's importer ignores Kd then). A missing
library or texture image: a warning naming the file, and the OBJ is read without it; a malformed
line: InputError naming the file and line.
"""
from __future__ import annotations

import logging
import math
from pathlib import Path

from ..core.errors import InputError
from ..model.appearance import DEFAULT_BASE_COLOR, Material

log = logging.getLogger(__name__)

#: map_Kd options and how many arguments each takes (-o/-s/-t/-mm: up to that many numbers).
_MAP_OPTIONS = {"-blendu": 1, "-blendv": 1, "-bm": 1, "-boost": 1, "-cc": 1, "-clamp": 1, "-imfchan": 1,
                "-texres": 1, "-type": 1, "-mm": 2, "-o": 3, "-s": 3, "-t": 3}
_NUMERIC_OPTIONS = ("-mm", "-o", "-s", "-t")


def read_mtl(path: Path) -> dict[str, Material]:
    """The materials of an MTL file by name (see the module docstring). A missing file: a warning
    and no materials; a malformed line: InputError naming the file and line."""
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        log.warning("%s: material library missing; the OBJ is read without its materials", path)
        return {}
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, expected a material library") from None
    out: dict[str, Material] = {}
    current, fields = None, {}
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        key, _, rest = line.partition(" ")
        rest = rest.strip()
        if key == "newmtl":
            if current is not None:
                out[current] = _mtl_material(path, current, fields)
            current, fields = rest, {}
        elif key in ("Kd", "d", "Tr", "Pr", "Pm", "Ns"):
            try:
                values = [float(x) for x in rest.split()]
            except ValueError:
                values = []
            if not values or not all(math.isfinite(v) for v in values):
                raise InputError(f"{path}: line {number} ('{line[:60]}'): {key} needs numbers")
            fields[key] = values
        elif key == "map_Kd":
            fields[key] = _map_file(rest)
    if current is not None:
        out[current] = _mtl_material(path, current, fields)
    return out


def _map_file(rest: str) -> str:
    """The file name of a map_Kd line: what follows its options (the name may hold spaces)."""
    tokens = rest.split()
    at = 0
    while at < len(tokens) - 1 and tokens[at] in _MAP_OPTIONS:
        option, at = tokens[at], at + 1
        for _ in range(_MAP_OPTIONS[option]):
            if at < len(tokens) - 1 and (option not in _NUMERIC_OPTIONS or _is_number(tokens[at])):
                at += 1
    return " ".join(tokens[at:]).replace("\\", "/")


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _mtl_material(path: Path, name: str, fields: dict) -> Material:
    texture = None
    if fields.get("map_Kd"):
        file = (path.parent / fields["map_Kd"]).resolve()
        if file.is_file():
            texture = str(file)
        else:
            log.warning("%s: texture image %s of material %s is missing; the material is read without it",
                        path, file, name)
    kd = fields.get("Kd", DEFAULT_BASE_COLOR[:3])
    rgb = [1.0, 1.0, 1.0] if texture is not None else (list(kd) * 3 if len(kd) == 1 else list(kd[:3]))
    alpha = fields["d"][0] if "d" in fields else (1.0 - fields["Tr"][0] if "Tr" in fields else 1.0)
    if "Pr" in fields:
        roughness = fields["Pr"][0]
    elif "Ns" in fields:
        roughness = 1.0 - math.sqrt(max(fields["Ns"][0], 0.0) / 1000.0)
    else:
        roughness = 0.5
    metallic = fields["Pm"][0] if "Pm" in fields else 0.0
    return Material(name=name, base_color=tuple(min(max(float(c), 0.0), 1.0) for c in (*rgb, alpha)),
                    metallic=min(max(metallic, 0.0), 1.0), roughness=min(max(roughness, 0.0), 1.0), texture=texture)


def obj_materials(path: Path, mtllibs: list[str], names: list[str]) -> tuple[Material, ...]:
    """One Material per `usemtl` name (in first-use order), from the OBJ's material libraries
    (relative to the OBJ); a name no library defines: a warning and Blender's default colour."""
    library: dict[str, Material] = {}
    missing_library = False
    for lib in mtllibs:
        file = path.parent / lib
        if not file.is_file() and " " in lib and all((path.parent / part).is_file() for part in lib.split()):
            parts = lib.split()  # `mtllib a.mtl b.mtl`
        else:
            parts = [lib]
        for part in parts:
            found = read_mtl(path.parent / part)
            missing_library |= not (path.parent / part).is_file()
            library.update({k: v for k, v in found.items() if k not in library})
    out = []
    for name in names:
        if name not in library and not missing_library:
            log.warning("%s: material %s is not in its material library; read with the default colour", path, name)
        out.append(library.get(name, Material(name=name, base_color=DEFAULT_BASE_COLOR)))
    return tuple(out)
