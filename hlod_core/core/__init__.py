"""Shared helpers every room of the core uses: typed errors (`errors`), array helpers (`arrays`),
the one atomic write (`atomic`), nesting-limited JSON (`jsonutil`), PNG writing (`png`), colour
conversions and the overlay's colour ramp (`colour`), stop signals (`signals`), the bake's process
tree on each platform (`process_tree`), triangles rasterised with numpy (`cpu_raster`: the CPU
occlusion test's and the bake's quality gate's), freed buffers given back to the system in the bake's
processes (`heap`). Imports nothing else of the core."""
