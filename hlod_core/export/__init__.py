"""Outputs for other tools: 3D Tiles 1.1 (`tiles3d`: one tile and GLB per node, `glb`; Draco-compressed
content through `draco` and JPEG/WebP textures through `texture_codec`, both command line only; on
the globe at a WGS84 `place`), the native .hlod copy, the choice between them (`formats`), and the
localhost viewer page for a 3D Tiles export (`viewer`)."""
