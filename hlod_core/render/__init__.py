"""OpenGL on moderngl: the renderer that draws nodes and query boxes for the traversal (`renderer`),
its GLSL programs (`shaders`, shared snippets in `glsl`), query boxes (`query_boxes`), materials and
textures (`materials`), cost calibration (`calibration`), query objects (`queries`), raw GL entry
points and enums (`gl_functions`), the host's GL state saved and restored (`gl_state`), GL
object ownership (`resources`), and node geometry and textures streamed under a GPU budget
(`residency` decides, `streamed_geometry` uploads, `texture_table` says what textures take); the
standalone GL context on every platform (`gl_platform`), the host's depth imported before the
queries (`depth_import`), and occlusion tested on the CPU when no GL context can be made
(`cpu_occlusion`, over the core's numpy rasteriser core/cpu_raster.py)."""
