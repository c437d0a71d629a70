"""The tiles CesiumJS chooses for a view against the nodes our VFC traversal draws for the same
camera and the same screen-space-error threshold, and the term that decides each tile in one set
only (benchmarks/cesium_compare.py prints the comparison; tests/test_viewer_compare.py checks it).

Both rules compute `SSE = geometricError * H / (d * 2 tan(fovy / 2))` and refine while SSE > tau;
they differ in the distance (our node's sphere, Cesium's box), Cesium's culling with children
bounds, Cesium keeping a tile with no visible child, the root's tileset error, and boxes touching a
frustum plane (TERMS). Cesium's choice is read from the viewer page in Chromium (Playwright) and
predicted by `cesium_rule.cesium_select`, a re-implementation of Cesium's rule. Why:
docs/how-it-works.md#our-selection-against-cesiumjss

Data form: a baked `Hlod` and its export's tileset.json (one tile per node with triangles, content
uri "tiles/<node>.glb", box = the node's subtree box, geometricError = the node's error), read as a
`cesium_rule.Tileset`; a `cesium_rule.Camera` in the tileset's frame.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cesium_rule import CESIUM_FAR_M, CESIUM_NEAR_M, Camera, CesiumChoice, Tileset, cesium_select
from hlod_core.export import tiles3d
from hlod_core.model.hierarchy import Hlod, query_box_pad
from hlod_core.model.view import View
from hlod_core.traversal import boxes, metrics
from hlod_core.traversal.methods import make
from hlod_core.traversal.settings import RuntimeSettings

#: An SSE or a plane distance this close (relative) to its threshold is a tie the two programs
#: may round either way (Cesium works in its own frame, a rigid transform of ours).
TIE_RELATIVE = 1e-9

#: Terms that decide a tile chosen by one side only (docs/how-it-works.md explains each).
DISTANCE = "distance: sphere (ours) vs box (Cesium)"
EYE_IN_SPHERE = "eye inside the node's sphere: ours refines whatever its error, Cesium divides it by the box distance"
CHILDREN_BOUNDS = "Cesium culls a tile none of whose children is in the frustum (cullWithChildrenBounds)"
NO_VISIBLE_CHILD = "Cesium keeps a tile above tau when no child is in the frustum"
ROOT_ERROR = "root: Cesium draws nothing while the tileset geometricError is within tau"
FRUSTUM = "frustum test at a plane (touching boxes)"
TERMS = (DISTANCE, EYE_IN_SPHERE, CHILDREN_BOUNDS, NO_VISIBLE_CHILD, ROOT_ERROR, FRUSTUM)
UNEXPLAINED = "unexplained"


# --- our side -----------------------------------------------------------------------------------

class SelectionOnly:
    """A traversal.NodeRenderer that draws nothing. VFC asks its renderer for nothing but draws (no
    queries), so the nodes it draws are decided without GL; the tests check that the GL renderer
    gives VFC the same nodes."""

    def __init__(self, hlod: Hlod):
        self.query_box_pad = query_box_pad(hlod.box_min, hlod.box_max)

    def begin_frame(self, view: View) -> None:
        pass

    def end_frame(self) -> float:
        return 0.0

    def draw_node(self, node: int, ratio_p: float) -> None:
        pass

    def issue_query(self, node: int, *, with_alpha: bool):
        raise AssertionError("VFC issues no occlusion queries")

    def available(self, query) -> bool:
        raise AssertionError("VFC issues no occlusion queries")

    def result(self, query):
        raise AssertionError("VFC issues no occlusion queries")


def vfc_nodes(hlod: Hlod, camera: Camera, *, tau_px: float, renderer=None) -> list[int]:
    """The nodes our VFC traversal draws for `camera` at threshold `tau_px` (traversal.VFC, one frame),
    in draw order; `renderer` defaults to SelectionOnly."""
    traversal = make("vfc", hlod, renderer or SelectionOnly(hlod), settings=RuntimeSettings(tau=tau_px))
    return list(traversal.frame(camera.view()).drawn)


def tile_uri(node: int) -> str:
    """The content uri tiles3d.export gives node `node`'s tile."""
    return f"{tiles3d.TILE_FOLDER}/{node}.glb"


def node_of_row(ts: Tileset, hlod: Hlod) -> np.ndarray:
    """(n,) our node id of each tile, by walking both trees together (tiles3d.tileset keeps the
    children's order and leaves out only subtrees without triangles); checked against the uris."""
    subtree_tris = hlod.tri_count.astype(np.int64).copy()
    for node in np.argsort(-hlod.depth, kind="stable").tolist():  # deepest first: sums flow up
        if hlod.parent[node] >= 0:
            subtree_tris[hlod.parent[node]] += subtree_tris[node]
    out = np.full(ts.tile_count, -1, np.int64)
    out[0] = 0
    for row in range(ts.tile_count):  # depth-first rows: a parent's row comes before its children's
        first, count = int(hlod.child_offset[out[row]]), int(hlod.child_count[out[row]])
        kept = [c for c in range(first, first + count) if subtree_tris[c] > 0] if count else []
        if len(kept) != len(ts.children[row]):
            raise ValueError(f"tile {ts.uri[row]}: {len(ts.children[row])} children, node {out[row]} has {len(kept)}")
        out[ts.children[row]] = kept
    has_uri = ts.node >= 0
    if not np.array_equal(out[has_uri], ts.node[has_uri]):
        raise ValueError("tileset.json does not belong to this HLOD: the tile uris name other nodes")
    return out


# --- the comparison -----------------------------------------------------------------------------

@dataclass
class Difference:
    """A tile one side chose and the other did not: `side` "ours" or "cesium" (who chose it), the
    deciding term (one of TERMS, or UNEXPLAINED), `tie` when the deciding values sit within
    TIE_RELATIVE of each other, and a line with the figures."""

    uri: str
    side: str
    term: str
    tie: bool
    detail: str
    at: str = ""  # the tile where the two rules decide differently


@dataclass
class _OurRule:
    """Our VFC's per-node decisions for one view: node of each tile row (n_tiles,), in the frustum,
    sphere distance (model units) and SSE (pixels) per node, leaves."""

    nodes: np.ndarray
    in_frustum: np.ndarray
    sphere_d: np.ndarray
    sse: np.ndarray
    is_leaf: np.ndarray

    @classmethod
    def of(cls, ts: Tileset, hlod: Hlod, view: View) -> "_OurRule":
        return cls(nodes=node_of_row(ts, hlod), in_frustum=boxes.boxes_in_frustum(view, hlod.box_min, hlod.box_max),
                   sphere_d=metrics.sphere_distance(view, hlod.sphere_center, hlod.sphere_radius),
                   sse=metrics.sse(view, hlod.error, center=hlod.sphere_center, radius=hlod.sphere_radius,
                                   is_leaf=hlod.is_leaf),
                   is_leaf=hlod.is_leaf)


def explain(ts: Tileset, hlod: Hlod, camera: Camera, *, tau_px: float, ours: set, cesium: set,
            choice: CesiumChoice) -> list[Difference]:
    """For every tile in one set only, the first node on its path from the root where our VFC and
    Cesium's rule decide differently (enter: in the frustum / visible; refine), and the term that
    makes them differ there."""
    rule = _OurRule.of(ts, hlod, camera.view())
    out = []
    for uri in sorted(ours ^ cesium, key=lambda u: (ts.depth[ts.row_of_uri[u]], u)):
        path = [ts.row_of_uri[uri]]
        while ts.parent[path[-1]] >= 0:
            path.append(int(ts.parent[path[-1]]))
        term, tie, detail, at = UNEXPLAINED, False, "no decision differs on the path", uri
        for row in reversed(path):
            at = ts.uri[row]
            decided = _entry_term(ts, rule, choice, row=row, tau_px=tau_px)
            if decided is None and bool(rule.in_frustum[int(rule.nodes[row])]):
                decided = _refine_term(ts, rule, choice, row=row, tau_px=tau_px)
            elif decided is None:  # neither enters: nothing below differs
                break
            if decided is not None:
                term, tie, detail = decided
                break
        out.append(Difference(uri=uri, side="ours" if uri in ours else "cesium", term=term, tie=tie, detail=detail,
                              at=at))
    return out


def _entry_term(ts: Tileset, rule: _OurRule, choice: CesiumChoice, *, row: int, tau_px: float):
    """(term, tie, detail) when our VFC and Cesium differ on entering tile `row` (in the frustum /
    visible), else None."""
    node = int(rule.nodes[row])
    where = f"{ts.uri[row]} (depth {ts.depth[row]})"
    ours_enter = bool(rule.in_frustum[node])
    cesium_enter = bool(choice.visible[row]) and (row != 0 or choice.root_sse > tau_px)
    if ours_enter == cesium_enter:
        return None
    if row == 0 and choice.visible[0]:
        return (ROOT_ERROR, _tie(choice.root_sse, tau_px), f"root SSE with the tileset error {ts.tileset_error:.4g} m: "
                f"{choice.root_sse:.4g} px <= tau {tau_px:g}")
    if ours_enter and choice.box_visible[row] and not choice.visible[row]:
        return (CHILDREN_BOUNDS, False,
                f"{where}: its box meets the frustum, none of its {len(ts.children[row])} children's does")
    return FRUSTUM, False, f"{where}: in our frustum {ours_enter}, Cesium's box test {bool(choice.box_visible[row])}"


def _refine_term(ts: Tileset, rule: _OurRule, choice: CesiumChoice, *, row: int, tau_px: float):
    """(term, tie, detail) when both enter tile `row` and differ on refining it, else None; the
    term is UNEXPLAINED when neither SSE side nor a missing visible child explains it."""
    node = int(rule.nodes[row])
    ours_refine = not rule.is_leaf[node] and rule.sse[node] > tau_px
    if ours_refine == bool(choice.refines[row]):
        return None
    figures = (f"{ts.uri[row]} (depth {ts.depth[row]}): ours {rule.sse[node]:.4g} px (sphere distance "
               f"{rule.sphere_d[node]:.4g} m), Cesium {choice.sse[row]:.4g} px (box distance "
               f"{choice.distance[row]:.4g} m), tau {tau_px:g}, error {ts.geometric_error[row]:.4g} m")
    if (rule.sse[node] > tau_px) != (choice.sse[row] > tau_px):
        term = EYE_IN_SPHERE if rule.sphere_d[node] <= 0 else DISTANCE
        return term, _tie(rule.sse[node], tau_px) or _tie(choice.sse[row], tau_px), figures
    if choice.sse[row] > tau_px and not any(choice.visible[c] for c in ts.children[row]):
        return NO_VISIBLE_CHILD, False, figures
    return UNEXPLAINED, False, figures


def _tie(value: float, threshold: float) -> bool:
    return bool(abs(value - threshold) <= TIE_RELATIVE * max(abs(threshold), 1.0))


def jaccard(a: set, b: set) -> float:
    """|a & b| / |a | b|; 1 for two empty sets."""
    union = a | b
    return len(a & b) / len(union) if union else 1.0


def compare(ts: Tileset, hlod: Hlod, camera: Camera, *, tau_px: float, cesium_uris: set | None = None,
            renderer=None) -> dict:
    """One row of the table: ours (VFC), Cesium's rule as predicted here, and Cesium's choice if
    given (else the prediction stands in for it), with the differences explained."""
    ours = {tile_uri(n) for n in vfc_nodes(hlod, camera, tau_px=tau_px, renderer=renderer)}
    choice = cesium_select(ts, camera, tau_px)
    predicted = {ts.uri[r] for r in choice.selected}
    cesium = predicted if cesium_uris is None else set(cesium_uris)
    differences = explain(ts, hlod, camera, tau_px=tau_px, ours=ours, cesium=cesium, choice=choice)
    return {"tau_px": tau_px, "ours": len(ours), "cesium": len(cesium), "both": len(ours & cesium),
            "jaccard": jaccard(ours, cesium), "predicted": len(predicted),
            "prediction_exact": predicted == cesium, "prediction_misses": sorted(predicted ^ cesium),
            "ours_only": sorted(ours - cesium), "cesium_only": sorted(cesium - ours),
            "ours_depth": _depths(ts, ours), "cesium_depth": _depths(ts, cesium),
            "differences": differences}


def _depths(ts: Tileset, uris: set) -> str:
    """'d0:n0 d1:n1 ...' of the tiles' depths."""
    depths = np.bincount([ts.depth[ts.row_of_uri[u]] for u in uris], minlength=1) if uris else np.zeros(1, int)
    return " ".join(f"{d}:{c}" for d, c in enumerate(depths.tolist()) if c)


# --- Cesium in the browser (window.hlodViewer of hlod_core/export/viewer_page) -------------------------

#: Frames a selection must stay the same, with all tiles loaded, before it is read as Cesium's choice.
STABLE_FRAMES = 3
_NEXT_FRAME_JS = "() => window.hlodViewer.redraw()"  # the page draws on demand: ask for a frame
_STATE_JS = """() => ({loaded: window.hlodViewer.allTilesLoaded === true,
    tiles: window.hlodViewer.selectedTiles().map(t => t.uri),
    size: window.hlodViewer.frameSize(), camera: window.hlodViewer.camera(),
    devicePixelRatio: window.devicePixelRatio})"""


def cesium_choose(page, camera: Camera, tau_px: float, *, timeout_s: float = 120.0) -> tuple[set, Camera]:
    """Set `camera` and the maximum SSE on the viewer page (a Playwright page showing it), wait until
    every tile is loaded and the selection has stayed the same for STABLE_FRAMES frames, and return
    (Cesium's selected uris, the camera as the page reports it: position, direction, up, fovy, the
    drawing buffer, and near, far, pixel ratio where the page gives them)."""
    page.evaluate("([c, tau]) => { window.hlodViewer.setMaximumScreenSpaceError(tau); "
                  "window.hlodViewer.setCamera(c); }", [camera.to_page(), tau_px])
    deadline = time.monotonic() + timeout_s
    previous, stable = None, 0
    while stable < STABLE_FRAMES:
        if time.monotonic() > deadline:
            raise TimeoutError(f"Cesium did not settle within {timeout_s:g} s "
                               f"(tau {tau_px:g} px, camera {camera.to_page()})")
        page.evaluate(_NEXT_FRAME_JS)
        state = page.evaluate(_STATE_JS)
        tiles = sorted(state["tiles"])
        stable = stable + 1 if state["loaded"] and tiles == previous else 0
        previous = tiles
    seen = state["camera"]
    # the page's camera: Cesium keeps direction and up orthonormal; fovy is its frustum's
    read = Camera(position=tuple(seen["position"]), direction=tuple(seen["direction"]), up=tuple(seen["up"]),
                  fovy_rad=float(seen["fovyRadians"]), buffer_px=tuple(int(v) for v in state["size"]),
                  near_m=float(seen.get("near", CESIUM_NEAR_M)), far_m=float(seen.get("far", CESIUM_FAR_M)),
                  pixel_ratio=float(seen.get("pixelRatio", 1.0)))
    return set(previous), read


# --- the benchmark ------------------------------------------------------------------------------

def scene_setups() -> dict:
    """name -> (mesh factory, target_tris, {camera name: Camera factory(buffer_px)}): the terrain
    (procedural.low_scene at scale 0.1, 200 m across, hills to 16 m: flat wide tiles whose spheres
    reach far closer to the eye than their boxes) and the default city at scale 0.25 (2 x 2
    towers on a 40 m ground). Cameras: beyond (so far that the tileset's geometricError is under
    16 px), far, middle, close-up and inside the root box."""
    from hlod_core.io import procedural

    def cams(spec):
        return {name: (lambda size, e=eye, t=target: Camera.looking_at(e, t, buffer_px=size))
                for name, (eye, target) in spec.items()}

    return {
        "terrain": (lambda: procedural.low_scene(seed=1, scale=0.1), 500, cams({
            "beyond": ([0.0, -9500.0, 3500.0], [0.0, 0.0, 0.0]), "far": ([0.0, -300.0, 120.0], [0.0, 0.0, 0.0]),
            "middle": ([60.0, -120.0, 40.0], [0.0, 0.0, 0.0]), "close": ([10.0, -30.0, 20.0], [15.0, 0.0, 5.0]),
            "inside": ([-60.0, -60.0, 14.0], [40.0, 40.0, 4.0])})),
        "city": (lambda: procedural.default_scene(seed=1, scale=0.25), 500, cams({
            "beyond": ([10.0, -2800.0, 1000.0], [10.0, 10.0, 15.0]), "far": ([10.0, -160.0, 70.0], [10.0, 10.0, 15.0]),
            "middle": ([45.0, -45.0, 35.0], [10.0, 10.0, 12.0]), "close": ([-1.0, -12.0, 4.0], [0.0, 0.0, 6.0]),
            "inside": ([10.0, -5.0, 1.7], [10.0, 25.0, 4.0])})),
    }


def bake_and_export(scene: str, out_dir: Path) -> tuple[Hlod, Tileset]:
    from hlod_core.bake.pipeline import BakeSettings, bake

    factory, target_tris, _ = scene_setups()[scene]
    hlod = bake(factory(), BakeSettings(jobs=1, target_tris=target_tris))
    tiles3d.export(hlod, out_dir)
    return hlod, Tileset.read(out_dir / "tileset.json")


class Browser:
    """Chromium from the system packages driven by Playwright (WebGL through SwiftShader), one page
    on `url` with window.hlodViewer ready; console errors collected. A context manager."""

    ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]

    def __init__(self, url: str, *, size: tuple[int, int] = (800, 600), executable: str = "/usr/bin/chromium"):
        self.url, self.size, self.executable = url, size, executable
        self.console_errors: list[str] = []

    def __enter__(self):
        from playwright.sync_api import sync_playwright

        self._playwright = sync_playwright().start()
        try:
            self._browser = self._playwright.chromium.launch(executable_path=self.executable, args=self.ARGS)
            self.page = self._browser.new_page(viewport={"width": self.size[0], "height": self.size[1]})
            self.page.on("console", lambda m: self.console_errors.append(m.text) if m.type == "error" else None)
            self.page.on("pageerror", lambda e: self.console_errors.append(str(e)))
            self.page.goto(self.url)
            self.page.wait_for_function("() => window.hlodViewer && window.hlodViewer.ready === true", timeout=120_000)
        except BaseException:
            self._playwright.stop()
            raise
        return self

    def __exit__(self, *exc):
        try:
            self._browser.close()
        finally:
            self._playwright.stop()
