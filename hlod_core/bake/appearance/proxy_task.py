"""The proxy task that runs on a worker (bake/run/schedule.py): decide whether an inner node needs a proxy
material and bake it (proxy.py), reading the scene's texture images that the bake shares with its
workers.

Data form: the scene's images, material row -> (h,w,4) uint8 sRGB RGBA, top row first, shared as
`image-<row>.npy` files in the bake's scratch folder (workers.Workers.scratch; memory-mapped on
first use) or, inline (folder ""), this process's own arrays; each worker keeps the mip chains it
made (surface_colour.MipChain) for the next tasks, at most CHAINS_KEPT of them.
"""
from __future__ import annotations

import os
import threading

import numpy as np

from ...model.appearance import AttributeLayout, Material
from .atlas import surface_area, texture_side
from .proxy import EXPECTED_PACKING, WHITE, Proxy, ProxySettings, SourceLooks, bake_proxy, proxy_of_id
from .surface_colour import MipChain

#: Coarsest mip level a child proxy's texture is read at: its charts have PADDING_TEXELS of padding
#: (atlas.py), so level 1 mixes no neighbouring chart, and a coarser one would.
ATLAS_MAX_LEVEL = 1


class AtlasChain(MipChain):
    """The mip chain of a child proxy's atlas texture, read no coarser than ATLAS_MAX_LEVEL."""

    @staticmethod
    def of(image_rgba8_top_first: np.ndarray) -> "AtlasChain":
        MipChain.of(image_rgba8_top_first)  # its checks (the levels are built when first read)
        return AtlasChain(image_rgba8_top_first)

    def sample(self, uv: np.ndarray, level: np.ndarray) -> np.ndarray:
        return super().sample(uv, np.minimum(level, ATLAS_MAX_LEVEL))

#: Mip chains a worker keeps (the oldest go first).
CHAINS_KEPT = 64

_INLINE: dict[int, np.ndarray] = {}
_CHAINS: dict[tuple[str, int], MipChain] = {}
_LOCK = threading.Lock()


def share_images(folder: str, images: dict[int, np.ndarray]) -> None:
    """Make the scene's `images` readable by every worker: .npy files in `folder`, or inline ("")."""
    if folder:
        for row, image in images.items():
            np.save(os.path.join(folder, f"image-{int(row)}.npy"), np.ascontiguousarray(image, np.uint8))
    else:
        with _LOCK:
            _INLINE.clear()
            _INLINE.update(images)
            for key in [k for k in _CHAINS if k[0] == ""]:
                del _CHAINS[key]


def release_images(folder: str) -> None:
    """Forget `folder`'s mip chains (and, inline, the images)."""
    with _LOCK:
        for key in [k for k in _CHAINS if k[0] == folder]:
            del _CHAINS[key]
        if not folder:
            _INLINE.clear()


def scene_chain(folder: str, row: int) -> MipChain | None:
    """The mip chain of the scene image of material `row`, or None when it has none."""
    key = (folder, int(row))
    with _LOCK:
        chain = _CHAINS.get(key)
    if chain is not None:
        return chain
    if folder:
        path = os.path.join(folder, f"image-{int(row)}.npy")
        image = np.load(path, mmap_mode="r") if os.path.exists(path) else None
    else:
        image = _INLINE.get(int(row))
    if image is None:
        return None
    chain = MipChain.of(np.asarray(image))
    with _LOCK:
        _CHAINS[key] = chain
        while len(_CHAINS) > CHAINS_KEPT:
            del _CHAINS[next(iter(_CHAINS))]
    return chain


def make_proxy(folder: str, lod: tuple, error: float, sources: list[tuple], *, node: int, layout: AttributeLayout,
               scene_materials: tuple, child_proxies: dict, settings: ProxySettings, free: bool) -> Proxy | None:
    """The node's proxy (proxy.bake_proxy), or None where it keeps its sources' material: a node
    decimated with its rows (`free` False: one material) whose material's texture has no more texels
    than the node's texture would (atlas.texture_side), or has no texture.
    child_proxies: material id -> (image (h,w,4) uint8 top row first, alpha mode) of the children's
    proxies their rows name."""
    scene_count = len(scene_materials)
    columns = layout.columns()
    used = set()
    if "material" in columns:
        for s in sources:
            used.update(np.unique(s[2][np.asarray(s[1])[:, 0], columns["material"].start]).astype(np.int64).tolist())
    else:
        used = {0}
    materials, chains = {}, {}
    for material in sorted(used):
        if material < scene_count:
            materials[material] = scene_materials[material]
            chain = scene_chain(folder, material) if scene_materials[material].texture is not None else None
        else:
            image, mode = child_proxies[material]
            _, alpha = proxy_of_id(np.array([material]), scene_materials=scene_count)
            materials[material] = Material(name="proxy", base_color=WHITE,
                                           alpha_mode=mode if alpha[0] else "OPAQUE")
            chain = AtlasChain.of(image)
        if chain is not None:
            chains[material] = chain
    if not free:
        if not chains:
            return None
        texel_size = max(float(error), 0.0) / settings.tau_px
        area = surface_area(lod[0], lod[1])
        side = texture_side(area, texel_size, efficiency=EXPECTED_PACKING, floor=settings.texture_floor,
                            cap=settings.texture_cap)
        (chain,) = chains.values()
        if chain.width * chain.height <= side * side:
            return None  # the source's texture is already within the node's budget
    return bake_proxy(lod, error, sources, node=node, layout=layout, looks=SourceLooks(materials, chains),
                      scene_materials=scene_count, settings=settings)
