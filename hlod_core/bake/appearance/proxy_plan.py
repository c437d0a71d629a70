"""The bake's side of the proxy materials (docs/how-it-works.md#proxy-materials-for-the-inner-nodes):
which inner nodes decimate freely and get a proxy, the proxy images the parents' tasks read, the
PNG files the proxies are written to, and, once the simplify phase is done, their material rows.

Data form: attribute rows as appearance.pack makes them, with the proxies' material ids
(proxy.proxy_material_id: past the scene's materials); a proxy's image (h,w,4) uint8 sRGB RGBA,
top row first, written as `proxy_<node>.png` into the bake's texture folder.
"""
from __future__ import annotations

import atexit
import dataclasses
import logging
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core.atomic import write_bytes_atomic
from ...core.png import png_bytes, png_pixels
from ...model.appearance import AttributeLayout, Material
from .proxy import Proxy, ProxySettings, proxy_of_id
from .proxy_task import share_images

log = logging.getLogger(__name__)

#: zlib level of the proxies' PNGs: level 1 compresses 2.5x faster than the default 6 and its files
#: were 2% larger on the statue square's proxies (docs/performance.md#with-proxy-materials).
PNG_LEVEL = 1


@dataclass(frozen=True)
class ProxyMade:
    """What one node's proxy is: its texture file, size (texels), texel size (model units), the
    atlas's utilization, and the alpha mode of its alpha-tested part (None: opaque only)."""

    file: str
    width: int
    height: int
    texel_size: float
    utilization: float
    alpha_mode: str | None
    psnr_y: float
    psnr_reason: str | None


class ProxyPlan:
    """The proxies of one bake: scene_materials (the scene's material rows), images (material row ->
    its texture image), settings (proxy.ProxySettings), layout (the rows' columns, with material and
    UV), folder (where the PNGs are written) and reference (the folder the file's materials name:
    the published texture folder)."""

    def __init__(self, *, scene_materials: tuple, images: dict, settings: ProxySettings, layout: AttributeLayout,
                 folder: str | os.PathLike, reference: str | os.PathLike):
        self.scene_materials, self.images, self.settings, self.layout = scene_materials, images, settings, layout
        self.folder, self.reference = Path(folder), Path(reference)
        self.material_column = layout.columns()["material"].start if layout.material else None
        self.free: set[int] = set()
        self.made_proxies: dict[int, ProxyMade] = {}
        # node -> (image or, restored from the bake cache, its PNG bytes, alpha mode): what a parent reads
        self._images: dict[int, tuple[np.ndarray | bytes, str | None]] = {}

    def share(self, workers) -> None:
        """The scene's images to every worker (proxy_task.share_images)."""
        share_images(workers.scratch, self.images)

    def _ids(self, rows: np.ndarray | None) -> np.ndarray:
        if rows is None or self.material_column is None:
            return np.zeros(1, np.int64)
        return np.unique(rows[:, self.material_column]).astype(np.int64)

    def decimate_freely(self, node: int, child_rows: list) -> bool:
        """Whether the node's sources (its children's rows) have more than one material: then it is
        decimated as an untextured mesh and gets a proxy."""
        ids = np.unique(np.concatenate([self._ids(rows) for rows in child_rows]))
        if ids.size > 1:
            self.free.add(int(node))
            return True
        return False

    def wants_proxy(self, node: int, rows: np.ndarray | None) -> bool:
        """Whether the node's proxy task runs: it decimated freely, or its one material is textured
        (the task then keeps the texture where it is within the node's budget)."""
        if node in self.free:
            return True
        material = int(self._ids(rows)[0])
        if material >= len(self.scene_materials):
            return True
        return self.scene_materials[material].texture is not None and int(material) in self.images

    def child_proxies(self, child_rows: list) -> dict:
        """material id -> (image, alpha mode) of every proxy the children's rows name."""
        out = {}
        for rows in child_rows:
            for material in self._ids(rows):
                if material >= len(self.scene_materials):
                    node, _ = proxy_of_id(np.array([material]), scene_materials=len(self.scene_materials))
                    image, mode = self._images[int(node[0])]
                    if isinstance(image, bytes):  # restored from the cache: decoded once a parent reads it
                        image = png_pixels(image)
                        self._images[int(node[0])] = (image, mode)
                    out[int(material)] = (image, mode)
        return out

    def made(self, node: int, proxy: Proxy, lod):
        """Record node's proxy: its image kept for its parent's task and written as a PNG; returns
        `lod` (simplify.NodeLod) with the proxy's arrays."""
        h, w, _ = proxy.image.shape
        self._record(node, png_bytes(proxy.image, level=PNG_LEVEL), image=proxy.image,
                     width=w, height=h, texel_size=proxy.texel_size, utilization=proxy.utilization,
                     alpha_mode=proxy.alpha_mode, psnr_y=proxy.psnr_y, psnr_reason=proxy.psnr_reason)
        return dataclasses.replace(lod, positions=proxy.positions, faces=proxy.faces, normals=proxy.normals,
                                   attributes=proxy.rows)

    def restore(self, node: int, fields: dict, png: bytes) -> None:
        """Record node's proxy as the bake cache holds it (bake/run/cache_proxies.py): its texture's PNG bytes
        written, decoded only if a parent's task reads it; fields: ProxyMade's but the file."""
        self._record(node, png, image=None, **fields)

    def _record(self, node: int, png: bytes, *, image: np.ndarray | None, **fields) -> None:
        self._images[int(node)] = (png if image is None else image, fields["alpha_mode"])
        self.folder.mkdir(parents=True, exist_ok=True)
        name = f"proxy_{int(node)}.png"
        write_bytes_atomic(self.folder / name, png)
        self.made_proxies[int(node)] = ProxyMade(file=str(self.reference / name), **fields)

    def texture_bytes(self, node: int) -> bytes:
        """The PNG file of node's proxy, as written (the bake cache stores it)."""
        return (self.folder / f"proxy_{int(node)}.png").read_bytes()

    def release_children(self, node: int, layout, lods: list) -> None:
        """Drop the images of node's children that its own rows no longer name."""
        named = set(self._ids(lods[node][3]).tolist())
        first = int(layout.child_offset[node])
        for child in range(first, first + int(layout.child_count[node])):
            if child in self._images:
                ids = {2 * child + len(self.scene_materials) + a for a in (0, 1)}
                if not ids & named:
                    del self._images[child]

    def finish(self, lods: list) -> tuple[Material, ...]:
        """After the simplify phase: renumber the proxies' material ids in `lods` (in place) to
        follow the scene's materials, in the order of their ids, and return their material rows."""
        scene = len(self.scene_materials)
        used = np.unique(np.concatenate([self._ids(lod[3]) for lod in lods if lod is not None and lod[3] is not None]
                                        or [np.zeros(0, np.int64)]))
        used = used[used >= scene]
        if used.size == 0:
            return ()
        for i, lod in enumerate(lods):
            if lod is None or lod[3] is None:
                continue
            column = lod[3][:, self.material_column]
            proxy = column >= scene
            if proxy.any():
                rows = lod[3].copy()
                rows[proxy, self.material_column] = scene + np.searchsorted(used, column[proxy].astype(np.int64))
                lods[i] = (*lod[:3], rows)
        nodes, alpha = proxy_of_id(used, scene_materials=scene)
        materials = []
        for node, part in zip(nodes.tolist(), alpha.tolist()):
            made = self.made_proxies[node]
            mode = made.alpha_mode if part else "OPAQUE"
            materials.append(Material(name=f"HLOD proxy {node}" + (" (alpha)" if part else ""),
                                      base_color=(1.0, 1.0, 1.0, 1.0), metallic=0.0, roughness=0.5,
                                      texture=made.file, image=proxy_image_name(made.file),
                                      alpha_mode=mode or "OPAQUE", alpha_cutoff=0.5))
        return tuple(materials)

    def meta(self) -> dict:
        """meta["proxies"]: per proxied node its texture's size, texel size (model units), the atlas's
        utilization and the quality gate's PSNR-Y (dB), and the median PSNR-Y over them."""
        nodes = sorted(self.made_proxies)
        made = [self.made_proxies[n] for n in nodes]
        psnr = [round(float(m.psnr_y), 2) for m in made]
        return {"nodes": nodes, "width": [m.width for m in made], "height": [m.height for m in made],
                "texel_size": [float(m.texel_size) for m in made],
                "utilization": [round(float(m.utilization), 4) for m in made], "psnr_y": psnr,
                "psnr_y_median": float(np.median(psnr)) if psnr else None}

    def log_lines(self) -> list[str]:
        """The bake log's lines of the proxies: their count, the median PSNR-Y, and each node under
        the quality gate with its reason."""
        if not self.made_proxies:
            return []
        psnr = [m.psnr_y for m in self.made_proxies.values()]
        lines = [f"proxy materials: {len(psnr)} inner nodes, median PSNR-Y {np.median(psnr):.1f} dB against their "
                 "sources from where each first shows"]
        for node in sorted(self.made_proxies):
            made = self.made_proxies[node]
            if made.psnr_reason is not None:
                lines.append(f"node {node}: proxy PSNR-Y {made.psnr_y:.1f} dB, {made.psnr_reason}")
        return lines


def proxy_image_name(file: str) -> str:
    """The image name a proxy's texture goes by in Blender (appearance.Material.image): its folder's
    and file's names, within Blender's 63 characters (a texture folder per bake output)."""
    path = Path(file)
    return f"{path.parent.name[:40]}/{path.name}"


@dataclass(frozen=True, eq=False)
class PlannedBake:
    """proxy_plan's answer: the mesh to bake (with zero UVs added where its materials have none, so
    the rows have the UV column a proxy needs) and the plan."""

    mesh: object
    plan: ProxyPlan


def proxy_plan(mesh, settings, *, images: dict | None, textures) -> PlannedBake | None:
    """The ProxyPlan of a bake of `mesh` (io.meshes.TriangleMesh) at `settings` (BakeSettings), or
    None where no node can need a proxy: proxies off, no material table, or one material without a
    texture. images: material row -> its texture image; None: read from the materials' files
    (io.textures.load_material_images). A material naming a texture without an image there (the
    loader warned) shows its base colour in the proxies. textures: where the PNGs go (its `scratch` folder, named by
    the file as its `final` one); None: a temporary folder of this process's own, which the bake's
    file names and which is removed when the process exits."""
    materials = tuple(getattr(mesh, "materials", ()) or ())
    if not settings.proxy_materials or mesh.material_ids is None or not materials:
        return None
    if len(materials) == 1 and materials[0].texture is None:
        return None
    if images is None:  # the materials' own files (Pillow; without it, one warning and base colours)
        from ...io.textures import load_material_images

        images = load_material_images(materials)
    images = dict(images)
    if mesh.uvs is None:
        mesh = dataclasses.replace(mesh, uvs=np.zeros((mesh.positions.shape[0], 2), np.float32))
    layout = AttributeLayout(material=True, uv=True, color=mesh.colors is not None)
    if textures is None:
        folder = Path(tempfile.mkdtemp(prefix="hlod-proxies-"))
        atexit.register(shutil.rmtree, folder, ignore_errors=True)
        write, reference = folder, folder
    else:
        write, reference = Path(textures.scratch), Path(textures.final)
    plan = ProxyPlan(scene_materials=materials, images=images, settings=settings.proxy(), layout=layout,
                     folder=write, reference=reference.resolve())
    return PlannedBake(mesh=mesh, plan=plan)
