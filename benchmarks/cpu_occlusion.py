"""The CPU occlusion test against real GL queries (docs/performance.md#the-cpu-occlusion-test).

    .venv/bin/python -m hlod_core scene default -o out/default.hlod
    .venv/bin/python -m benchmarks.cpu_occlusion out/default.hlod [--sizes 320x240,640x480]
        [--factors 1,2,4,8] [--methods sw,coh] [--frames 30]

On the street walk of benchmarks.depth_import (the default city's first street), with no wall and
with a wall over the left half of the view at 5 m (depth_import.wall_depth) given to both as the
host's depth, for each size, reduction factor and method:
- the traversal on the GL renderer (queries, Mesa llvmpipe) and on render.cpu_occlusion.CpuOcclusion,
  frame by frame side by side (a method is a traversal_table entry: `coh:skip_queries=off`): the mean over frames of the
  nodes drawn on the CPU over those drawn with queries, and the PSNR-Y (median, minimum) of the frames drawn from the
  CPU's node lists against the query path's (both drawn by the GL renderer, the wall's depth in both);
- CPU milliseconds per frame (median of the CPU traversal's frame_ms; of which rasterising draws
  and queries);
- with SW (stop and wait: every result awaited, so both traversals decide from the same results
  wherever the tests agree), per test: the share of tests whose visibility (q > 0) differs from the
  GL query's at the same depth buffer state, and the mean |mu_cpu - mu_gl| (mu = min(q / alpha, 1)),
  measured by a paired renderer that draws into both and tests in both, the traversal following GL.

Prints one JSON line per row, then a Markdown table.
"""
from __future__ import annotations

import argparse
import json

import numpy as np

from hlod_core.io import hlod_file
from hlod_core.render.cpu_occlusion import CpuOcclusion
from hlod_core.render.depth_import import wall_depth
from hlod_core.render.renderer import Renderer
from hlod_core.report import image_error
from hlod_core.traversal.methods import make
from hlod_core.traversal.settings import RuntimeSettings

from .depth_import import WALL_M, street_path
from .traversal_table import parse_entry


class Paired:
    """A NodeRenderer drawing into the GL renderer and the CPU test alike and testing in both: the
    traversal follows GL's results; each (GL, CPU) pair of (q, alpha) is recorded."""

    def __init__(self, gl: Renderer, cpu: CpuOcclusion):
        self.gl, self.cpu = gl, cpu
        self.query_box_pad = gl.query_box_pad
        self.pairs: list[tuple[int, int, int, int]] = []  # q_gl, alpha_gl, q_cpu, alpha_cpu
        self._cpu_results: dict[int, tuple[int, int]] = {}

    def begin_frame(self, view):
        self.gl.begin_frame(view)
        self.cpu.begin_frame(view)

    def end_frame(self):
        self.cpu.end_frame()
        return self.gl.end_frame()

    def draw_node(self, node, ratio_p=1.0):
        self.gl.draw_node(node, ratio_p)
        self.cpu.draw_node(node, ratio_p)

    def issue_query(self, node, *, with_alpha):
        query = self.gl.issue_query(node, with_alpha=True)
        cpu = self.cpu.issue_query(node, with_alpha=True)
        self._cpu_results[id(query)] = (cpu.q, cpu.alpha)
        return query

    def available(self, query):
        return self.gl.available(query)

    def result(self, query):
        q, alpha, stall = self.gl.result(query)
        q_cpu, alpha_cpu = self._cpu_results.pop(id(query))
        self.pairs.append((q, alpha, q_cpu, alpha_cpu))
        return q, alpha, stall


def agreement(hlod, size, factor: int, wall: bool, frames: int) -> dict:
    """SW through `Paired`: the share of tests whose visibility differs and the mean |mu| difference."""
    path = street_path(frames)
    gl = Renderer.create_standalone(hlod, size)
    try:
        cpu = CpuOcclusion(hlod, size, factor=factor)
        paired = Paired(gl, cpu)
        traversal = make("sw", hlod, paired, settings=RuntimeSettings())
        for i in range(len(path)):
            view = path.view(i, size)
            depth = wall_depth(view, distance=WALL_M) if wall else None
            gl.set_scene_depth(depth)
            cpu.set_scene_depth(depth)
            traversal.frame(view)
    finally:
        gl.release()
    pairs = np.array(paired.pairs, np.float64).reshape(-1, 4)

    def mu(q, a):
        return np.where(a > 0, np.minimum(q / np.maximum(a, 1), 1.0), 0.0)

    return {"tests": len(pairs), "visibility_differs": float(np.mean((pairs[:, 0] > 0) != (pairs[:, 2] > 0))),
            "mu_error_mean": float(np.mean(np.abs(mu(pairs[:, 0], pairs[:, 1]) - mu(pairs[:, 2], pairs[:, 3]))))}


def side_by_side(hlod, size, factor: int, method: str, wall: bool, frames: int) -> dict:
    """The method on GL queries and on the CPU test, frame by frame (module notes)."""
    path = street_path(frames)
    gl = Renderer.create_standalone(hlod, size)
    try:
        cpu = CpuOcclusion(hlod, size, factor=factor)
        name, settings = parse_entry(method)
        with_queries = make(name, hlod, gl, settings=settings)
        on_cpu = make(name, hlod, cpu, settings=settings)
        ratios, psnr, cpu_ms, draw_ms, query_ms, dn_gl, dn_cpu = [], [], [], [], [], [], []
        for i in range(len(path)):
            view = path.view(i, size)
            depth = wall_depth(view, distance=WALL_M) if wall else None
            gl.set_scene_depth(depth)
            cpu.set_scene_depth(depth)
            reference = with_queries.frame(view)
            image = gl.read_pixels()
            tested = on_cpu.frame(view)
            gl.begin_frame(view, time_gpu=False)  # the CPU's nodes, drawn by GL with the same depth
            for node in tested.drawn:
                gl.draw_node(node, 1.0)
            gl.end_frame()
            psnr.append(float(image_error.psnr(image, gl.read_pixels())[0]))
            ratios.append(tested.dn / reference.dn if reference.dn else float(tested.dn == 0))
            dn_gl.append(reference.dn)
            dn_cpu.append(tested.dn)
            cpu_ms.append(tested.frame_ms)
            draw_ms.append(cpu.draw_ms)
            query_ms.append(cpu.query_ms)
    finally:
        gl.release()
    return {"dn_queries": float(np.mean(dn_gl)), "dn_cpu": float(np.mean(dn_cpu)),
            "drawn_nodes_ratio": float(np.mean(ratios)), "psnr_y_median": float(np.median(psnr)),
            "psnr_y_min": float(np.min(psnr)), "cpu_ms_median": float(np.median(cpu_ms)),
            "draw_ms_median": float(np.median(draw_ms)), "query_ms_median": float(np.median(query_ms))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file")
    parser.add_argument("--sizes", default="320x240,640x480")
    parser.add_argument("--factors", default="1,2,4,8")
    parser.add_argument("--methods", default="sw,coh,coh:skip_queries=off",
                        help="traversal_table's entries, separated by semicolons if they hold commas")
    parser.add_argument("--frames", type=int, default=30)
    args = parser.parse_args()
    hlod = hlod_file.load(args.file)
    rows = []
    for size in (tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")):
        for factor in (int(f) for f in args.factors.split(",")):
            for wall in (False, True):
                agree = agreement(hlod, size, factor, wall, args.frames)
                for method in args.methods.split(";" if ";" in args.methods else ","):
                    row = {"size": f"{size[0]}x{size[1]}", "factor": factor, "wall": wall, "method": method,
                           **side_by_side(hlod, size, factor, method, wall, args.frames), **agree}
                    print(json.dumps(row), flush=True)
                    rows.append(row)
    print("\n| size | factor | wall | method | nodes, queries / CPU | ratio | PSNR-Y median / min (dB) "
          "| CPU ms (draws / tests) | visibility differs (SW) | mean abs mu error (SW) |")
    print("|---|---:|---|---|---|---:|---|---|---:|---:|")
    for r in rows:
        print(f"| {r['size']} | {r['factor']} | {'yes' if r['wall'] else 'no'} | {r['method']} | "
              f"{r['dn_queries']:.1f} / {r['dn_cpu']:.1f} | {r['drawn_nodes_ratio']:.3f} | "
              f"{r['psnr_y_median']:.1f} / {r['psnr_y_min']:.1f} | {r['cpu_ms_median']:.1f} "
              f"({r['draw_ms_median']:.1f} / {r['query_ms_median']:.1f}) | {r['visibility_differs']:.3f} | "
              f"{r['mu_error_mean']:.3f} |")


if __name__ == "__main__":
    main()
