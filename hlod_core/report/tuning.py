"""Tuning the bias P_{s,t} to an image-quality target: the (s, t) with the fewest drawn nodes whose
luminance PSNR against Bool stays at or above a target on a camera path, and the curve of drawn
nodes against PSNR over the (s, t) tried.

Papers (docs/how-it-works.md#papers): VMSSE = P_{s,t}(mu) SSE and the bias P_{s,t} = (1 - s) mu +
s S_t(mu) come from J. P. Charalambos, J. Bittner, M. Wimmer, E. Romero, "Optimized HLOD
Refinement Driven by Hardware Occlusion Queries", ISVC 2007 (section 3), and Charalambos'
dissertation ("HLOD Refinement Driven by Hardware Occlusion Queries", 2007, chapter 8), which
chose (s, t) per scene by hand and judged image quality by the PSNR of luminance against Bool
(Table 8.1). docs/how-it-works.md#vmsse-and-the-bias-p_st defines P_{s,t},
docs/how-it-works.md#tuning-s-and-t-to-a-psnr-target the search, and docs/evaluation.md the
evaluation whose loop (`interleaved`), rows (`rows`) and report writing (`evaluate.write_report`)
this reuses.

The search: a bisection over T_LADDER along each s of S_LINES, all lines advancing together, one
round a pass of Bool and each line's next candidate; the chosen candidate has the fewest drawn
nodes among those whose *lowest* PSNR-Y over the PSNR frames meets the target; when none does,
MOST_CONSERVATIVE with `met: false`.
Why: docs/how-it-works.md#tuning-s-and-t-to-a-psnr-target

Data form: `search` returns a Search: candidates (a list of Candidate, in the order tried),
the chosen one, whether it meets the target, and for the chosen one's round the report rows and
per-frame medians ((frames, len(COUNTERS)) float64) of Bool and the candidate. `tune` writes an
evaluation folder (report.json with a "psnr_target" section, report.md, report.html,
per_frame.npz, path.json, and with matplotlib psnr_target.png).
"""
from __future__ import annotations

import logging
import math
import os
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..io.textures import load_images
from ..model.camera_path import CameraPath
from ..model.hierarchy import Hlod
from ..render.renderer import Renderer
from ..render.residency import StreamingSettings
from ..traversal.settings import RuntimeSettings
from ..traversal.stats import COUNTERS
from .evaluate import write_report
from .image_error import PSNR_CAP_DB
from .interleaved import Variant, psnr_frame_indices, run_interleaved
from .per_frame_file import PER_FRAME_FILE, save_per_frame
from .rows import psnr_against, relative_tables, settings_json, variant_row

log = logging.getLogger(__name__)

#: s of the bisection lines (1.0 is the pure step P = [mu >= t]; 0.9 the default setting).
S_LINES = (0.25, 0.5, 0.75, 0.9, 1.0)
#: t tried along a line, ascending: finer where the papers' settings lie (0.05 to 0.2).
T_LADDER = (0.0, 0.01, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.5, 0.7, 1.0)
#: s = 0: P = mu whatever t; measured once, as (0, 0).
MU_SETTING = (0.0, 0.0)
#: The pointwise largest P_{s,t} (with the step: P = 1 for every visible node, unmodulated): the
#: result when no candidate meets the target.
MOST_CONSERVATIVE = (1.0, 0.0)
STEPS_PER_LINE = math.ceil(math.log2(len(T_LADDER) + 1))  # bisection over len + 1 gaps
MAX_CANDIDATES = 1 + len(S_LINES) * STEPS_PER_LINE
MAX_ROUNDS = STEPS_PER_LINE
MIN_TARGET_DB, MAX_TARGET_DB = 0.0, PSNR_CAP_DB  # PSNR >= 0 always (MSE <= 255^2); identical = the cap
CRITERION = "min"  # over the PSNR frames (module docstring)


def check_target(target_db) -> float:
    """The target as a float in [MIN_TARGET_DB, MAX_TARGET_DB] dB; InputError otherwise (NaN too)."""
    try:
        value = float(target_db)
    except (TypeError, ValueError):
        raise InputError(f"PSNR target: expected a number of dB, got {target_db!r}") from None
    if not MIN_TARGET_DB <= value <= MAX_TARGET_DB:  # NaN fails both
        raise InputError(f"PSNR target: expected dB in [{MIN_TARGET_DB:g}, {MAX_TARGET_DB:g}] "
                         f"({MAX_TARGET_DB:g} = identical to Bool), got {value:g}")
    return value


@dataclass(frozen=True)
class Candidate:
    """One (s, t) measured: Coh(P) over the path. dn: drawn nodes, mean over frames; psnr_y: the
    criterion, min over the PSNR frames of PSNR-Y against Bool (dB); psnr_y_mean: their mean (the
    report's PSNR column); frame_ms: mean frame time; frame_ms_vs_bool: that over Bool's mean frame
    time in the same round (timings compare within a round); round: the pass it ran in (0-based)."""

    s: float
    t: float
    dn: float
    psnr_y: float
    psnr_y_mean: float
    frame_ms: float
    frame_ms_vs_bool: float | None
    round: int

    @property
    def key(self) -> str:
        return candidate_key(self.s, self.t)

    def meets(self, target_db: float) -> bool:
        return self.psnr_y >= target_db


def candidate_key(s: float, t: float) -> str:
    """The variant key of Coh(P) at (s, t), as evaluate's (s, t) sweep names its points."""
    return f"coh_p s,t={s:g},{t:g}"


@dataclass
class _Line:
    """Bisection along T_LADDER for one s: the largest index that meets the target lies in
    [lo, hi), lo = -1 meaning none does (T_LADDER[lo] met, T_LADDER[hi] not, when measured)."""

    s: float
    lo: int = -1
    hi: int = len(T_LADDER)

    def next_index(self) -> int | None:
        return None if self.hi - self.lo <= 1 else (self.lo + self.hi) // 2

    def record(self, index: int, met: bool) -> None:
        if met:
            self.lo = index
        else:
            self.hi = index


@dataclass
class Search:
    """What `search` measured (module docstring)."""

    target_db: float
    candidates: list[Candidate]
    chosen: Candidate
    met: bool
    rounds: int
    step: bool  # k = inf: S_t is the step
    bool_rows: list[dict]  # per round: Bool's report row
    rows: dict = field(default_factory=dict)  # key -> report row of each candidate
    medians: dict = field(default_factory=dict)  # "bool", "coh_p" -> (frames, C) of the chosen one's round


def choose(candidates: list[Candidate], target_db: float) -> tuple[Candidate, bool]:
    """(the candidate with the fewest drawn nodes among those meeting the target, ties to the higher
    PSNR, True); if none meets it, (the MOST_CONSERVATIVE candidate, False). Raises ValueError when none
    meets it and MOST_CONSERVATIVE was not measured (search always measures it then)."""
    feasible = [c for c in candidates if c.meets(target_db)]
    if feasible:
        return min(feasible, key=lambda c: (c.dn, -c.psnr_y, c.s, c.t)), True
    for c in candidates:
        if (c.s, c.t) == MOST_CONSERVATIVE:
            return c, False
    raise ValueError(f"no candidate meets {target_db:g} dB and (s, t) = {MOST_CONSERVATIVE} was not measured")


def search(hlod: Hlod, renderer: Renderer, path: CameraPath, *, size: tuple[int, int], target_db: float,
           settings: RuntimeSettings = RuntimeSettings(), picked: list[int], repeat: int = 1) -> Search:
    """The bisection of the module docstring on `renderer` over `path`; settings other than s, t and
    bias (tau, k, alpha, ...) are kept for every candidate. `picked`: the PSNR frames."""
    target_db = check_target(target_db)
    lines = [_Line(s) for s in S_LINES]
    candidates: list[Candidate] = []
    bool_rows, rows, medians_of = [], {}, {}
    started = time.perf_counter()
    for rnd in range(MAX_ROUNDS):
        pending = [(line, line.next_index()) for line in lines]
        pending = [(line, i) for line, i in pending if i is not None]
        points = [(line.s, T_LADDER[i]) for line, i in pending] + ([MU_SETTING] if rnd == 0 else [])
        if not points:
            break
        log.info("PSNR target %g dB: round %d, (s, t) = %s", target_db, rnd + 1,
                 ", ".join(f"({s:g}, {t:g})" for s, t in points))
        bool_row, measured = _round(hlod, renderer, path, size=size, settings=settings, points=points, rnd=rnd,
                                    picked=picked, repeat=repeat, started=started)
        bool_rows.append(bool_row)
        for candidate, row, medians in measured:
            candidates.append(candidate)
            rows[candidate.key], medians_of[candidate.key] = row, medians
        met = {(c.s, c.t): c.meets(target_db) for c, _, _ in measured}
        for line, i in pending:
            line.record(i, met[(line.s, T_LADDER[i])])
    chosen, ok = choose(candidates, target_db)
    log.info("PSNR target %g dB: %s (s, t) = (%g, %g), %.1f nodes, lowest PSNR-Y %.1f dB; %d candidates",
             target_db, "chosen" if ok else "not met; most conservative", chosen.s, chosen.t, chosen.dn,
             chosen.psnr_y, len(candidates))
    return Search(target_db=target_db, candidates=candidates, chosen=chosen, met=ok, rounds=len(bool_rows),
                  step=math.isinf(settings.k), bool_rows=bool_rows, rows=rows, medians=medians_of[chosen.key])


def _round(hlod: Hlod, renderer: Renderer, path: CameraPath, *, size: tuple[int, int], settings: RuntimeSettings,
           points: list[tuple[float, float]], rnd: int, picked: list[int], repeat: int,
           started: float) -> tuple[dict, list]:
    """One pass: Bool and Coh(P) at each (s, t) of `points`, interleaved (interleaved.run_interleaved).
    Returns (Bool's report row, [(Candidate, its report row, {"bool", "coh_p": (frames, C) per-frame
    medians of this pass}) per point]). The pass's images are compared here and dropped."""
    runs = [Variant(key="bool", method="bool", settings=replace(settings, bias="P"))]
    runs += [Variant(key=candidate_key(s, t), method="coh", settings=replace(settings, s=s, t=t, bias="P"))
             for s, t in points]
    per_frame, images = run_interleaved(hlod, renderer, path, size=size, runs=runs, repeat=repeat, picked=picked,
                                        started=started, label=f"round {rnd + 1}: ")
    ms = COUNTERS.index("frame_ms")
    bool_median = np.median(per_frame["bool"], axis=0)  # per frame, over repeats
    bool_ms = float(np.mean(bool_median[:, ms]))
    measured = []
    for (s, t), v in zip(points, runs[1:]):
        row = variant_row(per_frame[v.key], images, key=v.key, picked=picked)
        psnr_y = psnr_against(images, key=v.key, ref="bool", picked=picked)[:, 0]
        candidate = Candidate(s=s, t=t, dn=row["dn"], psnr_y=float(np.min(psnr_y)), psnr_y_mean=float(np.mean(psnr_y)),
                              frame_ms=row["frame_ms"],
                              frame_ms_vs_bool=row["frame_ms"] / bool_ms if bool_ms > 0 else None, round=rnd)
        medians = {"bool": bool_median, "coh_p": np.median(per_frame[v.key], axis=0)}
        measured.append((candidate, row, medians))
    return variant_row(per_frame["bool"], images, key="bool", picked=picked), measured


def tune(hlod: Hlod, path: CameraPath, size: tuple[int, int], *, target_db: float,
         settings: RuntimeSettings = RuntimeSettings(), repeat: int = 1, out_dir: str | os.PathLike,
         psnr_frames: int = 20, seed: int = 1, figures: bool = True,
         streaming: StreamingSettings | None = None) -> dict:
    """`search` on a private headless renderer, then the report into out_dir (module docstring):
    evaluate's report of Bool and Coh(P) at the chosen (s, t) (both from the chosen candidate's
    round), with a "psnr_target" section (`section`). Returns the report (report.json's contents)."""
    target_db = check_target(target_db)
    if repeat < 1:
        raise InputError(f"repeat must be at least 1, got {repeat}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    picked = psnr_frame_indices(len(path), psnr_frames, seed)
    started = time.perf_counter()
    renderer = Renderer.create_standalone(hlod, size, images=load_images(hlod), streaming=streaming)
    try:
        found = search(hlod, renderer, path, size=size, target_db=target_db, settings=settings, picked=picked,
                       repeat=repeat)
    finally:
        renderer.release()
    chosen = replace(settings, s=found.chosen.s, t=found.chosen.t, bias="P")
    methods = {"bool": found.bool_rows[found.chosen.round], "coh_p": found.rows[found.chosen.key]}
    report = {"methods": methods, "frames": len(path), "size": list(size), "repeat": repeat,
              "settings": settings_json(chosen),
              "psnr_frames": picked, "sweep": None, "scene": hlod.summary(),
              "relative": relative_tables(methods), "psnr_target": section(found),
              "parts": [{"name": name, "start": start} for name, start in path.parts],
              "seconds": time.perf_counter() - started}
    save_per_frame(out_dir / PER_FRAME_FILE, found.medians)
    path.save(out_dir / "path.json")
    write_report(report, found.medians, out_dir, figures=figures)
    return report


def section(found: Search) -> dict:
    """report.json's "psnr_target": the target, the criterion, the chosen (s, t) with its drawn
    nodes and PSNR, whether it meets the target (and what was done when not), the search's bounds,
    and every candidate tried as {s, t, dn, psnr_y, psnr_y_mean, frame_ms, frame_ms_vs_bool, round,
    meets}."""
    c = found.chosen
    note = None
    if not found.met:
        note = (f"No (s, t) tried reaches {found.target_db:g} dB against Bool at every PSNR frame; only Bool's "
                f"own image (the reference) does. Chosen: the most conservative (s, t) = ({c.s:g}, {c.t:g}), "
                f"{'P = 1 for every visible node (unmodulated)' if found.step else 'P = S_0(mu), the largest P'}, "
                f"which Coh(P) draws at a lowest PSNR-Y of {c.psnr_y:.1f} dB.")
    bool_dn = [r["dn"] for r in found.bool_rows]
    return {"target_db": found.target_db, "criterion": CRITERION, "met": found.met,
            "chosen": {"s": c.s, "t": c.t, "dn": c.dn, "psnr_y": c.psnr_y, "psnr_y_mean": c.psnr_y_mean,
                       "frame_ms": c.frame_ms, "frame_ms_vs_bool": c.frame_ms_vs_bool},
            "note": note, "bool_dn": float(np.mean(bool_dn)),
            "search": {"s_lines": list(S_LINES), "t_ladder": list(T_LADDER), "mu_setting": list(MU_SETTING),
                       "max_candidates": MAX_CANDIDATES, "max_rounds": MAX_ROUNDS, "rounds": found.rounds},
            "candidates": [asdict(x) | {"meets": x.meets(found.target_db)} for x in found.candidates]}


def summary(report: dict) -> dict:
    """The command's "psnr_target" summary: target, met, the chosen s, t with its DN and PSNR, how
    many candidates were tried."""
    p = report["psnr_target"]
    return {"target_db": p["target_db"], "met": p["met"], **{k: p["chosen"][k] for k in ("s", "t", "dn", "psnr_y")},
            "candidates": len(p["candidates"])}
