"""Appearance and atlases of the bake (docs/how-it-works.md#proxy-materials-for-the-inner-nodes): the
inner nodes' proxy materials. atlas (xatlas charts and packing at the node's texel density), texels
(where the texels lie on the LOD and which source point is nearest), surface_colour (what a
textured surface shows, averaged over a footprint), proxy (one node's proxy), proxy_task (the
worker's task), proxy_plan (the bake's side: decisions, images, files, material rows), quality (the quality gate: a
proxy's PSNR-Y against its sources)."""
