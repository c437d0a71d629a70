"""Where a 3D Tiles export of the scene stands on the globe: the Export panel's Place (scene.hlod's
place_mode and fields: the scene's georeference, a typed longitude/latitude, or the local frame),
read through hlod_core/export/place.py, and the line the panel shows about it."""
from __future__ import annotations

from ...hlod_core.core.errors import HlodError
from ...hlod_core.export import place as geo


def export_place(scene):
    """Where a 3D Tiles export of `scene` stands (scene.hlod.place_mode): the scene's georeference
    (None when it has none), the panel's longitude, latitude, height and heading, or None (the local
    frame). InputError, one line, for values or a georeference that cannot be read."""
    props = scene.hlod
    if props.place_mode == "NONE":
        return None
    if props.place_mode == "MANUAL":
        return geo.place(props.place_longitude, props.place_latitude, props.place_height, props.place_heading,
                         where="Export: Place")
    return geo.from_scene(dict(scene.items()), where=f"Export: scene {scene.name!r}")


def place_line(scene) -> str:
    """What the panel says about the place of the next 3D Tiles export (export_place in words)."""
    try:
        found = export_place(scene)
    except HlodError as exc:
        return str(exc)
    if found is None:
        return "Local frame: the scene has no georeference" if scene.hlod.place_mode == "SCENE" else "Local frame"
    return (f"At {abs(found.latitude_deg):.6f} {'N' if found.latitude_deg >= 0 else 'S'}, "
            f"{abs(found.longitude_deg):.6f} {'E' if found.longitude_deg >= 0 else 'W'}, {found.height_m:g} m, "
            f"heading {found.heading_deg:g}")
