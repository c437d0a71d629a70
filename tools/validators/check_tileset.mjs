// Independent checks of a 3D Tiles export (used by tests/test_export.py):
//   node check_tileset.mjs DIR
// Reads DIR/tileset.json with CesiumGS 3d-tiles-tools (its tileset traversal), and validates every
// tile's GLB content with the Khronos glTF validator (external images read relative to the GLB). Prints one JSON object:
// {"tiles": [{"path", "level", "uri", "geometricError", "box", "parentGeometricError",
//   "errors", "warnings", "triangles", "vertices"}], "tilesetGeometricError"}
import fs from "node:fs";
import path from "node:path";
import tools from "3d-tiles-tools";
import validator from "gltf-validator";

const dir = path.resolve(process.argv[2]);
const { TilesetSources, TilesetTraversers } = tools;
const source = await TilesetSources.createAndOpen(dir);
const tilesetJson = JSON.parse(fs.readFileSync(path.join(dir, "tileset.json")));
const iterable = await TilesetTraversers.createTraversedTilesIterable(source, "tileset.json", false, true);
const tiles = [];
for await (const traversed of iterable) {
  const tile = traversed.asFinalTile();
  const parent = traversed.getParent();
  const row = {
    path: traversed.path, level: traversed.level, geometricError: tile.geometricError,
    box: tile.boundingVolume.box ?? null,
    parentGeometricError: parent ? parent.asFinalTile().geometricError : null,
    uri: null, errors: null, warnings: null, triangles: null, vertices: null,
  };
  const contents = traversed.getFinalContents();
  if (contents.length > 0) {
    row.uri = contents[0].uri;
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
