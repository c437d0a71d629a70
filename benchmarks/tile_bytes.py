"""Bytes of a 3D Tiles export by what they hold: plain float32 tile content against positions and
normals quantized (KHR_mesh_quantization) and Draco compressed (KHR_draco_mesh_compression), on
baked files.

    .venv/bin/python -m benchmarks.tile_bytes FILE.hlod [FILE.hlod ...]

Each file is exported once per encoding (MESH_ENCODINGS, --mesh) into a temporary folder
(hlod_core.export.tiles3d.export) and every GLB's buffer views are summed by what they serve:
POSITION, NORMAL, TEXCOORD_0, COLOR_0, indices, draco (a Draco mesh holds all of them), and the
rest of the GLB (JSON chunk, headers, padding); the tileset JSON files and the texture files are
counted apart; then the Draco export again with its textures re-encoded (--textures jpeg, webp), and
with each node's leaves in one tile (--merge-leaves).
Prints one JSON object per file: nodes, stored triangles, and for each export the bytes by part,
the GLB bytes per stored triangle, the triangles the GLBs hold (Draco stores no triangle whose
corners repeat a vertex), the whole export's bytes and the export's seconds (a rough figure: the
machine's load moves it; sizes do not depend on it), and the ratios to plain's: GLB bytes, texture
bytes, the whole export's bytes.
"""
from __future__ import annotations

import argparse
import json
import shutil
import struct
import tempfile
import time
from pathlib import Path

from hlod_core.export import tiles3d
from hlod_core.io import hlod_file

#: The texture encodings measured, each with the compact mesh encoding.
COMPACT_MESH, COMPACT_TEXTURES = "draco", ("jpeg", "webp")
PARTS = ("POSITION", "NORMAL", "TEXCOORD_0", "COLOR_0", "indices", "draco", "glb_rest")


def glb_parts(data: bytes) -> dict[str, int]:
    """Bytes of one GLB by part (PARTS): each buffer view counted once, under the first attribute
    (or indices) that uses it, a Draco primitive's view under "draco" (its accessors have no view);
    the rest is the JSON chunk, headers and padding."""
    json_len = struct.unpack("<I", data[12:16])[0]
    gltf = json.loads(data[20:20 + json_len])
    view_part: dict[int, str] = {}
    for primitive in gltf["meshes"][0]["primitives"]:
        compressed = primitive.get("extensions", {}).get("KHR_draco_mesh_compression")
        if compressed is not None:
            view_part.setdefault(compressed["bufferView"], "draco")
            continue
        for name, index in [*primitive["attributes"].items(), ("indices", primitive["indices"])]:
            view_part.setdefault(gltf["accessors"][index]["bufferView"], name)
    out = dict.fromkeys(PARTS, 0)
    for view, name in view_part.items():
        out[name] += gltf["bufferViews"][view]["byteLength"]
    out["glb_rest"] = len(data) - sum(out.values())
    return out


def measure(folder: Path) -> dict:
    """The export in `folder` by part, with its tileset JSON and texture files."""
    parts = dict.fromkeys(PARTS, 0)
    for glb in (folder / tiles3d.TILE_FOLDER).glob("*.glb"):
        for name, size in glb_parts(glb.read_bytes()).items():
            parts[name] += size
    parts["tileset_json"] = sum(p.stat().st_size for p in folder.rglob("*.json"))
    textures = folder / tiles3d.TEXTURE_FOLDER
    parts["textures"] = sum(p.stat().st_size for p in textures.iterdir()) if textures.is_dir() else 0
    return parts


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.tile_bytes", description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="+", metavar="FILE.hlod")
    args = parser.parse_args(argv)
    for file in args.files:
        hlod = hlod_file.load(file)
        row = {"file": str(file), "nodes": hlod.node_count, "stored_triangles": int(hlod.tri_count.sum()),
               "normals": hlod.normals is not None, "uvs": hlod.uvs is not None, "colors": hlod.colors is not None}
        with tempfile.TemporaryDirectory(prefix="tile_bytes.") as scratch:
            for name, textures, merge in [*((m, "original", False) for m in tiles3d.MESH_ENCODINGS),
                                          *((COMPACT_MESH, t, False) for t in COMPACT_TEXTURES),
                                          (COMPACT_MESH, "original", True)]:
                key = name if textures == "original" else f"{name}+{textures}"
                key += "+merged_leaves" if merge else ""
                folder = Path(scratch) / key
                start = time.perf_counter()
                summary = tiles3d.export(hlod, folder, mesh=name, textures=textures, merge_leaves=merge)
                seconds = time.perf_counter() - start
                parts = measure(folder)
                row[key] = {**parts, "tiles": summary["tiles"], "glb_bytes": summary["bytes"],
                            "glb_bytes_per_triangle": summary["bytes"] / row["stored_triangles"],
                            "glb_triangles": summary["glb_triangles"],
                            "export_bytes": summary["bytes"] + parts["tileset_json"] + parts["textures"],
                            "export_s": round(seconds, 2)}
                shutil.rmtree(folder)
        row["glb_ratio"] = {name: row[name]["glb_bytes"] / row["plain"]["glb_bytes"]
                            for name in (*tiles3d.MESH_ENCODINGS, f"{COMPACT_MESH}+merged_leaves")}
        if row["plain"]["textures"]:
            row["texture_ratio"] = {t: row[f"{COMPACT_MESH}+{t}"]["textures"] / row["plain"]["textures"]
                                    for t in COMPACT_TEXTURES}
        row["export_ratio"] = {key: row[key]["export_bytes"] / row["plain"]["export_bytes"]
                               for key in row if isinstance(row[key], dict) and "export_bytes" in row[key]}
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
