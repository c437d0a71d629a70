"""The evaluation report as Markdown (report.md): the figures first, with captions saying what to
read in them, then the dissertation's tables. `html_page` renders the same text as one page.

Data form: in, the report dict that evaluate.evaluate writes as report.json (measured figures only)
and the method labels; out, one Markdown string.
"""
from __future__ import annotations

from ..traversal.settings import ALPHA_MODES

# figure file -> what a reader sees in it (`figures` draws them)
FIGURE_CAPTIONS = {
    "error_vs_time.png": "Each method's mean frame time and image error (luminance RMSE against Full): lower left "
                         "is better; the grey band joins the methods that no other beats on both (the Pareto front).",
    "per_frame.png": "Per frame: drawn nodes relative to SW(P)'s (the count VMSSE asks for) and frame time relative "
                     "to Ideal's (SW(P)'s nodes without queries) for the methods that query; Full and VFC below; "
                     "the camera path's parts marked.",
    "alpha_estimators.png": "Error of each alpha estimator against the exact query count, against its cost per node.",
    "modulation.png": "Bool, Coh(P) and Coh(mu) at the frame where Coh(P) saves the most nodes: shaded, modulation "
                      "colours (blue weak, magenta moderate, red strong) and the drawn front from above.",
    "psnr_target.png": "Each (s, t) tried: drawn nodes against its lowest PSNR-Y against Bool over the PSNR frames, "
                       "one line per s (t rising along it); the dashed line is the target, the star the chosen "
                       "(s, t): the fewest nodes right of the target.",
}
NO_FIGURES = ("No figures: they were not drawn here (they need matplotlib, which Blender's Python lacks). "
              "`python -m hlod_core.report.evaluate --redraw DIR` draws them into this folder, from report.json and "
              "per_frame.npz, with a Python that has matplotlib.")


MIB = 2.0 ** 20


def _f(x, digits=2) -> str:
    """A number with thousands separators, or an en dash for a missing one."""
    return "–" if x is None else f"{x:,.{digits}f}"


def _query_options(st: dict) -> str:
    """", shift_up = ..., ..." of the settings a report records beyond tau, s, t, k and alpha (the
    query options; older reports have none)."""
    return "".join(f", {name} = {value}" for name, value in st.items() if name not in ("tau", "s", "t", "k", "alpha"))


def markdown(report: dict, *, labels: dict[str, str]) -> str:
    """report.md of a report (evaluate.evaluate's JSON); `labels`: report key -> method name shown."""
    lines = _heading(report) + _figures(report)
    if report.get("psnr_target"):
        lines += _psnr_target(report["psnr_target"], frames=len(report["psnr_frames"]))
    lines += _per_method(report["methods"], labels=labels)
    lines += _draw_cost(report["methods"], labels=labels)
    lines += _queries_off(report["methods"], labels=labels)
    lines += _relative(report["relative"], labels=labels)
    lines += _image_quality(report, labels=labels)
    if report.get("sweep"):
        lines += _sweep(report["sweep"])
    if report.get("alpha_estimators") is not None:  # a tuning report (tuning.tune) runs no alpha study
        lines += _alpha_estimators(report["alpha_estimators"])
    return "\n".join(lines) + "\n"


def _heading(report: dict) -> list[str]:
    """The title and the paragraph on the scene, the settings and how the run was timed."""
    w, h = report["size"]
    st = report["settings"]
    return [f"# HLOD evaluation: {report['frames']} frames at {w}x{h}",
            "",
            f"Scene: {report['scene']['input_tris']:,} input triangles, {report['scene']['nodes']:,} nodes, "
            f"depth {report['scene']['depth']}. tau = {st['tau']:g} px, (s, t) = ({st['s']:g}, {st['t']:g}), "
            f"k = {'inf' if st['k'] is None else st['k']}, alpha = {st['alpha']}{_query_options(st)}. "
            f"{report['repeat']} repeats, methods interleaved frame by frame in a rotating order; per frame the "
            "median over repeats, then the mean over frames. Timings compare as ratios within this run (on "
            "llvmpipe, absolute times are the CPU rasteriser's).",
            ""]


def _per_method(methods: dict, *, labels: dict[str, str]) -> list[str]:
    """Table 8.2's columns and more, a row per method."""
    lines = ["## Per method (Table 8.2 columns and more)",
             "",
             "| method | FPS | frame ms | DN | RARN | D | triangles | queries | stall ms | CPU ms | GPU ms |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for key, r in methods.items():
        lines.append(f"| {labels[key]} | {_f(r['fps'], 1)} | {_f(r['frame_ms'])} | {_f(r['dn'])} | {_f(r['rarn'])} | "
                     f"{_f(r['d'])} | {_f(r['tris'], 0)} | {_f(r['queries'], 1)} | {_f(r['stall_ms'])} | "
                     f"{_f(r['cpu_ms'])} | {_f(r['gpu_ms'])} |")
    return lines


def _draw_cost(methods: dict, *, labels: dict[str, str]) -> list[str]:
    """Draws and texture memory per frame beside triangles and time (none in a report made before
    they were counted, nor in a tuning report)."""
    if not any("draws" in r for r in methods.values()):
        return []
    lines = ["", "## Draws and texture memory per frame", "",
             "Draws: one per drawn node and material. Texture MiB: the distinct textures the drawn nodes refer to, "
             "each as RGBA8 with a full mip chain (4/3 x width x height x 4 bytes). Mean over frames, and the most.",
             "",
             "| method | triangles | frame ms | draws | draws max | texture MiB | texture MiB max |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for key, r in methods.items():
        if "draws" in r:
            lines.append(f"| {labels[key]} | {_f(r['tris'], 0)} | {_f(r['frame_ms'])} | {_f(r['draws'], 1)} | "
                         f"{_f(r['draws_max'], 0)} | {_f(r['texture_bytes'] / MIB)} | "
                         f"{_f(r['texture_bytes_max'] / MIB)} |")
    return lines


def _queries_off(methods: dict, *, labels: dict[str, str]) -> list[str]:
    """The share of frames each querying method drew without queries (settings queries "auto"), per
    part of the path, and why; nothing for a report from before the gate or where none went off."""
    rows = {k: r for k, r in methods.items() if r.get("queries_off")}
    if not rows:
        return []
    parts = list(next(iter(rows.values())).get("queries_off_by_part") or {})
    lines = ["", "## Frames without queries (they culled less than they cost)", "",
             "| method | all frames | " + " | ".join(parts) + " | why, last time |",
             "|---|---:|" + "---:|" * len(parts) + "---|"]
    for key, r in rows.items():
        by_part = r.get("queries_off_by_part") or {}
        cells = " | ".join("–" if by_part.get(p) is None else f"{by_part[p]:.0%}" for p in parts)
        lines.append(f"| {labels[key]} | {r['queries_off']:.0%} | {cells} | {r.get('queries_off_reason', '')} |")
    return lines


def _relative(relative: dict, *, labels: dict[str, str]) -> list[str]:
    """Tables 8.3 / 8.4: Coh(P) and Coh(mu) over the others."""
    lines = ["", "## Speedup and node savings (Tables 8.3 / 8.4), percent", "",
             "| method | over | speedup % | node savings % |", "|---|---|---:|---:|"]
    for coh, rows in relative.items():
        for other, r in rows.items():
            lines.append(f"| {labels[coh]} | {labels[other]} | {_f(r['speedup_pct'], 1)} | "
                         f"{_f(r['node_savings_pct'], 1)} |")
    return lines


def _image_quality(report: dict, *, labels: dict[str, str]) -> list[str]:
    """Table 8.1: PSNR of Y, Cb, Cr against Bool and Full, and the luminance RMSE against Full."""
    lines = ["", f"## Image quality (Table 8.1): PSNR dB, mean ± s.d. over {len(report['psnr_frames'])} seeded "
             "frames (100 = identical)", "",
             "| method | Y vs Bool | Cb vs Bool | Cr vs Bool | Y vs Full | Cb vs Full | Cr vs Full | RMSE Y vs Full |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for key, r in report["methods"].items():
        cells = [f"{_f(r[f'psnr_{c}_vs_{ref}'], 1)} ± {_f(r[f'psnr_{c}_vs_{ref}_sd'], 1)}"
                 if r[f"psnr_{c}_vs_{ref}"] is not None else "–"
                 for ref in ("bool", "full") for c in ("y", "cb", "cr")]
        lines.append(f"| {labels[key]} | " + " | ".join(cells) + f" | {_f(r['rmse_y_vs_full'])} |")
    return lines


def _sweep(sweep: dict) -> list[str]:
    lines = ["", f"## Sweep over {sweep['name']} (Coh(P))", "",
             "| variant | frame ms | DN | RARN | stall ms | PSNR-Y vs Bool | RMSE Y vs Full |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for key, r in sweep["points"].items():
        lines.append(f"| {key} | {_f(r['frame_ms'])} | {_f(r['dn'])} | {_f(r['rarn'])} | {_f(r['stall_ms'])} | "
                     f"{_f(r['psnr_y_vs_bool'], 1)} | {_f(r['rmse_y_vs_full'])} |")
    return lines


def _alpha_estimators(a: dict) -> list[str]:
    lines = ["", f"## alpha estimators ({a['nodes']} boxes over {a['views']} views; error against the exact "
             "`query` count)", "", "| estimator | cost µs per node | median error % | 90th percentile error % |",
             "|---|---:|---:|---:|"]
    for mode in ALPHA_MODES:
        r = a[mode]
        lines.append(f"| {mode} | {_f(r['cost_us_per_node'], 1)} | {_f(r['median_rel_error_pct'])} | "
                     f"{_f(r['p90_rel_error_pct'])} |")
    return lines + ["", "`query` is exact by definition (its cost is one extra GL query per node: charged as half "
                        "the measured time of issuing and reading both queries)."]


def _psnr_target(p: dict, *, frames: int) -> list[str]:
    """The tuning section (tuning.section's dict): what was chosen, then the curve, sorted by s and t."""
    c, bounds = p["chosen"], p["search"]
    if p["met"]:
        verdict = (f"Chosen: **(s, t) = ({c['s']:g}, {c['t']:g})**, {_f(c['dn'])} drawn nodes (Bool "
                   f"{_f(p['bool_dn'])} on average over the rounds), lowest PSNR-Y {_f(c['psnr_y'], 1)} dB "
                   f"(mean {_f(c['psnr_y_mean'], 1)}): "
                   f"the fewest drawn nodes of the candidates that meet the target.")
    else:
        verdict = f"**Target not met.** {p['note']}"
    lines = [f"## Tuned to PSNR-Y >= {p['target_db']:g} dB against Bool", "",
             verdict, "",
             f"The target holds for a candidate when its lowest PSNR-Y against Bool over the {frames} PSNR frames "
             f"reaches it (the {p['criterion']}, not the mean: a mean in dB is inflated by frames identical to Bool's, "
             "which count as 100 dB). Search: for each s in "
             f"{', '.join(f'{s:g}' for s in bounds['s_lines'])}, a bisection for the largest t of "
             f"{', '.join(f'{t:g}' for t in bounds['t_ladder'])} that meets the target (P_(s,t) falls as t rises), "
             f"and s = 0 (P = mu) once; {len(p['candidates'])} candidates tried in {bounds['rounds']} rounds "
             f"(at most {bounds['max_candidates']} in {bounds['max_rounds']}), each round Bool and its candidates "
             "interleaved on one renderer. Frame ms compare within a round (the ratio to Bool's).", "",
             "| s | t | DN | lowest PSNR-Y dB | mean PSNR-Y dB | frame ms | ÷ Bool's | round | meets |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for x in sorted(p["candidates"], key=lambda x: (x["s"], x["t"])):
        mark = " (chosen)" if (x["s"], x["t"]) == (c["s"], c["t"]) else ""
        lines.append(f"| {x['s']:g} | {x['t']:g} | {_f(x['dn'])} | {_f(x['psnr_y'], 1)} | {_f(x['psnr_y_mean'], 1)} | "
                     f"{_f(x['frame_ms'])} | {_f(x['frame_ms_vs_bool'], 3)} | {x['round'] + 1} | "
                     f"{'yes' if x['meets'] else 'no'}{mark} |")
    return lines + [""]


def _figures(report: dict) -> list[str]:
    """The Figures section: each figure and its caption, or why there are none."""
    lines = ["## Figures", ""]
    if not report.get("figures"):
        return lines + [NO_FIGURES, ""]
    for name, file in report["figures"].items():
        lines += [f"![{name}]({file})", ""]
        if file in FIGURE_CAPTIONS:
            lines += [f"*{FIGURE_CAPTIONS[file]}*", ""]
    return lines
