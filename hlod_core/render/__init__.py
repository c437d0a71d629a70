"""OpenGL on moderngl (docs/how-it-works.md): raw GL entry points and enums, query objects, host GL
state saved and restored, and the renderer that draws nodes and query boxes for the traversal."""
