"""Start the bpy module with a chosen GPU backend, for the Blender checks and measurements on
machines without a window (never used by the extension itself).

The bpy module reads no command line, and it picks its GPU backend while `import bpy` runs, from
the factory preferences: setting `preferences.system.gpu_backend` afterwards changes nothing. Blender
has an internal override, `GPU_backend_type_selection_set_override(GPUBackendType)`, which its own
`--gpu-backend` argument calls. The bpy module keeps that function's symbol in its symbol table
(.symtab, not exported), so here, before `import bpy`:

1. the bpy module's library (`bpy/__init__.so`, or `.pyd` elsewhere) is loaded with ctypes, which
   `import bpy` then reuses (the same library, loaded once);
2. the function's address is its .symtab value (read from the ELF file here: section headers,
   the symbol table and its string table) plus the library's load address (/proc/self/maps);
3. it is called with the backend's GPUBackendType value (BACKENDS).

    import blender_gpu_backend
    blender_gpu_backend.force("vulkan")   # or force_from_environment(): $HLOD_GPU_BACKEND
    import bpy
    ...  # once the GPU is initialised (a render, gpu.init() in 5.2):
    blender_gpu_backend.check("vulkan")   # RuntimeError unless gpu.platform says VULKAN

Linux only (ELF, /proc). Tried on bpy 4.2.23, 5.0.1 and 5.2.3 (whose mangled names differ: the
match is on the unmangled name inside them). Blender's Vulkan backend runs on Mesa's lavapipe
(Debian's mesa-vulkan-drivers) without a GPU; bpy 4.2's experimental one crashes in its first
render there, 5.0 and 5.2 draw.
"""
from __future__ import annotations

import ctypes
import importlib.util
import os
import struct
import sys
import tempfile

#: Blender's GPUBackendType values (GPU_platform_backend.hh): what the override takes.
BACKENDS = {"opengl": 1 << 0, "metal": 1 << 1, "vulkan": 1 << 3}
#: The function, unmangled (its C++ mangling differs between Blender versions).
OVERRIDE = "GPU_backend_type_selection_set_override"
#: The environment variable force_from_environment reads: one of BACKENDS, or empty for Blender's default.
VARIABLE = "HLOD_GPU_BACKEND"
SHT_SYMTAB = 2


def bpy_library() -> str:
    """The path of the bpy module's shared library, found without importing it."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.origin:
        raise RuntimeError("the bpy module is not installed in this Python")
    return os.path.realpath(spec.origin)


def symbol_value(path: str, name_part: str) -> int:
    """The value (address relative to the load base) of the one .symtab symbol of the ELF64 file
    `path` whose name contains `name_part`. RuntimeError when there is none or more than one."""
    with open(path, "rb") as f:
        data = f.read()
    if data[:4] != b"\x7fELF" or data[4] != 2 or data[5] != 1:
        raise RuntimeError(f"{path}: not a little-endian ELF64 file")
    section_offset, = struct.unpack_from("<Q", data, 0x28)
    entry_size, count = struct.unpack_from("<HH", data, 0x3A)
    sections = [struct.unpack_from("<IIQQQQIIQQ", data, section_offset + i * entry_size) for i in range(count)]
    found = []
    for _, kind, _, _, offset, size, link, _, _, sym_size in sections:
        if kind != SHT_SYMTAB:
            continue
        strings = sections[link][4]  # the linked string table's file offset
        wanted = name_part.encode()
        for at in range(offset, offset + size, sym_size):
            name_at, _, _, _, value, _ = struct.unpack_from("<IBBHQQ", data, at)
            end = data.index(b"\0", strings + name_at)
            if wanted in data[strings + name_at:end]:
                found.append(value)
    if len(found) != 1:
        raise RuntimeError(f"{path}: {len(found)} symbols named like {name_part} in .symtab (expected one)")
    return found[0]


def load_base(path: str) -> int:
    """The address `path` is mapped at in this process (its mapping of file offset 0)."""
    with open("/proc/self/maps") as maps:
        for line in maps:
            fields = line.split()
            if len(fields) >= 6 and fields[5] == path and int(fields[2], 16) == 0:
                return int(fields[0].split("-")[0], 16)
    raise RuntimeError(f"{path} is not mapped in this process")


def force(backend: str) -> None:
    """Make the bpy module, imported after this call, start its GPU with `backend` (one of BACKENDS).
    RuntimeError where bpy has been imported already or the override cannot be found."""
    if backend not in BACKENDS:
        raise ValueError(f"GPU backend {backend!r}: one of {', '.join(BACKENDS)}")
    if "bpy" in sys.modules:
        raise RuntimeError("the GPU backend must be chosen before `import bpy`")
    os.environ.setdefault("XDG_RUNTIME_DIR", tempfile.mkdtemp(prefix="xdg-runtime-"))  # the Vulkan loader asks
    path = bpy_library()
    ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
    override = ctypes.CFUNCTYPE(None, ctypes.c_int)(load_base(path) + symbol_value(path, OVERRIDE))
    override(BACKENDS[backend])


def force_from_environment() -> str | None:
    """force($HLOD_GPU_BACKEND) when it is set and not empty; the backend forced, or None."""
    backend = os.environ.get(VARIABLE, "").strip().lower()
    if backend:
        force(backend)
    return backend or None


def check(backend: str) -> None:
    """RuntimeError unless the bpy module's GPU, initialised by now, runs `backend`."""
    import gpu

    running = gpu.platform.backend_type_get()
    if running != backend.upper():
        raise RuntimeError(f"the bpy module's GPU backend is {running}, not {backend.upper()}")
