"""Appearance carried through the bake: materials, UVs, vertex colours.

Data form:
- `Material`: one row of the material table (glTF's pbrMetallicRoughness subset): name, linear
  RGBA base colour factor, metallic and roughness factors, the base-colour texture as an image
  file path (`texture`, absolute in memory; relative to the .hlod file where it can be in a file)
  and, for a bake from Blender, the name of the image datablock (`image`) the preview draws there;
  glTF's alpha mode ("OPAQUE", "MASK": alpha below `alpha_cutoff` is not drawn, "BLEND"), and
  whether both faces of a triangle are drawn (`double_sided`: Blender's default, no backface culling,
  and so the default here; glTF's doubleSided, whose default is one face).
- Per vertex, optional: `uvs` (v,2) float32 in Blender's and OpenGL's convention (origin at the
  image's bottom-left, v up; glTF's v is 1 - v), `colors` (v,4) float32 linear RGBA in [0, 1].
- Per triangle, optional: a material id (row of the material table).

Inside the bake every vertex carries one attribute row (`pack`): [material, u, v, r, g, b, a], the
columns present only for what the scene has. A vertex belongs to one material; vertices that share
a position but differ in any attribute (a UV seam, a material border, a colour jump) are distinct
vertices, and the decimation keeps such borders where they are.

A scene with no materials, UVs or colours has none of this: every field is None or empty.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError

#: Most materials one HLOD can have (triangle material ids are stored as uint16).
MAX_MATERIALS = 65535

#: Base colour of a triangle whose source has no material (Blender's default material).
DEFAULT_BASE_COLOR = (0.8, 0.8, 0.8, 1.0)

#: glTF's alpha modes (material.alphaMode).
ALPHA_MODES = ("OPAQUE", "MASK", "BLEND")

#: Base colour drawn for an HLOD without a material table (glTF's default material), so vertex
#: colours show as they are.
NO_MATERIAL_BASE_COLOR = (1.0, 1.0, 1.0, 1.0)


@dataclass(frozen=True)
class Material:
    """One material (see the module docstring)."""

    name: str
    base_color: tuple[float, float, float, float] = DEFAULT_BASE_COLOR
    metallic: float = 0.0
    roughness: float = 0.5
    texture: str | None = None
    image: str | None = None
    alpha_mode: str = "OPAQUE"
    alpha_cutoff: float = 0.5
    double_sided: bool = True

    def to_json(self, *, relative_to: str | os.PathLike | None = None) -> dict:
        """A JSON object; `texture` relative to the folder `relative_to` when it is below it or
        beside it on the same drive (else absolute)."""
        texture = self.texture
        if texture is not None and relative_to is not None:
            try:
                texture = os.path.relpath(texture, relative_to)
            except ValueError:  # another drive (Windows)
                pass
            texture = texture.replace(os.sep, "/")
        out = {"name": self.name, "base_color": [float(c) for c in self.base_color],
               "metallic": float(self.metallic), "roughness": float(self.roughness),
               "texture": texture, "image": self.image}
        if self.alpha_mode != "OPAQUE":  # files of opaque materials stay as they were
            out.update(alpha_mode=self.alpha_mode, alpha_cutoff=float(self.alpha_cutoff))
        if not self.double_sided:  # files of double-sided materials stay as they were
            out["double_sided"] = False
        return out

    @staticmethod
    def from_json(value, *, where: str, relative_to: str | os.PathLike | None = None) -> "Material":
        """Parse and check one material object; raises InputError starting with `where`."""
        if not isinstance(value, dict):
            raise InputError(f"{where} is {type(value).__name__}, expected an object")
        name = value.get("name")
        if not isinstance(name, str):
            raise InputError(f"{where}.name must be a string")
        colour = value.get("base_color", list(DEFAULT_BASE_COLOR))
        if not isinstance(colour, list) or len(colour) != 4 or not all(_unit_number(c) for c in colour):
            raise InputError(f"{where}.base_color must be 4 numbers in [0, 1]")
        factors = {}
        for key, default in (("metallic", 0.0), ("roughness", 0.5)):
            factors[key] = value.get(key, default)
            if not _unit_number(factors[key]):
                raise InputError(f"{where}.{key} must be a number in [0, 1]")
        texture, image = value.get("texture"), value.get("image")
        for key, text in (("texture", texture), ("image", image)):
            if text is not None and (not isinstance(text, str) or not text or "\x00" in text):
                raise InputError(f"{where}.{key} must be a non-empty string or null")
        if texture is not None and relative_to is not None and not os.path.isabs(texture):
            texture = os.path.normpath(os.path.join(relative_to, texture))
        alpha_mode, alpha_cutoff = value.get("alpha_mode", "OPAQUE"), value.get("alpha_cutoff", 0.5)
        if alpha_mode not in ALPHA_MODES:
            raise InputError(f"{where}.alpha_mode must be one of {', '.join(ALPHA_MODES)}")
        if not _unit_number(alpha_cutoff):
            raise InputError(f"{where}.alpha_cutoff must be a number in [0, 1]")
        double_sided = value.get("double_sided", True)
        if not isinstance(double_sided, bool):
            raise InputError(f"{where}.double_sided must be true or false")
        return Material(name=name, base_color=tuple(float(c) for c in colour), metallic=float(factors["metallic"]),
                        roughness=float(factors["roughness"]), texture=texture, image=image, alpha_mode=alpha_mode,
                        alpha_cutoff=float(alpha_cutoff), double_sided=double_sided)


def _unit_number(value) -> bool:
    return type(value) in (int, float) and math.isfinite(value) and 0.0 <= value <= 1.0


def materials_from_json(value, *, where: str, relative_to: str | os.PathLike | None = None) -> tuple[Material, ...]:
    """A JSON list of material objects -> tuple of Material (InputError naming `where`)."""
    if not isinstance(value, list):
        raise InputError(f"{where} must be a list of materials")
    if len(value) > MAX_MATERIALS:
        raise InputError(f"{where} has {len(value)} materials, more than {MAX_MATERIALS}")
    return tuple(Material.from_json(m, where=f"{where}[{i}]", relative_to=relative_to) for i, m in enumerate(value))


def check_vertex_attributes(name: str, vertices: int, *, uvs, colors) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Validate optional per-vertex UVs (v,2) and colours (v,3 or v,4; alpha 1 added) of a mesh
    with `vertices` vertices. Non-finite UVs are refused; colours are clipped to [0, 1] (NaN: 1)."""
    uv = col = None
    if uvs is not None:
        uv = np.asarray(uvs, dtype=np.float32)
        if uv.shape != (vertices, 2):
            raise InputError(f"{name}: UVs must have shape ({vertices}, 2), got {list(uv.shape)}")
        if not np.all(np.isfinite(uv)):
            raise InputError(f"{name}: {int((~np.isfinite(uv)).any(axis=1).sum())} UVs are NaN or infinite")
    if colors is not None:
        col = np.asarray(colors, dtype=np.float32)
        if col.ndim != 2 or col.shape[0] != vertices or col.shape[1] not in (3, 4):
            raise InputError(f"{name}: vertex colours must have shape ({vertices}, 3 or 4), got {list(col.shape)}")
        if col.shape[1] == 3:
            col = np.concatenate([col, np.ones((vertices, 1), np.float32)], axis=1)
        col = np.clip(np.nan_to_num(col, nan=1.0), 0.0, 1.0).astype(np.float32)
    return uv, col


def check_material_ids(name: str, faces: int, *, material_ids, materials) -> np.ndarray | None:
    """Validate optional per-triangle material ids (f,) against the material table."""
    if material_ids is None:
        if materials:
            raise InputError(f"{name}: has {len(materials)} materials but no per-triangle material ids")
        return None
    ids = np.asarray(material_ids)
    if ids.shape != (faces,) or not np.issubdtype(ids.dtype, np.integer):
        raise InputError(f"{name}: material ids must be integers of shape ({faces},), got {ids.dtype}{list(ids.shape)}")
    if not materials:
        raise InputError(f"{name}: has material ids but no materials")
    if len(materials) > MAX_MATERIALS:
        raise InputError(f"{name}: has {len(materials)} materials, more than the {MAX_MATERIALS} a .hlod file holds")
    if ids.size and (ids.min() < 0 or ids.max() >= len(materials)):
        raise InputError(f"{name}: a material id is outside 0..{len(materials) - 1}")
    return ids.astype(np.int32, copy=False)


# --- the bake's per-vertex attribute rows ---------------------------------------------------------

@dataclass(frozen=True)
class AttributeLayout:
    """Which columns the bake's attribute rows have: material (1), uv (2), color (4), in that order."""

    material: bool
    uv: bool
    color: bool

    @property
    def width(self) -> int:
        return int(self.material) + 2 * int(self.uv) + 4 * int(self.color)

    @property
    def empty(self) -> bool:
        return self.width == 0

    def columns(self) -> dict[str, slice]:
        out, at = {}, 0
        for key, size in (("material", 1), ("uv", 2), ("color", 4)):
            if getattr(self, key):
                out[key] = slice(at, at + size)
                at += size
        return out


def pack(positions_count: int, faces: np.ndarray, *, material_ids=None, uvs=None, colors=None):
    """Per-vertex attribute rows for the bake: returns (layout, vertex_of_row (r,) int64, rows (r,A)
    float32, faces (f,3) rows), splitting a vertex used by triangles of several materials into one
    row per material. Without any attribute: (empty layout, None, None, faces) and nothing is copied."""
    layout = AttributeLayout(material=material_ids is not None, uv=uvs is not None, color=colors is not None)
    if layout.empty:
        return layout, None, None, faces
    faces = np.asarray(faces, np.int64)
    if material_ids is not None:
        corner_material = np.repeat(np.asarray(material_ids, np.int64), 3)
        key = faces.ravel() * (int(corner_material.max()) + 1) + corner_material
        unique, inverse = np.unique(key, return_inverse=True)
        vertex = unique // (int(corner_material.max()) + 1)
        material = (unique % (int(corner_material.max()) + 1)).astype(np.float32)
        faces = inverse.reshape(-1, 3)
    else:
        vertex = np.arange(positions_count, dtype=np.int64)
        material = None
    parts = []
    if material is not None:
        parts.append(material[:, None])
    if uvs is not None:
        parts.append(np.asarray(uvs, np.float32)[vertex])
    if colors is not None:
        parts.append(np.asarray(colors, np.float32)[vertex])
    return layout, vertex, np.concatenate(parts, axis=1).astype(np.float32), faces


def unpack(layout: AttributeLayout, rows: np.ndarray | None, faces: np.ndarray):
    """(uvs (v,2) | None, colors (v,4) | None, face material (f,) int32 | None) of attribute rows."""
    if rows is None or layout.empty:
        return None, None, None
    cols = layout.columns()
    uvs = np.ascontiguousarray(rows[:, cols["uv"]], np.float32) if "uv" in cols else None
    colors = np.ascontiguousarray(rows[:, cols["color"]], np.float32) if "color" in cols else None
    face_material = None
    if "material" in cols:
        face_material = rows[np.asarray(faces)[:, 0], cols["material"].start].astype(np.int32)
    return uvs, colors, face_material


def texture_paths(materials) -> list[str]:
    """Distinct texture paths of a material table, in first-use order."""
    return list(dict.fromkeys(m.texture for m in materials if m.texture is not None))
