// Independent checks of a 3D Tiles export (used by tests/test_export.py):
//   node check_tileset.mjs DIR
// Reads DIR/tileset.json with CesiumGS 3d-tiles-tools (its tileset traversal, into external tilesets),
// and validates every tile's GLB content with the Khronos glTF validator (external images read relative
// to the GLB). Prints one JSON object:
// {"tiles": [{"path", "level", "uri", "external", "geometricError", "box", "parentGeometricError",
//   "errors", "warnings", "triangles", "vertices"}], "tilesetGeometricError"}
// uri: a GLB content's path relative to DIR; external: that of an external tileset the tile refers to
// (its root follows as a tile of its own, the referring tile its parent).
import fs from "node:fs";
import path from "node:path";
import tools from "3d-tiles-tools";
import validator from "gltf-validator";

const dir = path.resolve(process.argv[2]);
const { TilesetSources, TilesetTraversers } = tools;
const source = await TilesetSources.createAndOpen(dir);
const tilesetJson = JSON.parse(fs.readFileSync(path.join(dir, "tileset.json")));
const iterable = await TilesetTraversers.createTraversedTilesIterable(source, "tileset.json", true, true);
const tiles = [];
// The folder (relative to DIR) a traversed tile's URIs are relative to: an external tileset's root
// takes the folder of the file its referring tile names.
const folders = new Map();
const folderOf = (traversed) => {
  if (!folders.has(traversed)) {
    const parent = traversed.getParent();
    let folder = ".";
    if (parent) {
      folder = folderOf(parent);
      const raw = parent.getRawContents();
      if (traversed.path.endsWith("]/root") && raw.length > 0) folder = path.join(folder, path.dirname(raw[0].uri));
    }
    folders.set(traversed, folder);
  }
  return folders.get(traversed);
};
for await (const traversed of iterable) {
  const tile = traversed.asFinalTile();
  const parent = traversed.getParent();
  const row = {
    path: traversed.path, level: traversed.level, geometricError: tile.geometricError,
    box: tile.boundingVolume.box ?? null,
    parentGeometricError: parent ? parent.asFinalTile().geometricError : null,
    uri: null, external: null, errors: null, warnings: null, triangles: null, vertices: null,
  };
  const contents = traversed.getFinalContents();
  const contentPath = contents.length > 0 ? path.join(folderOf(traversed), contents[0].uri).split(path.sep).join("/") : null;
  if (contentPath !== null && contentPath.endsWith(".json")) {
    row.external = contentPath;
  } else if (contentPath !== null) {
    row.uri = contentPath;
    const bytes = fs.readFileSync(path.join(dir, row.uri));
    const glbFolder = path.dirname(path.join(dir, row.uri));  // images are shared by URI (../textures/)
    const report = await validator.validateBytes(new Uint8Array(bytes), {
      uri: row.uri, maxIssues: 50,
      externalResourceFunction: (uri) => fs.promises.readFile(path.resolve(glbFolder, decodeURIComponent(uri)))
        .then((data) => new Uint8Array(data)),
    });
    row.errors = report.issues.numErrors;
    row.warnings = report.issues.numWarnings;
    row.messages = report.issues.messages.filter((m) => m.severity === 0).map((m) => `${m.code}: ${m.message}`);
    row.triangles = report.info.totalTriangleCount;
    row.vertices = report.info.totalVertexCount;
  }
  tiles.push(row);
}
await source.close();
console.log(JSON.stringify({ tilesetGeometricError: tilesetJson.geometricError, tiles }));
