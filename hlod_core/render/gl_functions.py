"""Raw OpenGL entry points that moderngl does not wrap, and the GL enums they take, named once.

Data form: `GL`, a namespace of the GL 3.3 core constants the project passes to raw calls (plain
ints: a class attribute reads as fast as a global, where an IntEnum member costs a descriptor call
and a conversion in every ctypes call on the per-query path); and
`GLFunctions`, ctypes function pointers resolved by moderngl's own loader (glcontext, or moderngl's
DefaultLoader for `moderngl.get_context()`), one attribute per entry point. moderngl has no
non-blocking "query result available" check and Blender's cached state must be read and restored
behind moderngl's back (docs/how-it-works.md#gl-queries), hence these.
"""
from __future__ import annotations

import ctypes


class GL:
    """GL constants (values from the OpenGL 3.3 core headers). A namespace, never instantiated."""

    NO_ERROR = 0x0000
    # capabilities (glEnable / glDisable / glIsEnabled)
    CULL_FACE = 0x0B44
    DEPTH_TEST = 0x0B71
    BLEND = 0x0BE2
    SCISSOR_TEST = 0x0C11
    # state queries (glGetIntegerv / glGetBooleanv)
    DEPTH_WRITEMASK = 0x0B72
    DEPTH_FUNC = 0x0B74
    # depth functions (glDepthFunc)
    LEQUAL = 0x0203
    ALWAYS = 0x0207
    # glBlitFramebuffer's mask and filter
    DEPTH_BUFFER_BIT = 0x0100
    NEAREST = 0x2600
    VIEWPORT = 0x0BA2
    SCISSOR_BOX = 0x0C10
    COLOR_WRITEMASK = 0x0C23
    ACTIVE_TEXTURE = 0x84E0
    VERTEX_ARRAY_BINDING = 0x85B5
    ARRAY_BUFFER_BINDING = 0x8894
    CURRENT_PROGRAM = 0x8B8D
    DRAW_FRAMEBUFFER_BINDING = 0x8CA6
    READ_FRAMEBUFFER_BINDING = 0x8CAA
    # binding targets
    ARRAY_BUFFER = 0x8892
    READ_FRAMEBUFFER = 0x8CA8
    DRAW_FRAMEBUFFER = 0x8CA9
    # queries
    TIME_ELAPSED = 0x88BF
    QUERY_RESULT = 0x8866
    QUERY_RESULT_AVAILABLE = 0x8867
    SAMPLES_PASSED = 0x8914
    # textures and the framebuffer's colour encoding (the renderer's appearance path)
    NONE = 0x0000
    FRONT_LEFT = 0x0400
    BACK_LEFT = 0x0402
    FRONT = 0x0404
    BACK = 0x0405
    TEXTURE_2D = 0x0DE1
    TEXTURE_BINDING_2D = 0x8069
    TEXTURE0 = 0x84C0
    DRAW_BUFFER0 = 0x8825
    SAMPLER_BINDING = 0x8919
    SRGB = 0x8C40
    SRGB8_ALPHA8 = 0x8C43
    FRAMEBUFFER_ATTACHMENT_COLOR_ENCODING = 0x8210
    FRAMEBUFFER_ATTACHMENT_OBJECT_TYPE = 0x8CD0
    FRAMEBUFFER_SRGB = 0x8DB9


class GLFunctions:
    """The entry points, resolved in `ctx` (a moderngl context) and called through ctypes."""

    def __init__(self, ctx):
        loader = ctx.mglo._context  # glcontext's backend, or moderngl's DefaultLoader for get_context()
        load = getattr(loader, "load", None) or loader.load_opengl_function
        u8, u32, i32 = ctypes.c_uint8, ctypes.c_uint32, ctypes.c_int32
        u8p, u32p, i32p = ctypes.POINTER(u8), ctypes.POINTER(u32), ctypes.POINTER(i32)
        u64p = ctypes.POINTER(ctypes.c_uint64)

        def fn(name, restype, *argtypes):
            addr = load(name)
            if not addr:
                raise RuntimeError(f"GL function {name} is not available in this context")
            return ctypes.CFUNCTYPE(restype, *argtypes)(addr)

        # queries
        self.gen_queries = fn("glGenQueries", None, i32, u32p)
        self.delete_queries = fn("glDeleteQueries", None, i32, u32p)
        self.is_query = fn("glIsQuery", u8, u32)
        self.begin_query = fn("glBeginQuery", None, u32, u32)
        self.end_query = fn("glEndQuery", None, u32)
        self.get_query_uiv = fn("glGetQueryObjectuiv", None, u32, u32, u32p)
        self.get_query_ui64v = fn("glGetQueryObjectui64v", None, u32, u32, u64p)
        self.flush = fn("glFlush", None)
        self.get_error = fn("glGetError", u32)
        # state
        self.color_mask = fn("glColorMask", None, u8, u8, u8, u8)
        self.depth_mask = fn("glDepthMask", None, u8)
        self.depth_func = fn("glDepthFunc", None, u32)
        self.enable = fn("glEnable", None, u32)
        self.disable = fn("glDisable", None, u32)
        self.is_enabled = fn("glIsEnabled", u8, u32)
        self.get_integerv = fn("glGetIntegerv", None, u32, i32p)
        self.get_booleanv = fn("glGetBooleanv", None, u32, u8p)
        self.bind_framebuffer = fn("glBindFramebuffer", None, u32, u32)
        self.blit_framebuffer = fn("glBlitFramebuffer", None, i32, i32, i32, i32, i32, i32, i32, i32, u32, u32)
        self.use_program = fn("glUseProgram", None, u32)
        self.bind_vertex_array = fn("glBindVertexArray", None, u32)
        self.bind_buffer = fn("glBindBuffer", None, u32, u32)
        self.viewport = fn("glViewport", None, i32, i32, i32, i32)
        self.scissor = fn("glScissor", None, i32, i32, i32, i32)
        self.active_texture = fn("glActiveTexture", None, u32)
        # textures
        self.bind_texture = fn("glBindTexture", None, u32, u32)
        self.bind_sampler = fn("glBindSampler", None, u32, u32)
        self.get_framebuffer_attachment_parameteriv = fn("glGetFramebufferAttachmentParameteriv", None, u32, u32, u32,
                                                         i32p)
