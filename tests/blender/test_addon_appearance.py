"""Appearance from Blender (materials, UVs, colours) with the real bpy module: the extension built by Blender's tool
and installed as Blender installs it (conftest.py's fixtures), each check in its own bpy
process (tests/blender/blender_appearance_checks.py, on a textured scene it makes with bpy: a checker PNG
made in Blender, two materials, a UV map, corner and point colour attributes, a linked mirrored
duplicate, collection instances).

Extraction (addon/scene/gather.py): materials resolved through the slots, one row per datablock, the
active render UV map and colour attribute per corner, vertices split only where corners differ.
The bake from Blender keeps them: every leaf corner equals a source corner in position, UV and
colour, per material. The preview draws the texture (GL mode through the renderer, private mode
through the gpu module). Materialize gives the source's materials, UV map and colour attribute by
name, and its root node renders like the source in Cycles (PSNR).
"""

import pytest

from blender_runs import all_hold, blender
from helpers import textured_scene

pytestmark = pytest.mark.blender

# Materialize of the root node against the source, Cycles at 160x120 from the far view where the
# root's screen-space error is below 1 px, PSNR (dB) over the scene's rectangle. Measured: bpy 4.2.23
# Y 42.9, Cb 52.3, Cr 51.5; bpy 5.0.1 39.6, 49.8, 48.0; bpy 5.2.3 39.6, 50.0, 48.4 (what differs is
# Cycles' noise on the simplified faces: 128 samples instead of 32 moved it by 0.1 dB). The same
# objects with their material slots emptied (grey objects): 19.9 to
# 20.6, 26.1, 24.6. The limits sit about 5 dB below the lowest measurement, 15 dB above grey.
PSNR_Y_DB, PSNR_CHROMA_DB = 35.0, 43.0
FAR_VIEW_SSE_PX = 1.0


def appearance_check(installed, check: str, tmp_path, *arguments: str, timeout_s: float = 600) -> dict:
    """tests/blender/blender_appearance_checks.py CHECK in `installed`'s Blender; its JSON result."""
    return blender(installed, check, tmp_path, *arguments, timeout_s=timeout_s, script="blender_appearance_checks.py")


def test_extraction_carries_materials_uvs_and_colours(versioned_repo, tmp_path):
    """In each Blender: gathering the scene gives one material row per datablock (the textured one with its
    PNG and image name, white base colour; the plain one with its factors), every corner's position,
    UV and colour as the source has them (house and its mirrored linked duplicate: bevel modifier,
    corner byte colours; the instanced ball: point float colours), vertices split at UV seams and
    colour jumps only; images for the renderer top row first, float ones sRGB-encoded; a plain cube (a UV map but no
    material or colour) has no appearance at all; an empty slot gives the default row; the table is sorted by name."""
    out = appearance_check(versioned_repo, "extraction", tmp_path)
    texture = out["names"]["texture"]
    all_hold(out,
             attributes=out["attributes"] == {"uv_map": "UVMap", "color_attribute": "Paint"},
             materials=out["materials"] == [
                 ["Checker", [1.0, 1.0, 1.0, 1.0], 0.0, pytest.approx(0.6), texture, "checker"],
                 ["Green", pytest.approx([0.05, 0.55, 0.1, 1.0]), pytest.approx(0.3), pytest.approx(0.4), None, None]],
             corners=all(c["same"] for c in out["corners"].values()) and set(out["corners"]) == {"Checker", "Green"},
             split_at_seams=out["vertices"] > out["source_vertices"],
             # a literal case: a UV seam at vertex 0 splits it; (1, 0.0) and (1, -0.0) do not split vertex 2
             split_literal=out["split"] == {"vertex": [0, 1, 2, 3, 0], "faces": [[0, 1, 2], [4, 2, 3]],
                                            "uv": [[0, 0], [1, 0], [1, 0], [0, 1], [0.5, 0]]},
             image_rows=out["image_rows"] == {"byte": [[128, 128, 128, 255], [255, 0, 0, 255]],
                                              "float": [[188, 188, 188, 255], [255, 0, 0, 255]]},
             plain_has_no_appearance=out["plain"] == {"appearance": False, "attributes": {}, "vertices": 8,
                                                      "uv_layers": 1},
             empty_slot_default=out["slotted"] == {"materials": ["Only", "default"], "tris_per_material": [6, 6],
                                                   "uvs": True, "colors": False})


@pytest.mark.gl  # the preview draws, in GL mode and in private mode
def test_bake_preview_and_materialize_keep_the_look(versioned_repo, tmp_path):
    """In each Blender: the Bake operator's file has both materials (the texture by path), the UV map's
    and colour attribute's names, and leaves whose corners are the source's; its inner nodes keep both
    materials. The preview draws the checker's red and blue only where the houses are and no node in
    the untextured grey, in GL mode and in private mode. Materialize of the root node puts the
    source's own material datablocks in the slots (none made), the UV map and the colour attribute
    (per vertex) by name; in a file without those materials it makes Principled ones from the table,
    the texture loaded from its path."""
    out = appearance_check(versioned_repo, "appearance", tmp_path)
    texture = str(tmp_path / "textures" / "checker.png")
    slots = {"objects": 1, "slots": [["Checker", "Green"]], "uv_maps": [["UVMap"]],
             "colour_attributes": [[["Paint", "POINT", "FLOAT_COLOR"]]], "render_colour": [0],
             "material_index_used": [[0, 1]]}
    checks = {"baked": out["bake"] == ["FINISHED"] and out["file"]["depth"] >= 2,
              "file_materials": out["file"]["materials"] == [["Checker", texture, "checker"], ["Green", None, None]],
              "file_names": out["file"]["uv_map"] == "UVMap" and out["file"]["color_attribute"] == "Paint",
              "root_keeps_both": out["file"]["inner_materials"] == ["Checker", "Green"],
              "leaves_are_the_source": all(c["same"] for c in out["leaves"].values())
              and set(out["leaves"]) == {"Checker", "Green"},
              "image_from_bpy": out["images"] == {"0": [64, 64, 4]}}
    for mode in ("gl", "private"):
        picture = out[mode]
        checks |= {f"{mode}_textured": picture["red"] > 200 and picture["blue"] > 200,
                   f"{mode}_green_material": picture["green"] > 200,
                   f"{mode}_texture_only_on_houses": picture["texture_off_houses"] == 0,
                   f"{mode}_no_grey_nodes": picture["grey"] == 0}
    materialized, made = out["materialized"], out["materialized_new"]
    all_hold(out, **checks,
             private_mode=out["private_status"].startswith("on (private context)"),
             materialized=out["materialize"] == ["FINISHED"] and {k: materialized[k] for k in slots} == slots,
             source_datablocks=out["materials_made"] == 0,
             materialized_in_empty_file=out["materialize_empty_file"] == ["FINISHED"]
             and {k: made[k] for k in slots} == slots,
             made_from_table=made["materials"] == {
                 "Checker": {"base_color": [1.0, 1.0, 1.0, 1.0], "metallic": 0.0, "roughness": 0.6, "texture": texture},
                 "Green": {"base_color": [0.05, 0.55, 0.1, 1.0], "metallic": 0.3, "roughness": 0.4, "texture": None}})


def test_materialized_root_renders_like_the_source(repo, tmp_path):
    """Cycles renders of the far view: the root node's Materialize against the source objects, in PSNR
    over the scene's rectangle (limits above); the same objects with their slots emptied (grey) stay
    below them, so the limits measure the appearance, not the geometry."""
    out = appearance_check(repo, "render", tmp_path)
    y, cb, cr = out["psnr_crop"]
    grey_y, grey_cb, grey_cr = out["psnr_grey_crop"]
    print(f"materialized root vs source, PSNR Y/Cb/Cr: {out['psnr_crop']} dB over the scene, {out['psnr']} dB whole "
          f"picture; grey objects: {out['psnr_grey_crop']} dB; root SSE {out['root_sse_px']:.2f} px, "
          f"{out['root_tris']} of {out['input_tris']} triangles")
    all_hold(out, rendered=out["bake"] == ["FINISHED"] and out["materialize"] == ["FINISHED"],
             far_view=out["root_sse_px"] <= FAR_VIEW_SSE_PX and out["root_tris"] < out["input_tris"],
             psnr=y >= PSNR_Y_DB and cb >= PSNR_CHROMA_DB and cr >= PSNR_CHROMA_DB,
             grey_below=grey_y < PSNR_Y_DB and grey_cb < PSNR_CHROMA_DB and grey_cr < PSNR_CHROMA_DB)


@pytest.mark.slow
def test_shared_textured_scene_bakes_from_blender(repo, tmp_path):
    """The shared textured scene's .blend (tests/scenes/textured_scene.py), every mesh object baked by
    the Bake operator: all its triangles, its four materials with their three textures, the UV map's
    and colour attribute's names, per material the source's triangles in the leaves, every leaf
    corner the source's (position, UV, colour); with the default Proxy Materials the root draws in one
    part, its own proxy with its texture written beside the .hlod, no inner node in more than two, and
    the preview's image of each proxy is its texture file's pixels."""
    scene = textured_scene("small")
    facts = scene["facts"]
    out = appearance_check(repo, "shared_scene", tmp_path, str(scene["blend"]))
    all_hold(out, baked=out["bake"] == ["FINISHED"] and out["input_tris"] == facts["triangles"],
             levels=out["depth"] >= 2 and out["inner_nodes"] > 1,
             materials=[m for m in out["materials"] if not m.startswith("HLOD proxy")]
             == sorted(facts["triangles_per_material"]),
             textures=set(facts["textures"]) <= set(out["textures"]),
             names=out["uv_map"] == "UVMap" and out["color_attribute"] in ("Paint", "Tint"),
             leaf_tris=out["leaf_tris_per_material"] == facts["triangles_per_material"],
             leaves_are_the_source=all(c["same"] for c in out["leaves"].values()),
             root_materials=out["root_materials"] == ["HLOD proxy 0"] and "proxy_0.png" in out["proxy_textures"],
             inner_parts=out["inner_parts_max"] <= 2, proxy_images=out["proxy_images_match"],
             attributes=out["has_uvs"] and out["has_colors"])
