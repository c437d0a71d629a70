// The HLOD 3D Tiles viewer page (served by hlod_core/export/viewer.py): CesiumJS showing /tiles/tileset.json
// in a local frame, a panel (maximum screen-space error, colour by depth, boxes, counters), and
// window.hlodViewer for scripts and tests.
//
// Frames. The tileset is in Blender's model space: Z up, metres (its root transform moves it to the
// bake's origin; glTF content is Y up and Cesium turns it Z up, as every 3D Tiles runtime does).
// Unplaced (no extras.place in tileset.json): the page places that space on the ellipsoid at
// longitude 0, latitude 0, height 0 with its east-north-up frame (x east, y north, z up), so Cesium's
// camera controller and lighting behave as for any geo-referenced tileset, and shows nothing else (no
// globe, imagery, sky or token). Placed (hlod_core/export/place.py): the root transform itself stands
// the tileset on the WGS84 globe; the page draws the globe as a plain ellipsoid of one colour (no
// imagery, no terrain, no network) and takes for model space the east-north-up frame at the place,
// turned clockwise by its heading, computed here by Cesium from extras.place. Either frame is rigid,
// so distances, and so Cesium's screen-space errors, are those of model space.
// hlodViewer.setCamera / camera() take and give model-space coordinates (the .hlod's, Blender's);
// hlodViewer.place is extras.place or null.
//
// Tile selection is made comparable with our traversal: dynamic and foveated screen-space error
// off, no progressive resolution, no skipping of levels (REPLACE refinement as written).
//
// Frames are drawn on demand (CesiumJS's request render mode): when the camera moves, a tile loads or
// the panel changes something, not 60 times a second, so an idle page costs no GPU or CPU time.
// hlodViewer.redraw() draws one frame of the page's state now and resolves once it is drawn.
"use strict";

(function () {
  const hv = (window.hlodViewer = {
    allTilesLoaded: false, // true once the tileset finished loading for the current view
    ready: false, // the tileset is constructed
    errors: [], // tile and render errors seen
    place: null, // the tileset's extras.place: where it stands on the globe, or null (a local frame)
  });
  const fail = (what) => { hv.errors.push(String(what)); setText("status", "error: " + what); };
  function setText(id, text) { const el = document.getElementById(id); if (el) el.textContent = text; }
  window.addEventListener("error", (e) => fail(e.message));
  window.addEventListener("unhandledrejection", (e) => fail(e.reason && e.reason.message ? e.reason.message : e.reason));

  // the tileset's place first: it decides the frame and whether a globe is drawn
  fetch("/tiles/tileset.json").then((r) => r.json()).then((doc) => {
    if (doc.extras && doc.extras.mesh === "draco") startDracoDecoder();
    start((doc.extras && doc.extras.place) || null);
  }).catch(fail);

  // CesiumJS starts its Draco decoder (a web worker compiling the decoder's WebAssembly) when the first
  // Draco tile arrives, and that tile waits for it; the export names Draco tiles in extras.mesh, so the
  // decoder starts here, while the viewer and the tileset load. DracoLoader is CesiumJS's own, not
  // documented: without it the decoder starts as before.
  function startDracoDecoder() {
    const loader = Cesium.DracoLoader;
    if (loader && typeof loader._getDecoderTaskProcessor === "function") loader._getDecoderTaskProcessor();
  }

  // model space -> Cesium's world (ECEF): the place's east-north-up frame turned clockwise by its
  // heading (the export's root transform, recomputed here), or the local frame at 0, 0, 0
  function modelToWorld(place) {
    if (place === null) return Cesium.Transforms.eastNorthUpToFixedFrame(Cesium.Cartesian3.fromDegrees(0.0, 0.0, 0.0));
    const enu = Cesium.Transforms.eastNorthUpToFixedFrame(
      Cesium.Cartesian3.fromDegrees(place.longitude_deg, place.latitude_deg, place.height_m));
    const heading = Cesium.Matrix4.fromRotation(Cesium.Matrix3.fromRotationZ(-Cesium.Math.toRadians(place.heading_deg)));
    return Cesium.Matrix4.multiply(enu, heading, new Cesium.Matrix4());
  }

  function start(place) {
    hv.place = place;
    const toWorld = modelToWorld(place);
    const toLocal = Cesium.Matrix4.inverseTransformation(toWorld, new Cesium.Matrix4());
    const DEPTH_COLOURS = ["#4e79a7", "#f28e2b", "#59a14f", "#e15759", "#b07aa1", "#edc948", "#76b7b2", "#ff9da7",
      "#9c755f", "#bab0ac"].map((css) => Cesium.Color.fromCssColorString(css));
    const LIGHT_FROM_LOCAL = [-0.45, -0.55, -0.70]; // light travelling down and to the north-east
    const GLOBE_CSS = "#6b7a66"; // the placed tileset's globe: one muted colour, no map
    const FIT_DIRECTION_LOCAL = [1.0, 1.3, -0.9]; // the first view looks north-east and down

    const c3 = (a) => new Cesium.Cartesian3(a[0], a[1], a[2]);
    const arr = (c) => [c.x, c.y, c.z];
    const pointToWorld = (p) => Cesium.Matrix4.multiplyByPoint(toWorld, c3(p), new Cesium.Cartesian3());
    const vectorToWorld = (v) => Cesium.Cartesian3.normalize(
      Cesium.Matrix4.multiplyByPointAsVector(toWorld, c3(v), new Cesium.Cartesian3()), new Cesium.Cartesian3());
    const pointToLocal = (p) => arr(Cesium.Matrix4.multiplyByPoint(toLocal, p, new Cesium.Cartesian3()));
    const vectorToLocal = (v) => arr(Cesium.Matrix4.multiplyByPointAsVector(toLocal, v, new Cesium.Cartesian3()));
    // A tile's level in the HLOD (root 0): Cesium's depth less the tiles above it that only refer to an
    // external tileset (a big export's subtrees are files of their own, tiles3d.tileset_files).
    function level(tile) {
      if (tile._hlodLevel === undefined) {
        let n = 0;
        for (let t = tile.parent; t; t = t.parent) if (!t.hasTilesetContent) n += 1;
        tile._hlodLevel = n;
      }
      return tile._hlodLevel;
    }

    // placed: the WGS84 ellipsoid in one colour (no imagery layer, the ellipsoid terrain: nothing fetched)
    const globe = place === null ? false : new Cesium.Globe(Cesium.Ellipsoid.WGS84);
    if (globe) {
      globe.baseColor = Cesium.Color.fromCssColorString(GLOBE_CSS);
      globe.showGroundAtmosphere = false;
      globe.enableLighting = false;
      globe.showSkirts = false;
    }
    const viewer = new Cesium.Viewer("cesium", {
      baseLayer: false, globe: globe, skyBox: false, skyAtmosphere: false, scene3DOnly: true,
      animation: false, timeline: false, baseLayerPicker: false, geocoder: false, homeButton: false,
      sceneModePicker: false, navigationHelpButton: false, fullscreenButton: false, infoBox: false,
      selectionIndicator: false, shouldAnimate: false, requestRenderMode: true, maximumRenderTimeChange: Infinity,
    });
    const scene = viewer.scene;
    scene.backgroundColor = Cesium.Color.fromCssColorString("#30343a");
    if (scene.sun) scene.sun.show = false;
    if (scene.moon) scene.moon.show = false;
    scene.light = new Cesium.DirectionalLight({ direction: vectorToWorld(LIGHT_FROM_LOCAL) });
    scene.screenSpaceCameraController.enableCollisionDetection = false;
    scene.renderError.addEventListener((_scene, error) => fail(error));
    hv.viewer = viewer;

    // The export's tiles carry normals only where the bake had them; without, Cesium draws them unlit
    // (flat colour). Every tile is shaded here instead, from the derivatives of its eye-space position
    // (faceted, as the Blender preview does), Lambert with an ambient floor, on the base colour (texture,
    // vertex colour and factor), the same with or without normals and whatever the material's metallic.
    const AMBIENT = 0.35;
    const FACETED = new Cesium.CustomShader({
      lightingModel: Cesium.LightingModel.UNLIT,
      fragmentShaderText: `
        void fragmentMain(FragmentInput fsInput, inout czm_modelMaterial material) {
          vec3 p = fsInput.attributes.positionEC;
          vec3 n = normalize(cross(dFdx(p), dFdy(p)));
          material.normalEC = n;
          float lambert = max(dot(n, normalize(czm_lightDirectionEC)), 0.0);
          material.diffuse = material.baseColor.rgb * (${AMBIENT.toFixed(2)} + ${(1 - AMBIENT).toFixed(2)} * lambert);
        }`,
    });

    let tileset = null;
    let colourByDepth = false;

    function fovFromFovy(fovy) { // Cesium's fov is the larger of the two angles
      const aspect = scene.drawingBufferWidth / scene.drawingBufferHeight;
      return aspect > 1 ? 2 * Math.atan(Math.tan(fovy / 2) * aspect) : fovy;
    }

    hv.setCamera = function (c) {
      hv.allTilesLoaded = false;
      const frustum = viewer.camera.frustum;
      if (c.fovyRadians !== undefined) frustum.fov = fovFromFovy(c.fovyRadians);
      if (c.near !== undefined) frustum.near = c.near;
      if (c.far !== undefined) frustum.far = c.far;
      viewer.camera.setView({ destination: pointToWorld(c.position),
        orientation: { direction: vectorToWorld(c.direction), up: vectorToWorld(c.up) } });
    };

    hv.camera = function () {
      const cam = viewer.camera;
      return { position: pointToLocal(cam.positionWC), direction: vectorToLocal(cam.directionWC),
        up: vectorToLocal(cam.upWC), fovyRadians: cam.frustum.fovy, near: cam.frustum.near, far: cam.frustum.far,
        pixelRatio: scene.pixelRatio };
    };

    hv.frameSize = () => [scene.drawingBufferWidth, scene.drawingBufferHeight];

    hv.redraw = () => new Promise((drawn) => {
      const stop = scene.postRender.addEventListener(() => { stop(); drawn(); });
      scene.requestRender();
    });

    hv.setMaximumScreenSpaceError = function (px) {
      hv.allTilesLoaded = false;
      const input = document.getElementById("sse");
      input.value = String(px);
      setText("sse-value", String(px));
      if (tileset) tileset.maximumScreenSpaceError = Number(px);
      scene.requestRender();
    };

    hv.setColorByDepth = function (on) {
      colourByDepth = Boolean(on);
      document.getElementById("depth-colours").checked = colourByDepth;
      scene.requestRender();
    };

    hv.setShowBoxes = function (on) {
      document.getElementById("boxes").checked = Boolean(on);
      if (tileset) tileset.debugShowBoundingVolume = Boolean(on);
      scene.requestRender();
    };

    // a content's path in the export folder (tiles/<node>.glb), whichever tileset file names it
    const exportPath = (t) => new URL(t._contentResource.url, location.href).pathname.replace(/^\/tiles\//, "");
    hv.selectedTiles = () => (tileset ? tileset._selectedTiles.map((t) => ({ uri: exportPath(t), depth: level(t) })) : []);

    hv.stats = function () {
      if (!tileset) return { tilesLoaded: 0, tilesDrawn: 0, trianglesDrawn: 0, maxDepthDrawn: -1 };
      const s = tileset.statistics;
      const selected = tileset._selectedTiles;
      return { tilesLoaded: s.numberOfTilesWithContentReady, tilesDrawn: selected.length,
        trianglesDrawn: s.numberOfTrianglesSelected, maxDepthDrawn: selected.reduce((m, t) => Math.max(m, level(t)), -1) };
    };

    // the camera around the root's bounding sphere, the whole tileset in view
    hv.fitCamera = function () {
      const sphere = tileset.boundingSphere;
      const fovy = viewer.camera.frustum.fovy;
      const fovx = 2 * Math.atan(Math.tan(fovy / 2) * scene.drawingBufferWidth / scene.drawingBufferHeight);
      const distance = 1.05 * sphere.radius / Math.sin(Math.min(fovy, fovx) / 2);
      const centre = pointToLocal(sphere.center);
      const d = c3(FIT_DIRECTION_LOCAL);
      Cesium.Cartesian3.normalize(d, d);
      const eye = [centre[0] - d.x * distance, centre[1] - d.y * distance, centre[2] - d.z * distance];
      const right = Cesium.Cartesian3.normalize(Cesium.Cartesian3.cross(d, Cesium.Cartesian3.UNIT_Z, new Cesium.Cartesian3()), new Cesium.Cartesian3());
      const up = Cesium.Cartesian3.cross(right, d, new Cesium.Cartesian3());
      hv.setCamera({ position: eye, direction: arr(d), up: arr(up) });
    };

    document.getElementById("sse").addEventListener("input", (e) => hv.setMaximumScreenSpaceError(Number(e.target.value)));
    document.getElementById("depth-colours").addEventListener("change", (e) => hv.setColorByDepth(e.target.checked));
    document.getElementById("boxes").addEventListener("change", (e) => hv.setShowBoxes(e.target.checked));
    viewer.camera.changed.addEventListener(() => { hv.allTilesLoaded = false; });

    // the panel's counters: at most every 200 ms, and once more after the last frame of a burst
    let lastCounters = 0;
    let countersLater = null;
    scene.postRender.addEventListener(() => {
      if (!tileset) return;
      hv.allTilesLoaded = tileset.tilesLoaded;
      const wait = lastCounters + 200 - performance.now();
      if (wait <= 0) updateCounters();
      else if (countersLater === null) countersLater = setTimeout(updateCounters, wait);
    });

    function updateCounters() {
      clearTimeout(countersLater);
      countersLater = null;
      lastCounters = performance.now();
      const s = hv.stats();
      setText("tiles-loaded", s.tilesLoaded.toLocaleString("en"));
      setText("tiles-drawn", s.tilesDrawn.toLocaleString("en"));
      setText("triangles-drawn", s.trianglesDrawn.toLocaleString("en"));
      setText("depth-drawn", s.maxDepthDrawn >= 0 ? String(s.maxDepthDrawn) : "-");
      if (!hv.errors.length) setText("status", hv.allTilesLoaded ? "all tiles loaded" : "loading");
    }

    Cesium.Cesium3DTileset.fromUrl("/tiles/tileset.json", {
      modelMatrix: place === null ? toWorld : Cesium.Matrix4.IDENTITY, maximumScreenSpaceError: 16,
      dynamicScreenSpaceError: false, foveatedScreenSpaceError: false, progressiveResolutionHeightFraction: 0,
      skipLevelOfDetail: false, preloadWhenHidden: true, cullRequestsWhileMoving: false,
    }).then((ts) => {
      tileset = ts;
      hv.tileset = ts;
      scene.primitives.add(ts);
      ts.customShader = FACETED;
      ts.tileFailed.addEventListener((e) => fail(`${e.url}: ${e.message}`));
      ts.tileVisible.addEventListener((tile) => {
        const want = colourByDepth ? DEPTH_COLOURS[level(tile) % DEPTH_COLOURS.length] : Cesium.Color.WHITE;
        if (!Cesium.Color.equals(tile.color, want)) tile.color = want;
      });
      hv.setMaximumScreenSpaceError(Number(document.getElementById("sse").value));
      hv.fitCamera();
      hv.ready = true;
    }).catch(fail);
  }
})();
