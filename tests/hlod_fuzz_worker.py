"""The fuzz run's worker (tests/hlod_fuzz.py starts it in a process of its own): reads `index path`
lines on stdin and answers one JSON line per case on stdout, after opening, summarising, checking
and, when it opens, rendering the file on the process's one standalone EGL context."""
from __future__ import annotations

import json
import os
import sys
import traceback
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hlod_core.io import hlod_file

ROOT = Path(__file__).resolve().parents[1]

RENDER_SIZE = (64, 48)  # viewport of the rendering check, pixels
RENDER_FRAMES = 4  # one frame of each part of the inspection path
RENDER_METHODS = ("full", "vfc", "coh")
WORKER_MEMORY_BYTES = 8 * 1024**3  # address-space limit of the worker: a runaway allocation fails fast


def worker() -> int:
    """Read `index path` lines on stdin; answer one JSON line per case on stdout."""
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (WORKER_MEMORY_BYTES, WORKER_MEMORY_BYTES))
    from helpers import standalone_gl

    out = os.fdopen(os.dup(1), "w")  # answers only: anything else written to fd 1 (Python or C) goes to stderr
    os.dup2(2, 1)
    with standalone_gl() as ctx:  # the worker's one context (its own process)
        for line in sys.stdin:
            index, path = line.rstrip("\n").split(" ", 1)
            out.write(json.dumps(run_case(ctx, Path(path), int(index))) + "\n")
            out.flush()
    return 0


def run_case(ctx, path: Path, index: int) -> dict:
    """Open, summarise, check and render one file; {"outcome": "loaded" | "refused" | "failed", ...}."""
    from hlod_core.bake import checks
    from hlod_core.core.errors import HlodError
    from hlod_core.model.camera_path import inspection_path
    from hlod_core.render.renderer import Renderer
    from hlod_core.traversal.methods import make
    from hlod_core.traversal.settings import RuntimeSettings

    stage = "load"
    renderer = None
    try:
        hlod = hlod_file.load(path, mmap=index % 2 == 0)
        stage = "info"
        json.dumps({**hlod.summary(), **checks.check(hlod), "target_tris": hlod.meta.get("target_tris"),
                    "max_depth": hlod.meta.get("max_depth"), "sources": hlod.meta.get("sources")})
        stage = "render"
        renderer = Renderer(ctx, hlod, size=RENDER_SIZE)
        camera = inspection_path(hlod, seed=max(index, 0), frames=RENDER_FRAMES)
        frames = 0
        for method in RENDER_METHODS:
            traversal = make(method, hlod, renderer, settings=RuntimeSettings())
            for i in range(len(camera)):
                traversal.frame(camera.view(i, RENDER_SIZE))
                frames += 1
        error = int(renderer.gl.get_error())
        if error:
            return {"outcome": "failed", "stage": stage, "error": f"GL error 0x{error:04x} pending after rendering"}
        return {"outcome": "loaded", "frames": frames}
    except HlodError as exc:
        message = str(exc)
        if "\n" in message or path.name not in message:
            return {"outcome": "failed", "stage": stage, "error": f"unclear refusal: {message!r}"}
        return {"outcome": "refused", "stage": stage, "message": message}
    except Exception:  # noqa: BLE001 - everything else is what the fuzz is looking for
        return {"outcome": "failed", "stage": stage, "error": traceback.format_exc()}
    finally:
        if renderer is not None:
            renderer.release()


if __name__ == "__main__":
    sys.exit(worker())
