"""Where a 3D Tiles export stands on the Earth: a longitude, latitude, height and heading on the WGS84
ellipsoid, the frame that puts the scene there, and the georeference a Blender scene carries.

Specification: WGS84 (NIMA TR8350.2: a = 6378137 m, 1/f = 298.257223563); geodetic to
Earth-centred Earth-fixed (ECEF) coordinates by the closed form X = (N + h) cos(lat) cos(lon),
Y = (N + h) cos(lat) sin(lon), Z = (N (1 - e^2) + h) sin(lat), N = a / sqrt(1 - e^2 sin^2(lat));
the east-north-up frame there (up the ellipsoid's normal). 3D Tiles' tileset frame is ECEF, so a
placed tileset's root transform is this frame (3D Tiles 1.1, "Coordinate reference system").

The scene's origin (0, 0, 0) stands at the point, its +Z along the ellipsoid's normal, its +Y north
at heading 0; the heading turns the scene clockwise seen from above (+Y points at azimuth `heading`,
east of north). Everything is float64: at 6.4e6 m a double keeps about 1e-9 m.

Georeferences read (`from_scene`), the custom properties GIS add-ons write on the scene:
BlenderGIS scene["latitude"], scene["longitude"] (degrees, WGS84) or, without them, scene["SRID"]
with the origin scene["crs x"], scene["crs y"] in that CRS; Blosm (blender-osm) scene["lat"],
scene["lon"]. Only a geographic longitude/latitude CRS (EPSG:4326 and its aliases) can be read
without a projection library; a projected one (UTM, Web Mercator ...) is refused with one line.
Why: docs/how-it-works.md#3d-tiles-export
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ..core.errors import InputError

WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
PLACE_SYNTAX = "LON,LAT,HEIGHT[,HEADING] (degrees, degrees, metres above the WGS84 ellipsoid, degrees)"
#: --place's word for "the local frame, even where the scene carries a georeference".
NO_PLACE = "none"
#: CRS names read as geographic WGS84 longitude/latitude in degrees (upper case, spaces removed).
GEOGRAPHIC_CRS = frozenset({"4326", "EPSG:4326", "EPSG:4979", "CRS:84", "CRS84", "OGC:CRS84", "WGS84",
                            "URN:OGC:DEF:CRS:EPSG::4326", "URN:OGC:DEF:CRS:OGC:1.3:CRS84"})


@dataclass(frozen=True)
class Place:
    """A point on the WGS84 ellipsoid and a heading: degrees, degrees, metres, degrees clockwise
    from north. Made by `place` (checked)."""

    longitude_deg: float
    latitude_deg: float
    height_m: float = 0.0
    heading_deg: float = 0.0

    def ecef(self) -> np.ndarray:
        """(3,) float64 metres: the point in Earth-centred Earth-fixed coordinates."""
        lon, lat = math.radians(self.longitude_deg), math.radians(self.latitude_deg)
        n = WGS84_A_M / math.sqrt(1.0 - WGS84_E2 * math.sin(lat) ** 2)
        return np.array([(n + self.height_m) * math.cos(lat) * math.cos(lon),
                         (n + self.height_m) * math.cos(lat) * math.sin(lon),
                         (n * (1.0 - WGS84_E2) + self.height_m) * math.sin(lat)], np.float64)

    def frame(self) -> np.ndarray:
        """(4, 4) float64: scene coordinates (Z up, metres) to ECEF. Columns: the scene's +X, +Y
        (east and north turned clockwise by the heading), +Z (up, the ellipsoid's normal) and the
        point."""
        lon, lat, heading = map(math.radians, (self.longitude_deg, self.latitude_deg, self.heading_deg))
        east = np.array([-math.sin(lon), math.cos(lon), 0.0])
        north = np.array([-math.sin(lat) * math.cos(lon), -math.sin(lat) * math.sin(lon), math.cos(lat)])
        up = np.array([math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)])
        out = np.eye(4)
        out[:3, 0] = math.cos(heading) * east - math.sin(heading) * north
        out[:3, 1] = math.sin(heading) * east + math.cos(heading) * north
        out[:3, 2] = up
        out[:3, 3] = self.ecef()
        return out

    def as_dict(self) -> dict:
        return {"longitude_deg": self.longitude_deg, "latitude_deg": self.latitude_deg, "height_m": self.height_m,
                "heading_deg": self.heading_deg}


def _number(value, what: str, where: str) -> float:
    """`value` as a finite float; InputError naming `what` and `where` otherwise."""
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {what} {value!r} is not a number") from None
    if not math.isfinite(out):
        raise InputError(f"{where}: {what} {value!r} is not a finite number")
    return out


def place(longitude, latitude, height=0.0, heading=0.0, *, where: str = "--place") -> Place:
    """A checked Place: numbers (or their text), latitude within +-90, longitude within +-180, height
    and heading finite. InputError, one line naming `where` and the value, otherwise."""
    lon, lat = _number(longitude, "longitude", where), _number(latitude, "latitude", where)
    height_m, heading_deg = _number(height, "height", where), _number(heading, "heading", where)
    if not -90.0 <= lat <= 90.0:
        raise InputError(f"{where}: latitude {lat:g} is beyond +-90 degrees")
    if not -180.0 <= lon <= 180.0:
        raise InputError(f"{where}: longitude {lon:g} is beyond +-180 degrees")
    return Place(lon, lat, height_m, heading_deg)


def parse(text: str, *, where: str = "--place") -> Place | str:
    """--place's text: LON,LAT,HEIGHT[,HEADING] (a Place), or NO_PLACE (returned as it is: the local
    frame, even for a scene that carries a georeference). Errors name `where`."""
    if text.strip().lower() == NO_PLACE:
        return NO_PLACE
    fields = [f.strip() for f in text.split(",")]
    if len(fields) not in (3, 4):
        raise InputError(f"{where}: give {PLACE_SYNTAX}, or {NO_PLACE}")
    return place(*fields, where=where)


def chosen(given: Place | str | None, scene: Mapping | None = None, *, where: str = "the scene") -> Place | None:
    """The place of an export: `given` (parse's result) when there is one, NO_PLACE the local frame,
    else (None: nothing given) the georeference of `scene` (its custom properties: from_scene), else
    the local frame (None)."""
    if isinstance(given, Place):
        return given
    if given == NO_PLACE or scene is None:
        return None
    return from_scene(scene, where=where)


def from_scene(properties: Mapping, *, where: str = "the scene") -> Place | None:
    """The place a scene's georeference names (its custom properties, module notes), at height 0 and
    heading 0; None when it carries none. InputError for a CRS this cannot read or values that are
    not a place."""
    for lat_key, lon_key in (("latitude", "longitude"), ("lat", "lon")):
        if lat_key in properties and lon_key in properties:
            return place(properties[lon_key], properties[lat_key],
                         where=f"{where}'s georeference ({lon_key!r}, {lat_key!r})")
    if "SRID" in properties and "crs x" in properties and "crs y" in properties:
        crs = str(properties["SRID"])
        if not _geographic(crs):
            raise InputError(f"{where}'s georeference: CRS {crs!r} is not geographic longitude/latitude; without a "
                             f"projection library only EPSG:4326 can be read: give the place as {PLACE_SYNTAX}")
        return place(properties["crs x"], properties["crs y"], where=f"{where}'s georeference (CRS {crs})")
    return None


def _geographic(crs: str) -> bool:
    """Whether a CRS string names geographic WGS84 longitude/latitude in degrees: an EPSG/OGC name of
    GEOGRAPHIC_CRS, or a PROJ string +proj=longlat on WGS84."""
    text = crs.upper().replace(" ", "")
    if text in GEOGRAPHIC_CRS:
        return True
    words = set(crs.lower().split())
    return "+proj=longlat" in words and bool(words & {"+datum=wgs84", "+ellps=wgs84"})
