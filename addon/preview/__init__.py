"""The live preview in the 3D viewport: its lifecycle and draw handlers (`live`, the one `PREVIEW`),
its drawing modes over one base (`mode`; `blender_context_mode`, and over `batch_drawn_mode` the
modes that test occlusion outside Blender's context against its depth: `private_context_mode`,
`cpu_context_mode`), the GL contexts it draws with (`gl_contexts`), what it draws with Blender's
gpu module (`node_batches`, `box_outlines`) and the corner statistics (`corner_text`). It hides the
baked objects and tracks their changes through the scene room, and reads material images through
the materials room.
"""
