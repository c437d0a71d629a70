"""Surfaces whose colour no reading of their node tree gives (materials/node_tree.py's
`unreadable`: a surface without one Principled BSDF, a procedural Base Color), baked by Cycles on
each object that draws them (materials/cycles_bake.py) while the scene is gathered (scene/gather.py):
- as the parts are read (`SurfaceBakes.take`), each evaluated mesh that draws such a material is
  copied once, whatever made it (modifiers, geometry nodes' Set Material, realised instances with
  their own materials, curves), with its material slots as evaluated; instances of one object share
  the copy;
- after (`bake_into`), each copy is baked, one Cycles bake per object, and the parts it draws take
  the result. With a UV map: a texture per material on that object, in a material row of its own
  (named "material (object)" when several objects use the material, so each keeps its own pixels;
  base colour white, the triangles' vertex colours white). Without: the baked colour of each face
  corner as the triangles' vertex colours, and a white row.
A scene without such surfaces copies nothing and runs no Cycles bake.
Why: docs/how-it-works.md#base-colours-baked-by-cycles

Data form: parts (scene/parts.py Part) changed in place: `slots` rows replaced, `colors` made per
corner (t*3, 4) float32 linear RGBA where a bake gave colours.
"""
from __future__ import annotations

import dataclasses
import logging
from collections import defaultdict
from dataclasses import dataclass, field

import bpy
import numpy as np

from ...hlod_core.model.appearance import Material
from ..materials.cycles_bake import Baked, CyclesBake, SurfaceBake, bake_surface, cycles_enabled
from ..materials.textures import texture_image_name, written_texture

log = logging.getLogger(__name__)

#: How a baked object's result reaches its triangles, for the report.
TEXTURE, CORNER_COLOURS = "texture", "corner colours"
#: What a material that cannot be baked keeps (materials/rows.py material_row).
KEPT = "its Base Color value (without a Principled BSDF, its viewport display colour)"


@dataclass(eq=False)
class _Source:
    """One evaluated mesh to bake: its SurfaceBake and the instance key of its first instance
    (the order bakes run and rows are named in)."""

    bake: SurfaceBake
    order: tuple
    baked: Baked | None = None


@dataclass
class SurfaceBakes:
    """The evaluated meshes a gathering bakes with Cycles, keyed by (object, evaluated mesh)."""

    sources: dict[tuple, _Source] = field(default_factory=dict)

    def take(self, inst, depsgraph, *, readings: dict, uv_map: str | None, order: tuple) -> tuple:
        """The key of the instance's evaluated mesh, copied the first time it is met (module
        notes). readings: slot -> node_tree.BaseColour of each slot it bakes; uv_map: the UV map
        its part carries (None: none)."""
        obj = inst.object
        key = (obj.original.name_full, obj.data.as_pointer())
        source = self.sources.get(key)
        if source is None:
            mesh = bpy.data.meshes.new_from_object(obj, preserve_all_data_layers=True, depsgraph=depsgraph)
            mesh.name = f"{obj.original.name} (Cycles bake)"
            materials = [slot.material.original if slot.material is not None else None for slot in obj.material_slots]
            source = self.sources[key] = _Source(SurfaceBake(
                label=obj.original.name, mesh=mesh, matrix_world=inst.matrix_world.copy(), materials=materials,
                readings={}, uv_map=uv_map), order=order)
        source.bake.readings.update(readings)
        source.order = min(source.order, order)
        return key

    def release(self) -> None:
        """Remove the temporary meshes. Idempotent."""
        for source in self.sources.values():
            if source.bake.mesh is not None:
                bpy.data.meshes.remove(source.bake.mesh)
                source.bake.mesh = None

    def bake_into(self, context, parts: list) -> list[CyclesBake]:
        """Bake every source that a part in `parts` draws and give those parts the result (module
        notes); the bakes made, in order. A material that cannot be baked (Cycles disabled, or
        refusing) keeps its row, with a warning naming it and the object."""
        wanted = {part.bake_key for part in parts if part.bake_key is not None}
        sources = sorted(((key, s) for key, s in self.sources.items() if key in wanted), key=lambda ks: ks[1].order)
        if sources and not cycles_enabled(context):
            for name in sorted({m.name_full for _, s in sources for slot, m in enumerate(s.bake.materials)
                                if slot in s.bake.readings}):
                log.warning("HLOD bake: material %r: its node tree cannot be read and Cycles, which would bake it, "
                            "is not enabled; baked with %s", name, KEPT)
            return []
        done = []
        for key, source in sources:
            names = [source.bake.materials[slot].name_full for slot in sorted(source.bake.readings)]
            try:
                source.baked = bake_surface(context, source.bake)
            except RuntimeError as exc:  # the bake refused (Blender's message)
                log.warning("HLOD bake: material(s) %s: the node tree cannot be read and Cycles could not bake it "
                            "on object %r: %s; baked with %s", ", ".join(map(repr, names)), source.bake.label,
                            " ".join(str(exc).split()), KEPT)
                continue
            target = TEXTURE if source.bake.uv_map is not None else CORNER_COLOURS
            done.append(CyclesBake(label=source.bake.label, materials=tuple(sorted(names)), target=target,
                                   seconds=source.baked.seconds))
            log.info("HLOD bake: Cycles baked %s on object %r into %s in %.2f s", ", ".join(map(repr, names)),
                     source.bake.label, target, source.baked.seconds)
        rows = _rows(dict(sources), parts)
        for part in parts:
            source = self.sources.get(part.bake_key)
            if source is not None and source.baked is not None:
                _apply(part, rows[part.bake_key], source.baked.corner_colours)
        return done


def _rows(sources: dict[tuple, _Source], parts: list) -> dict[tuple, dict[int, Material]]:
    """source key -> {slot: its baked material row}: the part's row with the bake's texture (or
    none: corner colours) and a white base colour, named after the object too where several
    objects bake that material."""
    first_row = {}
    for part in parts:
        if part.bake_key in sources:
            for slot in sources[part.bake_key].bake.readings:
                first_row.setdefault((part.bake_key, slot), part.slots[slot])
    users = defaultdict(list)
    for key, source in sources.items():
        if source.baked is not None:
            for slot in source.bake.readings:
                users[source.bake.materials[slot].name_full].append(key)
    out, names = {}, {m.name_full for m in bpy.data.materials}  # a row's name names one material
    for key, source in sources.items():
        if source.baked is None:
            continue
        out[key] = {}
        for slot, reading in source.bake.readings.items():
            material = source.bake.materials[slot]
            name = material.name_full
            if len(users[name]) > 1:
                name = _unique(f"{name} ({source.bake.label})", names)
            pixels = source.baked.textures.get(slot)
            row = first_row.get((key, slot), Material(name))
            texture = written_texture(pixels) if pixels is not None else None
            out[key][slot] = dataclasses.replace(
                row, name=name, base_color=(1.0, 1.0, 1.0, 1.0),
                metallic=0.0 if reading.whole_surface else row.metallic,
                texture=texture, image=texture_image_name(name) if texture else None, alpha_mode="OPAQUE")
    return out


def _unique(name: str, taken: set) -> str:
    out, k = name, 2
    while out in taken:
        out, k = f"{name} {k}", k + 1
    taken.add(out)
    return out


def _apply(part, rows: dict[int, Material], corner_colours: np.ndarray | None) -> None:
    """The part's baked slots take their rows; their triangles' corners take the baked colours
    (without a UV map) or white (with one: the texture holds the whole colour)."""
    for slot, row in rows.items():
        part.slots[slot] = row
    if corner_colours is None and part.colors is None:
        return
    at = np.isin(np.repeat(part.tri_slot, 3), list(rows))
    colours = _per_corner(part)
    colours[at] = corner_colours[part.corner_loops[at]] if corner_colours is not None else 1.0
    part.colors, part.color_domain = colours, "CORNER"


def _per_corner(part) -> np.ndarray:
    """(t*3, 4) the part's colours per triangle corner: its own expanded, white where it has none."""
    if part.colors is None:
        return np.ones((part.corners.size, 4), np.float32)
    if part.color_domain == "CORNER":
        return part.colors.copy()
    return part.colors[part.corners].astype(np.float32)
