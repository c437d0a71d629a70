"""Where Coh draws more nodes than SW (the DN targets: docs/evaluation.md#targets): both traversals
run on every frame of a path, one after the other on the same view and renderer, and each node Coh
draws that SW does not is put in the first class that fits (tests/dn_classes.py: finer, hidden,
under hidden, coarser, other; `missing` counts the nodes SW draws and Coh does not). Coh's extra
nodes also count as `skipped` (drawn without their query this frame) and `predicted` (newly
visited, drawn before their query).

    PYTHONPATH=. .venv/bin/python -m benchmarks.dn_excess FILE.hlod --path PATH.json [--size 640x480]
        [--variants default skip_off predict_off both_off] [--out DIR]

Prints one JSON line per variant and a Markdown table; --out writes dn_excess.json. SW's count is
the one of the same pass (SW asks every query and waits for it, so its set does not depend on
timing; Coh's does, through which results are back when it looks).
"""
from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

from hlod_core.io import hlod_file
from hlod_core.io.textures import load_images
from hlod_core.model.camera_path import load_path
from hlod_core.render.renderer import Renderer
from hlod_core.traversal.methods import make
from hlod_core.traversal.settings import RuntimeSettings

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from dn_classes import CLASSES, classify  # the classes, a test helper

#: Variants of Coh's settings by name (the rest are the defaults).
VARIANTS = {"default": {}, "skip_off": {"skip_queries": "off"}, "predict_off": {"predict_new": "off"},
            "both_off": {"skip_queries": "off", "predict_new": "off"}}


def run(hlod, path, size, *, variant: dict) -> dict:
    """One pass of SW and Coh (with `variant`'s settings) over `path`, frame by frame."""
    renderer = Renderer.create_standalone(hlod, size, images=load_images(hlod))
    try:
        sw = make("sw", hlod, renderer, settings=RuntimeSettings())
        coh = make("coh", hlod, renderer, settings=RuntimeSettings(**variant))
        classes, totals = Counter(), Counter()
        for i in range(len(path)):
            view = path.view(i, size)
            s = sw.frame(view)
            c = coh.frame(view)
            visited = sw.last_visited == sw.frame_id
            extra = set(c.drawn) - set(s.drawn)
            classes += classify(hlod.parent, coh_drawn=c.drawn, sw_drawn=s.drawn, sw_visited=visited,
                                sw_visible=sw.visible)
            totals["sw"] += s.dn
            totals["coh"] += c.dn
            totals["skipped"] += len(extra & set(c.skipped))
            totals["predicted"] += c.predicted  # all predicted nodes (not only the extra ones)
            totals["frames_above_sw"] += c.dn > s.dn
    finally:
        renderer.release()
    return {"dn_sw": totals["sw"], "dn_coh": totals["coh"], "ratio": totals["coh"] / max(totals["sw"], 1),
            "extra": {k: classes[k] for k in CLASSES}, "missing": classes["missing"],
            "extra_skipped": totals["skipped"], "predicted": totals["predicted"],
            "frames_above_sw": totals["frames_above_sw"], "frames": len(path)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file")
    parser.add_argument("--path", required=True)
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument("--out")
    args = parser.parse_args()
    size = tuple(int(x) for x in args.size.split("x"))
    hlod, path = hlod_file.load(args.file), load_path(args.path)
    table = {}
    for name in args.variants:
        table[name] = run(hlod, path, size, variant=VARIANTS[name])
        print(json.dumps({"variant": name, **table[name]}), flush=True)
    print("| Coh variant | DN Coh / SW | " + " | ".join(f"extra: {c}" for c in CLASSES)
          + " | missing | extra skipped |")
    print("|---|---:|" + "---:|" * (len(CLASSES) + 2))
    for name, row in table.items():
        print(f"| {name} | {row['dn_coh']} / {row['dn_sw']} = {row['ratio']:.4f} | "
              + " | ".join(str(row["extra"][c]) for c in CLASSES) + f" | {row['missing']} | {row['extra_skipped']} |")
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "dn_excess.json").write_text(json.dumps({"file": args.file, "path": args.path, "size": list(size),
                                                         "variants": table}, indent=1))


if __name__ == "__main__":
    main()
