"""Node geometry and textures on the GPU node by node, under a byte budget
(docs/how-it-works.md#streaming-node-geometry): the GL side of `residency.Residency`, which decides
what is resident.

Data form: per resident node, its own buffers: positions (k,3) float32 (the file's, origin-relative),
indices (m,3) uint32 local to the node's vertices, and with an appearance its UVs (k,2) and colours
(k,4) float32; one vertex array for the node program and one for the appearance program. A node
reads its arrays from the (memory-mapped) file when it is uploaded, so only resident nodes take
memory. node_bytes says what a node's geometry takes: the sum of its buffers' sizes. A texture
(texture_table.TextureTable) is made with the first resident node that draws with it and released
with the last.
"""
from __future__ import annotations

import logging
import time

import numpy as np

from ..model.hierarchy import Hlod
from .residency import Plan, Residency, StreamingSettings
from .resources import GLObjects
from .texture_table import TextureTable

log = logging.getLogger(__name__)

POSITION_BYTES, INDEX_BYTES, UV_BYTES, COLOUR_BYTES = 12, 12, 8, 16


def node_bytes(hlod: Hlod, *, with_uv: bool, with_colour: bool) -> np.ndarray:
    """(n,) int64: the GPU bytes of each node's buffers (positions, indices per triangle, and the
    UVs and colours when drawn)."""
    per_vertex = POSITION_BYTES + UV_BYTES * with_uv + COLOUR_BYTES * with_colour
    return (np.asarray(hlod.vertex_count, np.int64) * per_vertex
            + np.asarray(hlod.tri_count, np.int64) * INDEX_BYTES)


def node_residency(hlod: Hlod, *, textures: TextureTable, with_uv: bool, with_colour: bool,
                   settings: StreamingSettings) -> Residency:
    """The residency of `hlod`'s nodes under `settings`: each node's geometry (node_bytes) and the
    textures of `textures` it draws with."""
    return Residency(child_offset=hlod.child_offset, child_count=hlod.child_count, depth=hlod.depth,
                     node_bytes=node_bytes(hlod, with_uv=with_uv, with_colour=with_colour),
                     node_textures=textures.node_textures(hlod), texture_bytes=textures.texture_bytes,
                     settings=settings)


class _NodeBuffers:
    """One resident node's GL objects: `vao` (node program) and `parts_vao` (appearance program or None)."""

    def __init__(self, objects: GLObjects, vao, parts_vao):
        self.objects, self.vao, self.parts_vao = objects, vao, parts_vao


class StreamedGeometry:
    """Per-node buffers and per-texture textures under `settings.budget_bytes` (module docstring).
    node_program: the renderer's one-colour program (attribute in_pos); appearance: the renderer's
    materials.MaterialParts or None; textures: the textures the budget counts (the appearance's
    own, made here when it draws textures; else those someone else draws for these nodes)."""

    def __init__(self, ctx, hlod: Hlod, *, node_program, appearance, textures: TextureTable,
                 settings: StreamingSettings):
        self.ctx, self.hlod = ctx, hlod
        self.node_program = node_program
        self.appearance = appearance
        self.parts_program = None if appearance is None else appearance.program
        self.with_uv = appearance is not None and appearance.has_uv
        self.with_colour = appearance is not None and appearance.has_color
        self.residency = node_residency(hlod, textures=textures, with_uv=self.with_uv, with_colour=self.with_colour,
                                        settings=settings)
        self._textures: dict[int, object] = {}  # texture number -> moderngl.Texture (the appearance's ones)
        self._vertex_offset = np.asarray(hlod.vertex_offset, np.int64).tolist()
        self._vertex_count = np.asarray(hlod.vertex_count, np.int64).tolist()
        self._tri_offset = np.asarray(hlod.tri_offset, np.int64).tolist()
        self._tri_count = np.asarray(hlod.tri_count, np.int64).tolist()
        self._nodes: dict[int, _NodeBuffers] = {}
        self.uploads_this_frame = 0
        if self.with_uv:
            appearance.warm_mipmaps()
        for node in self.residency.initial_uploads():
            self._upload(node)

    # --- what the renderer draws with ---------------------------------------------------------

    def drawable(self, node: int) -> int:
        """`node`, or its nearest resident ancestor when it is not resident (a caller other than a
        traversal asked for it: the traversals only draw resident nodes)."""
        resident, parent = self.residency.resident, self.hlod.parent
        while not resident[node]:
            node = int(parent[node])
        return node

    def vao(self, node: int):
        """The node's vertex array for the node program (a resident node; KeyError otherwise; None
        for a node without triangles)."""
        return self._nodes[node].vao

    def parts_vao(self, node: int):
        """The node's vertex array for the appearance program; its indices start at the node's first."""
        return self._nodes[node].parts_vao

    @property
    def gl_objects(self) -> tuple:
        """Every resident node's GL objects (buffers and vertex arrays) and the resident textures."""
        return tuple(o for buffers in self._nodes.values() for o in buffers.objects.objects) + tuple(
            self._textures.values())

    def index_base(self, node: int) -> int:
        """The node's first index in the file's index buffer (a part's `first` minus this is local)."""
        return 3 * self._tri_offset[node]

    # --- a frame ---------------------------------------------------------------------------------

    def begin_frame(self) -> None:
        self.residency.begin_frame()
        self.uploads_this_frame = 0

    def end_frame(self) -> Plan:
        """Evict and upload what the residency plans after this frame; the plan."""
        started = time.perf_counter()
        plan = self.residency.plan()
        for node in plan.evict:
            self._evict(node)
        for node in plan.upload:
            self._upload(node)
        self.uploads_this_frame = len(plan.upload)
        self.residency.upload_seconds = time.perf_counter() - started
        return plan

    def _upload(self, node: int) -> None:
        hlod, ctx = self.hlod, self.ctx
        first, count = self._vertex_offset[node], self._vertex_count[node]
        tri_first, tris = self._tri_offset[node], self._tri_count[node]
        made = self._make_textures(node)
        objects = GLObjects()
        if tris == 0:  # nothing to draw (no GL buffer can be empty)
            self._nodes[node] = _NodeBuffers(objects, None, None)
            self.residency.uploaded(node)
            return
        indices = np.asarray(hlod.indices[tri_first:tri_first + tris], np.int64) - first
        try:
            positions = objects.keep(ctx.buffer(np.ascontiguousarray(hlod.positions[first:first + count], np.float32)))
            index_buffer = objects.keep(ctx.buffer(indices.astype(np.uint32)))
            vao = objects.keep(ctx.vertex_array(self.node_program, [(positions, "3f", "in_pos")],
                                                index_buffer=index_buffer, index_element_size=4))
            parts_vao = None
            if self.parts_program is not None:
                content = [(positions, "3f", "in_pos")]
                for present, values, layout, name in ((self.with_uv, hlod.uvs, "2f", "in_uv"),
                                                      (self.with_colour, hlod.colors, "4f", "in_color")):
                    if present:
                        data = np.ascontiguousarray(values[first:first + count], np.float32)
                        content.append((objects.keep(ctx.buffer(data)), layout, name))
                parts_vao = objects.keep(ctx.vertex_array(self.parts_program, content, index_buffer=index_buffer,
                                                          index_element_size=4))
        except BaseException:
            objects.release()
            self._release_textures(made)
            raise
        self._nodes[node] = _NodeBuffers(objects, vao, parts_vao)
        self.residency.uploaded(node)

    def _make_textures(self, node: int) -> tuple[int, ...]:
        """The textures `node` brings, made when the appearance draws them (counted either way)."""
        if not self.with_uv:
            return ()
        made = []
        try:
            for number in self.residency.textures_to_make(node):
                self._textures[number] = self.appearance.make_texture(number)
                made.append(number)
        except BaseException:
            self._release_textures(made)
            raise
        return tuple(made)

    def _release_textures(self, numbers) -> None:
        for number in numbers:
            texture = self._textures.pop(number, None)
            if texture is not None:
                self.appearance.forget_texture(number)
                texture.release()

    def _evict(self, node: int) -> None:
        buffers = self._nodes.pop(node, None)
        if buffers is not None:
            buffers.objects.release()
        self._release_textures(self.residency.evicted(node))

    def release(self) -> None:
        """Free every resident node's buffers and every texture (idempotent)."""
        for node in list(self._nodes):
            self._evict(node)
