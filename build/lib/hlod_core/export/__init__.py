"""Outputs for other tools: 3D Tiles 1.1 (one tile and GLB per node), the native .hlod copy, and the
localhost viewer page for a 3D Tiles export."""
