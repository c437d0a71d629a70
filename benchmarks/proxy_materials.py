"""What the coarse levels of a many-material scene cost: draws, texture memory, triangles, the root
tile's bytes, bake time and image error, for the code of one or more source trees, in one run.

    PYTHONPATH=. .venv/bin/python -m benchmarks.proxy_materials [--tree DIR ...] [--size bench|small]
        [--repeat 1] [--jobs 2] [--target-tris 2000] [--eval-size 640x480] [--out DIR]

The scene is the statue square (tests/scenes/statue_square.py: 32 statues and 4 alpha-masked bushes
on a tiled ground, 37 image-textured materials) and its far-to-near camera path. Each `--tree`
(default: this checkout; e.g. `git worktree add /tmp/before COMMIT`) runs its own code: every
command below is `python -m hlod_core ...` with PYTHONPATH=DIR, and the file's figures are read by
this script run as a subprocess with the same PYTHONPATH (`--analyse`), so a tree reads its own file.

Per tree:
    bake seconds    `bake --no-cache --jobs J`, the command's own `seconds` and the wall time, median of
                    --repeat bakes, the trees interleaved (their order alternating); and the CPU
                    seconds of the command and its workers (user + system), which a machine shared
                    with other work moves far less than the wall time;
    triangles       per inner node: mean and largest, and how many are above 1.25 x target_tris;
    draws           ranged draws per inner node (`Hlod.draw_parts`: one per node and material run),
                    per depth the largest and the mean;
    textures        per inner node, the distinct textures its parts refer to as RGBA8 with a full mip
                    chain (4/3 x w x h x 4 bytes; the images `io.textures.load_images` gives the
                    renderer): mean and largest, the root's; the largest texture side of an inner node;
    root tile       `export` (3D Tiles): the root tile's GLB and the texture files it refers to, bytes;
    path            `evaluate --methods full coh_p --tau 1` over the path with this checkout's code for
                    every tree's file (the bake is what is compared), every frame compared:
                    Coh(P)'s PSNR-Y, Cb, Cr against Full (mean over frames), and per frame on the far
                    half of the path (its first half) Coh(P)'s draws, texture bytes and triangles
                    (docs/evaluation.md#draws-and-texture-memory; a tree whose report lacks the draws
                    gives null);
    proxy PSNR-Y    the quality gate's PSNR-Y of the proxied inner nodes (meta["proxies"]["psnr_y"],
                    docs/file-format.md): the median and lowest and the count under 25 dB; null when
                    the file has no proxies.
The load average is recorded before and after. Writes report.json and report.md into --out.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OVER_FACTOR = 1.25  # bake.collapse.OVER_BUDGET_FACTOR: an inner node above this x target is over budget
MIP_CHAIN, RGBA8_BYTES = 4.0 / 3.0, 4
LOW_PSNR_DB = 25.0


def _last_json(text: str) -> dict:
    return json.loads([line for line in text.splitlines() if line.startswith("{")][-1])


def _children_cpu_seconds() -> float:
    """User + system CPU seconds of this process's finished children (and theirs: a bake's workers)."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _hlod_core(tree: Path, *args, timeout_s: float = 1800) -> dict:
    """`python -m hlod_core -q ARGS` with `tree`'s code; its last JSON line."""
    done = subprocess.run([sys.executable, "-m", "hlod_core", "-q", *map(str, args)], cwd=tree,
                          env={**os.environ, "PYTHONPATH": str(tree)}, capture_output=True, text=True,
                          timeout=timeout_s)
    if done.returncode != 0:
        raise RuntimeError(f"{tree}: hlod_core {args[0]} failed ({done.returncode}): {done.stderr.strip()[-800:]}")
    return _last_json(done.stdout)


# --- the file's figures (run with the tree's code: --analyse) --------------------------------------

def analyse(path: Path, target_tris: int) -> dict:
    """Per inner node: triangles, draws, texture bytes and sides; the root's; proxy PSNR-Y from meta."""
    from hlod_core.io import hlod_file
    from hlod_core.io.textures import load_images

    hlod = hlod_file.load(path)
    inner = np.flatnonzero(~hlod.is_leaf)
    parts = hlod.draw_parts()
    images = load_images(hlod)
    number: dict[int, int] = {}
    texture = np.full(len(hlod.materials) + 1, -1, np.int64)  # last row: parts without a material
    sides, sizes = [], []
    for row, image in sorted(images.items()):
        if id(image) not in number:
            number[id(image)] = len(sizes)
            sizes.append(MIP_CHAIN * image.shape[0] * image.shape[1] * RGBA8_BYTES)
            sides.append(max(image.shape[:2]))
        texture[row] = number[id(image)]
    part_texture = texture[parts.material]
    node_bytes, node_side = np.zeros(hlod.node_count), np.zeros(hlod.node_count, np.int64)
    for node in inner.tolist():
        used = np.unique(part_texture[parts.first[node]:parts.first[node] + parts.count[node]])
        used = used[used >= 0]
        node_bytes[node] = float(np.sum(np.asarray(sizes)[used])) if used.size else 0.0
        node_side[node] = int(np.max(np.asarray(sides)[used])) if used.size else 0
    tris, draws = hlod.tri_count[inner], parts.count[inner]
    by_depth = {}
    for d in np.unique(hlod.depth[inner]).tolist():
        level = inner[hlod.depth[inner] == d]
        by_depth[str(d)] = {"nodes": int(level.size), "draws_max": int(parts.count[level].max()),
                            "draws_mean": float(parts.count[level].mean()),
                            "tris_max": int(hlod.tri_count[level].max())}
    return {"nodes": int(hlod.node_count), "inner_nodes": int(inner.size), "materials": len(hlod.materials),
            "textures": len(sizes), "input_tris": int(hlod.meta.get("input_tris", -1)),
            "root_tris": int(hlod.tri_count[0]), "root_error": float(hlod.error[0]),
            "tris_per_inner_mean": float(tris.mean()), "tris_per_inner_max": int(tris.max()),
            "inner_over_budget": int((tris > OVER_FACTOR * target_tris).sum()),
            "root_draws": int(parts.count[0]), "draws_per_inner_mean": float(draws.mean()),
            "draws_per_inner_max": int(draws.max()), "draws_by_depth": by_depth,
            "root_texture_bytes": float(node_bytes[0]), "texture_bytes_per_inner_mean": float(node_bytes[inner].mean()),
            "texture_bytes_per_inner_max": float(node_bytes[inner].max()),
            "texture_side_per_inner_max": int(node_side[inner].max()), "root_texture_side": int(node_side[0]),
            "proxy_psnr_y": proxy_psnr(hlod.meta, inner)}


def proxy_psnr(meta: dict, inner: np.ndarray) -> dict | None:
    """The proxied inner nodes' PSNR-Y from meta["proxies"]: median, lowest, count under LOW_PSNR_DB;
    None when the file has no proxies."""
    values = np.asarray((meta.get("proxies") or {}).get("psnr_y", []), np.float64)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return None
    return {"nodes": int(values.size), "median": float(np.median(values)), "lowest": float(values.min()),
            "under_25_db": int((values < LOW_PSNR_DB).sum())}


def analyse_with(tree: Path, path: Path, target_tris: int) -> dict:
    """`analyse` run with `tree`'s code (this script as a subprocess, PYTHONPATH=tree)."""
    done = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--analyse", str(path), "--target-tris",
                           str(target_tris)], cwd=tree, env={**os.environ, "PYTHONPATH": str(tree)},
                          capture_output=True, text=True, check=True)
    return _last_json(done.stdout)


# --- the export's root tile and the path -----------------------------------------------------------

def root_tile_bytes(folder: Path) -> dict:
    """The 3D Tiles export's root tile: its content's bytes, and those of the image files it refers to."""
    tileset = json.loads((folder / "tileset.json").read_text())
    uri = tileset["root"]["content"]["uri"]
    glb = folder / uri
    data = glb.read_bytes()
    length = int.from_bytes(data[12:16], "little")
    header = json.loads(data[20:20 + length])
    files = {(glb.parent / image["uri"]).resolve() for image in header.get("images", []) if "uri" in image}
    image_bytes = sum(f.stat().st_size for f in files)
    return {"glb_bytes": len(data), "image_files": len(files), "image_bytes": image_bytes,
            "bytes": len(data) + image_bytes}


def path_figures(report_dir: Path) -> dict:
    """Coh(P) against Full from an evaluation folder: PSNR per channel (mean over the compared
    frames), and per frame on the path's first half the draws, texture bytes and triangles."""
    report = json.loads((report_dir / "report.json").read_text())
    coh = report["methods"]["coh_p"]
    out = {f"psnr_{c}_vs_full": coh[f"psnr_{c}_vs_full"] for c in ("y", "cb", "cr")}
    out["psnr_frames"] = len(report["psnr_frames"])
    with np.load(report_dir / "per_frame.npz", allow_pickle=False) as data:
        keys, counters, median = data["keys"].tolist(), data["counters"].tolist(), data["median"]
        costs = (data["cost_columns"].tolist(), data["cost_median"]) if "cost_median" in data.files else None
    half = median.shape[1] // 2
    for key in ("coh_p", "full"):
        i = keys.index(key)
        out[f"{key}_far_tris"] = float(median[i, :half, counters.index("tris")].mean())
        out[f"{key}_far_draws"] = float(costs[1][i, :half, costs[0].index("draws")].mean()) if costs else None
        out[f"{key}_far_draws_max"] = float(costs[1][i, :half, costs[0].index("draws")].max()) if costs else None
        out[f"{key}_far_texture_bytes"] = (float(costs[1][i, :half, costs[0].index("texture_bytes")].mean())
                                          if costs else None)
    out["frame_ms"] = {key: report["methods"][key]["frame_ms"] for key in ("coh_p", "full")}
    return out


# --- the run -------------------------------------------------------------------------------------

def run(trees: dict[str, Path], *, size: str, repeat: int, jobs: int, target_tris: int, eval_size: str,
        out: Path) -> dict:
    sys.path.insert(0, str(ROOT / "tests" / "scenes"))
    import statue_square

    spec, camera = statue_square.scene(size), statue_square.far_path(size)
    facts = json.loads((spec.parent / "facts.json").read_text())
    frames = len(json.loads(camera.read_text())["frames"])
    load = [os.getloadavg()]
    bakes: dict[str, list] = {name: [] for name in trees}
    for r in range(repeat):
        for name in (list(trees) if r % 2 == 0 else list(trees)[::-1]):
            started, cpu = time.perf_counter(), _children_cpu_seconds()
            summary = _hlod_core(trees[name], "bake", spec, "-o", out / f"{name}.hlod", "--no-cache", "--jobs", jobs,
                                 "--target-tris", target_tris)
            bakes[name].append({"seconds": float(summary["seconds"]), "wall_seconds": time.perf_counter() - started,
                                "cpu_seconds": _children_cpu_seconds() - cpu})
            print(f"{name}: bake {summary['seconds']:.1f} s (repeat {r + 1}/{repeat})", file=sys.stderr, flush=True)
    result = {"scene": {"spec": str(spec), "size": size, "triangles": facts["triangles"],
                        "materials": facts["materials"], "path": str(camera), "frames": frames},
              "jobs": jobs, "target_tris": target_tris, "repeat": repeat, "eval_size": eval_size, "trees": {}}
    for name, tree in trees.items():
        hlod = out / f"{name}.hlod"
        row = {"tree": str(tree), "bake_seconds": float(np.median([b["seconds"] for b in bakes[name]])),
               "bake_wall_seconds": float(np.median([b["wall_seconds"] for b in bakes[name]])),
               "bake_cpu_seconds": float(np.median([b["cpu_seconds"] for b in bakes[name]])), "bakes": bakes[name]}
        row.update(analyse_with(tree, hlod, target_tris))
        _hlod_core(tree, "export", hlod, "-o", out / f"{name}-tiles")
        row["root_tile"] = root_tile_bytes(out / f"{name}-tiles")
        # one evaluation code for every tree's file (this checkout's: its draws and texture bytes)
        _hlod_core(ROOT, "evaluate", hlod, "--out", out / f"{name}-eval", "--path", camera, "--methods", "full",
                   "coh_p", "--tau", 1, "--repeat", 1, "--psnr-frames", frames, "--size", eval_size)
        row["path"] = path_figures(out / f"{name}-eval")
        result["trees"][name] = row
        print(f"{name}: measured", file=sys.stderr, flush=True)
    load.append(os.getloadavg())
    result["load_average"] = [[round(x, 2) for x in one] for one in load]
    result["date"] = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return result


def _mb(x) -> str:
    return "–" if x is None else f"{x / 1e6:,.2f}"


def _n(x, digits=1) -> str:
    return "–" if x is None else f"{x:,.{digits}f}"


def _cells(r: dict, depths: list[str]) -> list[tuple[str, str]]:
    """(label, cell) rows of report.md for one tree's figures."""
    p, tile, proxy = r["path"], r["root_tile"], r["proxy_psnr_y"]
    rows = [("bake s (command; wall; CPU)", f"{r['bake_seconds']:.1f}; {r['bake_wall_seconds']:.1f}; "
                                            f"{r['bake_cpu_seconds']:.1f}"),
            ("root: triangles, draws, texture MB", f"{r['root_tris']:,}, {r['root_draws']}, "
                                                   f"{_mb(r['root_texture_bytes'])}"),
            ("triangles per inner node: mean, max", f"{r['tris_per_inner_mean']:,.0f}, {r['tris_per_inner_max']:,}"),
            (f"inner nodes over {OVER_FACTOR} x target", f"{r['inner_over_budget']} of {r['inner_nodes']}"),
            ("draws per inner node: mean, max", f"{r['draws_per_inner_mean']:.2f}, {r['draws_per_inner_max']}")]
    for d in depths:
        level = r["draws_by_depth"].get(d)
        rows.append((f"draws at depth {d}: max, mean",
                     "–" if level is None else f"{level['draws_max']}, {level['draws_mean']:.2f}"))
    rows += [("texture MB per inner node: mean, max", f"{_mb(r['texture_bytes_per_inner_mean'])}, "
                                                      f"{_mb(r['texture_bytes_per_inner_max'])}"),
             ("largest texture side of an inner node, px", f"{r['texture_side_per_inner_max']}"),
             ("root tile: GLB + images, MB (image files)", f"{_mb(tile['glb_bytes'])} + {_mb(tile['image_bytes'])} = "
                                                           f"{_mb(tile['bytes'])} ({tile['image_files']})"),
             ("Coh(P) vs Full, PSNR Y / Cb / Cr dB", " / ".join(_n(p[f"psnr_{c}_vs_full"]) for c in ("y", "cb", "cr"))),
             ("far half, per frame: Coh(P) draws (max)",
              f"{_n(p['coh_p_far_draws'])} ({_n(p['coh_p_far_draws_max'], 0)})"),
             ("far half, per frame: Coh(P) texture MB", _mb(p["coh_p_far_texture_bytes"])),
             ("far half, per frame: Coh(P) triangles", f"{p['coh_p_far_tris']:,.0f}"),
             ("far half, per frame: Full draws", _n(p["full_far_draws"])),
             ("frame ms: Coh(P), Full", f"{p['frame_ms']['coh_p']:.1f}, {p['frame_ms']['full']:.1f}"),
             ("proxy PSNR-Y dB: median, lowest, under 25", "–" if proxy is None else
              f"{proxy['median']:.1f}, {proxy['lowest']:.1f}, {proxy['under_25_db']}")]
    return rows


def markdown(result: dict) -> str:
    """report.md: one column per tree."""
    trees, s = result["trees"], result["scene"]
    depths = sorted({d for r in trees.values() for d in r["draws_by_depth"]}, key=int)
    cells = [_cells(r, depths) for r in trees.values()]
    lines = [f"Statue square `{s['size']}`: {s['triangles']:,} triangles, {s['materials']} materials; target_tris "
             f"{result['target_tris']}, jobs {result['jobs']}, {result['repeat']} bake(s) per tree; path "
             f"{s['frames']} frames at {result['eval_size']}, tau 1 px. {result['date']}, load average "
             f"{result['load_average'][0][0]} / {result['load_average'][1][0]} (before / after).", "",
             "| | " + " | ".join(trees) + " |", "|---|" + "---:|" * len(trees)]
    for i, (label, _) in enumerate(cells[0]):
        lines.append(f"| {label} | " + " | ".join(c[i][1] for c in cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tree", type=Path, action="append", default=None,
                        help="a source tree whose code bakes and measures (repeatable; default this checkout)")
    parser.add_argument("--size", choices=("bench", "small"), default="bench")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--target-tris", type=int, default=2000)
    parser.add_argument("--eval-size", default="640x480")
    parser.add_argument("--out", type=Path, default=None, help="keep the bakes and the reports here")
    parser.add_argument("--analyse", type=Path, default=None, help=argparse.SUPPRESS)  # the subprocess' part
    args = parser.parse_args(argv)
    if args.analyse is not None:
        print(json.dumps(analyse(args.analyse, args.target_tris)))
        return 0
    trees = {}
    for tree in args.tree or [ROOT]:
        name = tree.resolve().name
        while name in trees:
            name += "'"
        trees[name] = tree.resolve()
    out = args.out or Path(tempfile.mkdtemp(prefix="proxy-materials-"))
    out.mkdir(parents=True, exist_ok=True)
    result = run(trees, size=args.size, repeat=args.repeat, jobs=args.jobs, target_tris=args.target_tris,
                 eval_size=args.eval_size, out=out)
    (out / "report.json").write_text(json.dumps(result, indent=1))
    (out / "report.md").write_text(markdown(result))
    print(markdown(result))
    print(json.dumps({"report": str(out / "report.json"), "trees": list(trees)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
