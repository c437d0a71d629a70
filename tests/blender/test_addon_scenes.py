"""What a bake from Blender takes, in each Blender (4.2, 5.0, 5.2) with the real bpy module
(tests/blender/blender_scene_checks.py): each triangle Blender draws, no more and no fewer, for every kind
of geometry a .blend holds; the kinds without triangles and hidden objects skipped and named once;
--include-hidden; the panel's count before a bake; a batch that goes on past files that cannot bake.
"""
import numpy as np
import pytest

from blender_runs import all_hold, blender

pytestmark = pytest.mark.blender

SKIP_LINE = ("skipped 3 hidden objects: HiddenEye, HiddenViewport, InHiddenCollection "
             "(--include-hidden bakes hidden objects)")

KINDS_SKIPPED = (("point cloud", "Points"), ("volume", "Fog"), ("light", "Sun"), ("camera", "Cam"),
                 ("grease pencil", "Sketch"))


def scene_check(installed, check: str, tmp_path) -> dict:
    return blender(installed, check, tmp_path, timeout_s=600, script="blender_scene_checks.py")


def test_every_kind_of_geometry_bakes_as_blender_draws_it(versioned_repo, tmp_path):
    """Per object, gathering the scene gives Blender's count (its MESH instances' loop triangles), which
    equals the count known by construction (modifiers with a shape key, a mirrored cube, loose
    edges, a zero-area face, an empty mesh, a mesh over 65,535 vertices, nested and linked
    collection instances, geometry-nodes instances and realised geometry); curves, text, surfaces
    and metaballs count once (their own evaluated mesh), not twice; the mirrored cube's faces face
    out. The background command bakes the sum (input_tris), names the hidden objects and the
    kinds without triangles in one line, and with --include-hidden bakes the hidden ones too and
    leaves them hidden. The panel's count (of the selection: hidden objects are not selected) says
    the same objects, triangles and kinds skipped."""
    out = scene_check(versioned_repo, "kinds", tmp_path)
    drawn, ours, converted, known = out["drawn"], out["ours"], out["converted"], out["known"]
    with_triangles = {name: n for name, n in drawn.items() if n > 0}
    total = sum(with_triangles.values())
    hidden_total = 12 + 12 + 1  # two cubes and a triangle
    cli, cli_h = out["cli"], out["cli_hidden"]
    file, file_h = cli["summary"]["files"][0], cli_h["summary"]["files"][0]
    skip_line = [line for line in cli["stderr"] if "skipped" in line]
    all_hold(out,
             known_counts=all(drawn.get(name) == n for name, n in known.items()),
             ours_equal_blender={name: ours.get(name) for name, n in with_triangles.items()
                                 if ours.get(name) != n} == {},
             no_triangles_refused=all(isinstance(ours.get(name), str) and "no triangles" in ours[name]
                                      for name in ("EmptyMesh", "BareCurve", "Meta.001")),
             curve_like_once=all(converted[name] == drawn[name] > 0 for name in converted),
             mirrored_outward=out["mirrored_outward"],
             cli_baked_all=cli["status"] == 0 and file.get("input_tris") == total,
             cli_skip_line=len(skip_line) == 1 and SKIP_LINE.split(" (")[0] in skip_line[0]
             and all(f"1 {kind}: {name}" in skip_line[0] for kind, name in KINDS_SKIPPED),
             cli_summary_skipped=file.get("skipped", {}).get("hidden objects") == ["HiddenEye", "HiddenViewport",
                                                                                   "InHiddenCollection"],
             hidden_baked=cli_h["status"] == 0 and file_h.get("input_tris") == total + hidden_total
             and "hidden objects" not in file_h.get("skipped", {}),
             hidden_left_hidden=out["still_hidden"] == [True, True, True]
             and out["layers_after"] == out["layers_before"],
             panel_count=out["plan"].startswith(
                 f"Will bake {len(with_triangles)} objects, {total:,} triangles; skipped ")
             and all(f"1 {kind}: {name}" in out["plan"] for kind, name in KINDS_SKIPPED))


def test_the_active_render_uv_map_is_baked(versioned_repo, tmp_path):
    """Of two UV maps, the bake takes the one Blender renders (active_render), not the one active in
    the UV editor, and names it in the meta."""
    out = scene_check(versioned_repo, "uv_maps", tmp_path)
    all_hold(out, editor_map_active=out["active"] == "Edit", render_map_baked=out["uvs"] == [[0.75, 0.5]],
             named=out["attributes"].get("uv_map") == "Render")


def test_a_texture_made_from_nodes_is_written_beside_the_hlod(versioned_repo, tmp_path):
    """A generated image through a Hue/Saturation node (no file of its own) comes out as a PNG in
    OUT.textures/ that the .hlod refers to, and in the 3D Tiles export; after the node changes and
    the scene is baked again, the preview's image is the new file's, not the one it read before; a
    bake that fails after making its textures leaves OUT.textures as it was and no scratch folder."""
    out = scene_check(versioned_repo, "textures_beside", tmp_path)
    texture = out["material_texture"] or ""
    all_hold(out, baked=out["status"] == 0, one_texture=len(out["textures"]) == 1,
             referred=texture.endswith("quad.textures/" + (out["textures"] or ["?"])[0]),
             in_tiles=len(out["tile_images"]) == 1, rebaked=out["status_again"] == 0,
             preview_reads_the_new_texture=out["preview_changed"] and out["preview_again_equals_file"],
             failed_bake_keeps_textures=out["failed_status"] == 1 and "is a file" in (out["failed_error"] or "")
             and out["textures_kept"] and out["leftovers"] == [])


def test_a_udim_image_gets_one_note_and_its_first_tile(versioned_repo, tmp_path):
    """A UDIM image (tiles 1001 red, 1002 green): one warning naming the material, the image and its
    tiles; the texture written beside the .hlod is tile 1001's."""
    out = scene_check(versioned_repo, "udim", tmp_path)
    notes = [line for line in out["stderr"] if "UDIM" in line]
    all_hold(out, baked=out["status"] == 0, tiles=out["tiles"] == [1001, 1002],
             one_note=len(notes) == 1 and "'Painted'" in notes[0] and "1001, 1002" in notes[0],
             first_tile=out["texture_rgba"] == [[255, 0, 0, 255]])


def test_colour_attributes_of_every_domain_and_type_are_read(versioned_repo, tmp_path):
    """POINT and CORNER, float and byte colour attributes: the bake's colours are the set ones
    (float exactly; byte within 0.01: an 8-bit sRGB step is at most 0.009 in linear)."""
    out = scene_check(versioned_repo, "colour_attributes", tmp_path)
    all_hold(out, point_float=out["POINT FLOAT_COLOR"] == 0.0, corner_float=out["CORNER FLOAT_COLOR"] == 0.0,
             point_byte=out["POINT BYTE_COLOR"] is not None and out["POINT BYTE_COLOR"] < 0.01,
             corner_byte=out["CORNER BYTE_COLOR"] is not None and out["CORNER BYTE_COLOR"] < 0.01)


def test_a_batch_goes_on_past_files_that_cannot_bake(versioned_repo, tmp_path):
    """Four files: not a .blend, one with only a light, a missing one, a good one: three failures,
    each one stderr line naming its file and the reason (no traceback), and the good file is baked."""
    out = scene_check(versioned_repo, "batch", tmp_path)
    files = {f["blend"].rsplit("/", 1)[-1]: f for f in out["summary"]["files"]}
    errors = [line for line in out["stderr"] if line.startswith("hlod: ")]
    all_hold(out,
             status=out["status"] == 1 and out["summary"]["failed"] == 3,
             good_baked=files["good.blend"]["ok"] and out["good_written"],
             one_line_each=all(sum(name in line for line in errors) == 1 for name in
                               ("not_a_blend.blend", "lights_only.blend", "missing.blend")),
             says_why="cannot open it" in files["not_a_blend.blend"]["error"]
             and files["missing.blend"]["error"] == "no such .blend file",
             lights_only_says_why="no triangles" in files["lights_only.blend"]["error"]
             and "1 light: Light" in files["lights_only.blend"]["error"],
             no_traceback=not any("Traceback" in line for line in out["stderr"]))


def test_a_georeferenced_scene_is_placed_and_a_projected_crs_is_one_line(versioned_repo, tmp_path):
    """BlenderGIS's scene latitude/longitude place the background bake's and the Export button's 3D
    Tiles (its root origin 6.37e6 m from the Earth's centre, extras.place the scene's); --place
    wins; the panel's typed place is read in double precision and Local Frame is not placed; a
    projected CRS alone is refused by the button and by `hlod export`, one line, nothing written;
    a latitude of 95 likewise; --mesh quantized and the button's Tile Content write quantized GLBs;
    --merge-leaves and the button's Merge Leaves write the same fewer GLBs, a node's leaves in one."""
    out = scene_check(versioned_repo, "place", tmp_path)
    zurich = {"longitude_deg": 8.5417, "latitude_deg": 47.3769, "height_m": 0.0, "heading_deg": 0.0}
    manhattan = {"longitude_deg": -73.98513, "latitude_deg": 40.7589, "height_m": 12.5, "heading_deg": 90.0}

    def placed(result, expected):
        return result is not None and result[0] == expected and 6.36e6 < float(np.linalg.norm(result[1])) < 6.38e6

    all_hold(out,
             baked=out["bake"][0] == 0 and placed(out["bake_place"], zurich),
             given_wins=out["given_place"][0] == 0 and placed(out["given_place"][1], {
                 "longitude_deg": -122.4194, "latitude_deg": 37.7749, "height_m": 16.0, "heading_deg": 30.0}),
             button_scene=out["button_scene"][0] == ["FINISHED"] and placed(out["button_scene"][1], zurich),
             button_manual=out["button_manual"][0] == ["FINISHED"] and placed(out["button_manual"][1], manhattan),
             button_none=out["button_none"][0] == ["FINISHED"] and out["button_none"][1][0] is None
             and float(np.linalg.norm(out["button_none"][1][1])) < 1e3,
             lines=out["line_unplaced"] == "Local frame: the scene has no georeference"
             and out["line_scene"].startswith("At 47.376900 N, 8.541700 E")
             and out["line_manual"].startswith("At 40.758900 N, 73.985130 W, 12.5 m, heading 90")
             and "'EPSG:2056' is not geographic" in out["line_projected"],
             button_projected=len(out["button_projected"][0]) == 1
             and "'EPSG:2056' is not geographic" in out["button_projected"][0][0]
             and out["button_projected"][1] is None,
             cli_projected=out["cli_projected"][0] == 1 and len(out["cli_projected"][1]) == 1
             and "'EPSG:2056' is not geographic" in out["cli_projected"][1][0] and not out["cli_projected"][2],
             cli_bad_latitude=out["cli_bad_latitude"][0] == 2 and len(out["cli_bad_latitude"][1]) == 1
             and "latitude 95 is beyond +-90 degrees" in out["cli_bad_latitude"][1][0]
             and not out["cli_bad_latitude"][2],
             quantized=out["quantized"] == [0, ["KHR_mesh_quantization"], ["KHR_mesh_quantization"]],
             merged=out["merged"][0] == 0 and out["merged"][1] == out["merged"][2]
             and any(name.endswith("-leaves.glb") for name in out["merged"][1])
             and len(out["merged"][1]) < len(out["merged"][3]))
