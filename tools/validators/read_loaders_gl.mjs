// A second reader of a 3D Tiles export (used by tests/test_export.py): loaders.gl's Tiles3DLoader in
// node, as deck.gl and other loaders.gl users read 3D Tiles.
//   node read_loaders_gl.mjs DIR
// Reads DIR/tileset.json and every external tileset with Tiles3DLoader, then decodes every tile's GLB
// content with it (Draco meshes through the draco3d package's decoder, images not loaded), and prints
// one JSON object: {"tiles": {GLB path relative to DIR: triangles decoded}, "tilesets": N}.
// Triangles: each primitive's decoded index count / 3 (TRIANGLES mode, as the export writes).
import fs from "node:fs";
import path from "node:path";
import { parse } from "@loaders.gl/core";
import { Tiles3DLoader } from "@loaders.gl/3d-tiles";
import draco3d from "draco3d";

const dir = path.resolve(process.argv[2]);
const options = {
  "3d-tiles": { loadGLTF: true }, gltf: { decompressMeshes: true, loadImages: false, normalize: true },
  modules: { draco3d }, worker: false,
};
const bytesOf = (file) => {
  const data = fs.readFileSync(file);
  return data.buffer.slice(data.byteOffset, data.byteOffset + data.byteLength);
};
const tiles = {};
let tilesets = 0;
async function readTileset(relative) {
  tilesets += 1;
  const tileset = await parse(bytesOf(path.join(dir, relative)), Tiles3DLoader,
    { ...options, "3d-tiles": { ...options["3d-tiles"], isTileset: true } });
  const folder = path.dirname(relative);
  const todo = [tileset.root];
  while (todo.length > 0) {
    const tile = todo.pop();
    todo.push(...(tile.children ?? []));
    const uri = tile.content?.uri;
    if (!uri) continue;
    const target = path.join(folder, decodeURIComponent(uri)).split(path.sep).join("/");
    if (target.endsWith(".json")) {
      await readTileset(target);
      continue;
    }
    const content = await parse(bytesOf(path.join(dir, target)), Tiles3DLoader, options);
    let triangles = 0;
    for (const mesh of content.gltf.meshes) {
      for (const primitive of mesh.primitives) triangles += primitive.indices.value.length / 3;
    }
    tiles[target] = triangles;
  }
}
await readTileset("tileset.json");
console.log(JSON.stringify({ tilesets, tiles }));
