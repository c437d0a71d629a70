"""Scene properties under `scene.hlod` (docs/user-guide.md): bake settings (with `jobs`, the bake's worker
processes, and `last_bake`, the line the panel shows about the last bake), runtime settings, overlay
settings, read-only live statistics (getters over the running preview; nothing is written from the
draw handler), `psnr_target` and `last_tuning` (Tune to PSNR's target and its last result),
`tiles_dir` (the last 3D Tiles export, which View in Browser serves), `place_*` (where a 3D Tiles
export stands on the globe), and two records: the objects
the last bake took, with content keys (`source_objects`, `source_file`; addon/scene/source_record.py) and
the objects the running preview hid (`hidden_objects`, `hidden_view_layer`;
addon/scene/source_hiding.py)."""
import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

from ..hlod_core.traversal.settings import RuntimeSettings
from .preview.live import PREVIEW
from .scene import source_record

# Path properties that may hold a path relative to the .blend ("//..."). Blender 5.0 and later (not
# 4.2 LTS) have the PATH_SUPPORTS_BLEND_RELATIVE option and print a RuntimeWarning ("does not support
# blend relative "//" prefix") when such a path is stored in a property without it; 4.2 does not know
# the option and refuses to register a property naming it. Detected by the RNA flag it sets.
BLEND_RELATIVE_PATH = ({"PATH_SUPPORTS_BLEND_RELATIVE"}
                       if "is_path_supports_blend_relative" in bpy.types.Property.bl_rna.properties else set())



def stored_path(path: str) -> str:
    """How a path property stores `path`: relative to the .blend when it is saved (the file moves
    with the project), else as given."""
    try:
        return bpy.path.relpath(path) if bpy.data.filepath else path
    except ValueError:  # another drive on Windows
        return path


METHOD_ITEMS = [
    ("coh", "Coherent (Coh)", "Coherent VMSSE traversal with refine/stop/delay prediction (the method)"),
    ("sw", "Stop and wait (SW)", "Query every node and wait: the ideal node count, slow"),
    ("simp", "Simple predictor (Simp)", "The 2006 predictor from queue positions"),
    ("bool", "Boolean culling (Bool)", "Coherent hierarchical culling, queries as booleans, plain SSE"),
    ("vfc", "Frustum culling (VFC)", "Frustum culling and SSE, no queries"),
    ("full", "Full", "Every leaf in the frustum"),
]


def _stat(name):
    return lambda self: PREVIEW.statistic(name)


def _changed_sources(self) -> int:
    tracker = source_record.tracker()
    return len(tracker.changed) if tracker is not None else 0


class HLOD_PG_source_object(bpy.types.PropertyGroup):
    """One object a bake took: `name` (the PropertyGroup's own) and its content key at the bake."""

    key: StringProperty(name="Content Key", description="blake2b of the evaluated geometry and world matrix")


class HLOD_PG_hidden_object(bpy.types.PropertyGroup):
    """One object the running preview hid: `name`, and whether it was selected before."""

    selected: BoolProperty(name="Was Selected")


class HLOD_PG_settings(bpy.types.PropertyGroup):
    # --- bake ---------------------------------------------------------------------------------
    source: EnumProperty(name="Source", items=[
        ("SELECTED", "Selected Objects", "Bake the selected objects (and the instances they make)"),
        ("COLLECTION", "Collection", "Bake every object of a collection, with its children collections"),
    ], default="SELECTED")
    collection: PointerProperty(name="Collection", type=bpy.types.Collection)
    target_tris: IntProperty(name="Triangles per Node", default=2000, min=16, max=1_000_000,
                             description="Leaf budget and LOD size of every node")
    max_depth: IntProperty(name="Max Depth", default=12, min=0, max=24, description="Deepest octree level (root = 0)")
    quality_threshold: FloatProperty(name="Decimation Quality", default=0.3, min=0.0, max=1.0,
                                     description="pymeshlab quadric quality threshold "
                                                 "(higher keeps better-shaped triangles)")
    error: EnumProperty(name="Error", items=[
        ("exact", "Exact", "Each inner node's error measured against every original triangle below it"),
        ("bound", "Bound", "Against the children's LODs plus their largest error: a faster bake, a looser "
                           "(never smaller) error, more triangles drawn")], default="exact")
    proxy_materials: BoolProperty(name="Proxy Materials", default=True,
                                  description="Inner nodes whose sources have several materials or finer textures "
                                              "than they need get one material of their own: a UV atlas and one "
                                              "base-colour texture sized by the node's error (off: every level "
                                              "keeps the sources' materials)")
    texture_cap: IntProperty(name="Texture Cap", default=1024, min=16, max=16384,
                             description="Longest side of a proxy texture, texels")
    jobs: IntProperty(name="Jobs", default=0, min=0, max=256,
                      description="Worker processes of the bake, which runs outside Blender's process; "
                                  "0 = all cores but one")
    use_cache: BoolProperty(name="Bake Cache", default=True,
                            description="Keep a cache folder beside the output (OUT.hlod.cache, safe to delete) "
                                        "so that a re-bake redoes only the parts of the octree that changed")
    output_path: StringProperty(name="Output", subtype="FILE_PATH", default="", options=BLEND_RELATIVE_PATH,
                                description="Where the .hlod goes; empty = next to the .blend, named after it")
    last_bake: StringProperty(name="Last Bake", default="",
                              description="How the last bake went: seconds, jobs, and what came from the cache")
    file: StringProperty(name="Baked File", subtype="FILE_PATH", default="", options=BLEND_RELATIVE_PATH,
                         description="The .hlod the preview shows (set by Bake)")
    tiles_dir: StringProperty(name="3D Tiles Export", subtype="DIR_PATH", default="", options=BLEND_RELATIVE_PATH,
                              description="The folder of the last 3D Tiles export (tileset.json); View in Browser "
                                          "serves it (set by Export and by View in Browser's folder)")
    # --- export: the place of a 3D Tiles export on the globe (hlod_core/export/place.py) ----------
    place_mode: EnumProperty(name="Place", items=[
        ("SCENE", "Scene's Georeference", "Where the scene's georeference says (the custom properties BlenderGIS "
                                          "or Blosm write: latitude/longitude, or a longitude/latitude CRS and its "
                                          "origin); the local frame when it has none"),
        ("MANUAL", "Longitude, Latitude", "At the longitude, latitude, height and heading below"),
        ("NONE", "Local Frame", "No place on the globe: the bake's own frame, as a viewer without a globe shows it")],
        default="SCENE", description="Where a 3D Tiles export's origin stands on the globe (WGS84)")
    # text, not FloatProperty: Blender's float properties are single precision (a metre at 120 degrees)
    place_longitude: StringProperty(name="Longitude", default="0",
                                    description="Degrees east of Greenwich (-180 to 180), decimal")
    place_latitude: StringProperty(name="Latitude", default="0", description="Degrees north (-90 to 90), decimal")
    place_height: FloatProperty(name="Height", default=0.0, min=-1e5, max=1e7, unit="LENGTH",
                                description="Metres above the WGS84 ellipsoid")
    place_heading: FloatProperty(name="Heading", default=0.0, min=-360.0, max=360.0,
                                 description="Degrees the scene turns clockwise from north seen from above "
                                             "(0: +Y north, +X east)")
    # --- runtime ------------------------------------------------------------------------------
    method: EnumProperty(name="Method", items=METHOD_ITEMS, default="coh")
    bias: EnumProperty(name="Bias", items=[("P", "P(s,t)", "VMSSE ratio P_{s,t}(mu), visual masking"),
                                           ("mu", "mu", "VMSSE ratio = mu, the visibility itself")], default="P")
    tau: FloatProperty(name="Tau (px)", default=1.0, min=0.01, max=1000.0,
                       description="Screen-space error threshold, pixels")
    s: FloatProperty(name="s", default=0.9, min=0.0, max=1.0, description="Smoothness of P_{s,t}")
    t: FloatProperty(name="t", default=0.05, min=0.0, max=1.0, description="Turnover of P_{s,t}")
    step: BoolProperty(name="Step (k = inf)", default=True,
                       description="Use the step S_t; off = logistic of steepness k")
    k: FloatProperty(name="k", default=50.0, min=1e-3, max=1e9, description="Steepness of the logistic S_t")
    alpha: EnumProperty(name="Alpha", items=[("query", "Query", "Second query, depth test off: exact"),
                                             ("projected", "Projected", "Screen area of the box's silhouette"),
                                             ("cube", "Cube", "Cube of equal volume (2006 paper)")], default="query")
    skip_queries: EnumProperty(name="Skip Queries", items=[
        ("off", "Off", "Query every node the method queries"),
        ("cheap", "Cheap", "Draw a visible node without a query when drawing it costs less than the query"),
        ("expected", "Expected", "Draw a visible node without a query when its draw, times the share of queries "
                                 "that changed anything, costs less than the query")],
        default=RuntimeSettings.skip_queries,
        description="Queries that cannot pay (the renderer's measured costs); "
                    "a skipped node is re-checked every 5 frames")
    multiquery: EnumProperty(name="Multiqueries", items=[
        ("on", "On", "Test nodes hidden last frame together, one query over their boxes (CHC++)"),
        ("lazy", "Lazy", "As On, but only once a group is full or the traversal would wait"),
        ("off", "Off", "Every node its own query")], default="on",
        description="CHC++ multiqueries: fewer queries where nodes stay hidden")
    batch_queries: BoolProperty(name="Batch Queries", default=True,
                                description="CHC++ query batching: the queries that gate nothing go out together, "
                                            "one state change for each kind")
    predict_new: BoolProperty(name="Predict New Nodes", default=RuntimeSettings.predict_new == "on",
                              description="Coh: draw a node that comes into view at once, assumed visible and "
                                          "checked by its query, while most such nodes turn out visible")
    psnr_target: FloatProperty(name="Target PSNR (dB)", default=40.0, min=0.0, max=100.0, precision=1,
                               description="Tune to PSNR: the lowest luminance PSNR against Bool's image, over the "
                                           "camera animation's sampled frames, that the tuned s and t must keep "
                                           "(100 = identical)")
    last_tuning: StringProperty(name="Last Tuning", default="",
                                description="What the last Tune to PSNR chose: s, t, drawn nodes, PSNR")
    private_context: BoolProperty(name="Private Context", default=False,
                                  description="Run the occlusion queries in a GL context of the extension's "
                                              "own, with Blender's depth imported each frame so its objects "
                                              "occlude them, and draw with Blender's gpu module (automatic on "
                                              "Metal and Vulkan; without any GL context the queries run on the "
                                              "CPU)")
    gpu_budget_mb: FloatProperty(name="GPU Memory (MB)", default=512.0, min=0.0, max=1e6, precision=0,
                                 description="GPU memory the preview's node geometry and textures may take: nodes "
                                             "are uploaded with their textures as the view wants them and the "
                                             "least recently used freed; a coarser node stands in until they "
                                             "arrive. 0 = unlimited, the whole file uploaded at the start")
    # --- overlay ------------------------------------------------------------------------------
    show_modulation: BoolProperty(name="Modulation Colours", default=True,
                                  description="Blue weak, magenta moderate, red strong occlusion-driven LOD change")
    show_boxes: BoolProperty(name="Node Boxes", default=False)
    show_delayed: BoolProperty(name="Delayed Nodes", default=False,
                               description="Boxes of nodes drawn after their own query (yellow)")
    show_rarn: BoolProperty(name="Refined After Draw", default=False, description="Boxes of RARN nodes (green)")
    show_corner_text: BoolProperty(name="Viewport Statistics", default=True,
                                   description="Method, drawn nodes, triangles (share of the sources'), queries and "
                                               "the last frame's milliseconds in the viewport's corner")
    # --- records ---------------------------------------------------------------------------------
    source_objects: CollectionProperty(type=HLOD_PG_source_object, name="Baked Objects",
                                       description="The objects the last bake took, with content keys")
    source_file: StringProperty(name="Record Of", subtype="FILE_PATH", options=BLEND_RELATIVE_PATH,
                                description="The baked file the Baked Objects record belongs to")
    hidden_objects: CollectionProperty(type=HLOD_PG_hidden_object, name="Hidden by the Preview",
                                       description="Objects the running preview hid; never in a saved file")
    hidden_view_layer: StringProperty(name="Hidden in View Layer")
    # --- live statistics (read-only) ----------------------------------------------------------
    stat_drawn: IntProperty(name="Drawn Nodes", get=_stat("dn"))
    stat_tris: IntProperty(name="Triangles", get=_stat("tris"))
    stat_queries: IntProperty(name="Queries", get=_stat("queries"))
    stat_rarn: IntProperty(name="RARN", get=_stat("rarn"))
    stat_d: IntProperty(name="Delayed (D)", get=_stat("d"))
    stat_stall_ms: FloatProperty(name="Stall ms", get=_stat("stall_ms"))
    stat_frame_ms: FloatProperty(name="Frame ms", get=_stat("frame_ms"))
    stat_resident_mb: FloatProperty(name="GPU Memory (MB)",
                                    get=lambda self: PREVIEW.statistic("resident_bytes") / 2**20,
                                    description="Node geometry and textures on the GPU after the last frame")
    stat_waiting: IntProperty(name="Nodes Waiting", get=_stat("waiting"),
                              description="Nodes the view wants that are not on the GPU yet")
    stat_changed: IntProperty(name="Changed Since Bake", get=_changed_sources,
                              description="Baked objects that changed since the bake (while the preview runs)")
    status: StringProperty(name="Status", get=lambda self: PREVIEW.status())


CLASSES = [HLOD_PG_source_object, HLOD_PG_hidden_object, HLOD_PG_settings]


def register() -> None:
    bpy.types.Scene.hlod = PointerProperty(type=HLOD_PG_settings)


def unregister() -> None:
    del bpy.types.Scene.hlod
