"""A 3D Tiles export on the globe (hlod_core/export/place.py): the root's frame against PROJ's
geodesy (pyproj, tests only: EPSG:4979 longitude/latitude/ellipsoidal height to EPSG:4978 ECEF),
the east-north-up axes, the heading, the scene georeferences GIS add-ons write, and bad input as one
line with nothing written."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

from hlod_core.core.errors import InputError
from hlod_core.export import place as geo
from hlod_core.export import tiles3d
from processes import hlod, last_json, one_line_error

#: Places across the globe: city scale heights, both hemispheres, the date line, a pole, a heading.
PLACES = [(-122.4194, 37.7749, 16.0, 0.0), (151.2093, -33.8688, -30.5, 45.0), (179.9999, 0.0, 8848.0, 270.0),
          (-180.0, -89.9999, 0.0, 0.0), (2.2945, 48.8584, 330.0, -10.0), (0.0, 90.0, 100.0, 0.0)]


@pytest.fixture(scope="module")
def cow(bakes):
    """A small bake (its origin is not 0: the tiles are relative to it)."""
    h = bakes.baked("cow", target_tris=500)[1]
    assert np.any(np.asarray(h.origin) != 0)
    return h


def _proj_ecef(lon: float, lat: float, height: float) -> np.ndarray:
    import pyproj

    to_ecef = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    return np.array(to_ecef.transform(lon, lat, height), np.float64)


def _proj_up(lon: float, lat: float) -> np.ndarray:
    """The ellipsoid's normal, from PROJ: the unit difference of two points 1 km apart in height."""
    d = _proj_ecef(lon, lat, 1000.0) - _proj_ecef(lon, lat, 0.0)
    return d / np.linalg.norm(d)


def _proj_north(lon: float, lat: float) -> np.ndarray:
    """North from PROJ: towards a point 1e-6 degrees of latitude further, made normal to up."""
    up = _proj_up(lon, lat)
    d = _proj_ecef(lon, min(lat + 1e-6, 90.0), 0.0) - _proj_ecef(lon, lat - 1e-6 if lat >= 90.0 else lat, 0.0)
    d -= up * (d @ up)
    return d / np.linalg.norm(d)


@pytest.mark.parametrize("lon, lat, height, heading", PLACES)
def test_the_placed_root_stands_the_scene_origin_at_the_point_up_the_normal(cow, tmp_path, lon, lat, height, heading):
    """The written root transform, applied to the scene's origin (the tiles are relative to the
    bake's origin), is PROJ's ECEF point within 1 mm; its axes are orthonormal, right-handed, +Z
    PROJ's ellipsoid normal, +Y north turned clockwise by the heading (away from the poles)."""
    h = cow
    summary = tiles3d.export(h, tmp_path / "tiles", place=geo.place(lon, lat, height, heading))
    document = json.loads((tmp_path / "tiles/tileset.json").read_text())
    m = np.array(document["root"]["transform"], np.float64).reshape(4, 4).T  # column-major
    origin = m @ np.append(-np.asarray(h.origin), 1.0)
    assert np.linalg.norm(origin[:3] - _proj_ecef(lon, lat, height)) < 1e-3
    axes = m[:3, :3]
    assert np.allclose(axes.T @ axes, np.eye(3), atol=1e-12) and np.linalg.det(axes) == pytest.approx(1.0)
    assert np.allclose(axes[:, 2], _proj_up(lon, lat), atol=1e-9)
    if abs(lat) < 89.0:
        north, up = _proj_north(lon, lat), _proj_up(lon, lat)
        east = np.cross(north, up)
        a = np.radians(heading)
        assert np.allclose(axes[:, 1], np.sin(a) * east + np.cos(a) * north, atol=1e-6)  # clockwise from north
    assert document["extras"]["place"] == summary["place"] == {"longitude_deg": lon, "latitude_deg": lat,
                                                               "height_m": height, "heading_deg": heading}


def test_centimetres_survive_at_city_scale(cow, tmp_path):
    """A point 5 km from the origin, through the written transform, lands where PROJ puts the same
    east/north/up offset within 1 cm (the transform is float64 in the JSON)."""
    lon, lat, height = 13.4050, 52.5200, 34.0
    h = cow
    tiles3d.export(h, tmp_path / "tiles", place=geo.place(lon, lat, height))
    m = np.array(json.loads((tmp_path / "tiles/tileset.json").read_text())["root"]["transform"]).reshape(4, 4).T
    local = np.array([3000.0, 4000.0, 12.34])  # scene metres: east, north, up
    world = m @ np.append(local - np.asarray(h.origin), 1.0)
    up, north = _proj_up(lon, lat), _proj_north(lon, lat)
    expected = _proj_ecef(lon, lat, height) + local[0] * np.cross(north, up) + local[1] * north + local[2] * up
    assert np.linalg.norm(world[:3] - expected) < 0.01


def test_an_unplaced_export_keeps_its_local_frame(cow, tmp_path):
    h = cow
    summary = tiles3d.export(h, tmp_path / "tiles")
    document = json.loads((tmp_path / "tiles/tileset.json").read_text())
    assert document["root"]["transform"][12:15] == list(h.origin) and "extras" not in document
    assert summary["place"] is None


@pytest.mark.parametrize("properties, expected", [
    ({"latitude": 45.5, "longitude": -73.5, "SRID": "EPSG:3857", "crs x": -8e6, "crs y": 5.7e6}, (-73.5, 45.5)),
    ({"lat": 41.985, "lon": -93.76}, (-93.76, 41.985)),  # Blosm
    ({"SRID": "EPSG:4326", "crs x": 7.25, "crs y": 46.5}, (7.25, 46.5)),  # BlenderGIS, geographic CRS
    ({"SRID": "+proj=longlat +datum=WGS84 +no_defs", "crs x": -3.7, "crs y": 40.4}, (-3.7, 40.4)),
    ({"SRID": "EPSG:32633"}, None), ({}, None), ({"latitude": 10.0}, None)])
def test_scene_georeferences_are_read(properties, expected):
    found = geo.from_scene(properties)
    assert (None if found is None else (found.longitude_deg, found.latitude_deg)) == expected
    assert found is None or (found.height_m, found.heading_deg) == (0.0, 0.0)


def test_a_given_place_wins_and_none_keeps_the_local_frame():
    scene = {"latitude": 1.0, "longitude": 2.0}
    given = geo.parse("3,4,5,6")
    assert geo.chosen(given, scene) == geo.Place(3.0, 4.0, 5.0, 6.0)
    assert geo.chosen(geo.parse("none"), scene) is None
    assert geo.chosen(None, scene) == geo.Place(2.0, 1.0) and geo.chosen(None, None) is None


@pytest.mark.parametrize("properties, message", [
    ({"SRID": "EPSG:32633", "crs x": 500000.0, "crs y": 5e6}, "CRS 'EPSG:32633' is not geographic longitude/latitude"),
    ({"latitude": 91.0, "longitude": 0.0}, "latitude 91 is beyond +-90 degrees"),
    ({"lat": "north", "lon": 0.0}, "latitude 'north' is not a number")])
def test_a_scene_georeference_that_cannot_be_read_is_one_line(properties, message):
    with pytest.raises(InputError, match=re.escape(message)) as caught:
        geo.from_scene(properties, where="city.blend")
    assert str(caught.value).startswith("city.blend's georeference") and "\n" not in str(caught.value)


@pytest.mark.parametrize("text, message", [
    ("0,91,0", "latitude 91 is beyond +-90 degrees"), ("0,-90.5,0", "latitude -90.5 is beyond +-90 degrees"),
    ("180.5,0,0", "longitude 180.5 is beyond +-180 degrees"), ("0,0,high", "height 'high' is not a number"),
    ("0,0,inf", "height 'inf' is not a finite number"), ("0,0,0,east", "heading 'east' is not a number"),
    ("0,0", "give LON,LAT,HEIGHT[,HEADING]"), ("1,2,3,4,5", "give LON,LAT,HEIGHT[,HEADING]")])
def test_bad_places_are_one_line_and_nothing_is_written(cow_file, tmp_path, text, message):
    out = tmp_path / "tiles"
    error = one_line_error(hlod("export", cow_file, "-o", out, f"--place={text}", check=False))
    assert message in error and text in error
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_the_export_command_places_the_tileset(cow_file, tmp_path):
    out = last_json(hlod("-q", "export", cow_file, "-o", tmp_path / "tiles", "--place=-0.1276,51.5072,11"))
    assert out["place"] == {"longitude_deg": -0.1276, "latitude_deg": 51.5072, "height_m": 11.0, "heading_deg": 0.0}
    assert "--place: only for --format 3dtiles" in one_line_error(
        hlod("export", cow_file, "-o", tmp_path / "native", "--format", "hlod", "--place=1,2,3", check=False))
