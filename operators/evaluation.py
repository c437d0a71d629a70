"""Benchmark and Tune to PSNR (docs/user-guide.md, docs/evaluation.md): the scene camera's animation
replayed with every traversal method into an evaluation report, or searched for the (s, t) with the
fewest drawn nodes that keeps the target PSNR against Bool (addon/evaluation.py). Tune sets scene.hlod.s, t and bias to
what it chose: an undo step like the other property edits."""
from __future__ import annotations

import os

import bpy
from bpy.props import IntProperty, StringProperty

from ..addon import evaluation
from ..addon.properties import BLEND_RELATIVE_PATH
from ..hlod_core.core.errors import HlodError

#: Said after a report written without figures (Blender's Python has no matplotlib).
NO_FIGURES = "; no figures (matplotlib is not installed in Blender's Python)"


class HLOD_OT_benchmark(bpy.types.Operator):
    """Replay the scene camera's animation with every traversal method and write the evaluation report"""

    bl_idname = "hlod.benchmark"
    bl_label = "Benchmark HLOD"

    directory: StringProperty(name="Report Folder", subtype="DIR_PATH", default="//hlod_report",
                              options=BLEND_RELATIVE_PATH)
    repeat: IntProperty(name="Repeats", default=2, min=1, max=10)

    def execute(self, context):
        try:
            report, folder = evaluation.run(context, bpy.path.abspath(self.directory), self.repeat)
        except (HlodError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        coh, boolean = report["methods"].get("coh_p"), report["methods"].get("bool")
        extra = f"; Coh(P) {coh['dn']:.1f} nodes vs Bool {boolean['dn']:.1f}" if coh and boolean else ""
        if not report["figures"]:
            extra += NO_FIGURES
        self.report({"INFO"}, f"HLOD report: {os.path.join(folder, 'report.md')}{extra}")
        return {"FINISHED"}


class HLOD_OT_tune_psnr(bpy.types.Operator):
    """Set s and t to the fewest drawn nodes that keep the target PSNR against Bool on the camera's animation"""

    bl_idname = "hlod.tune_psnr"
    bl_label = "Tune to PSNR"
    bl_options = {"REGISTER", "UNDO"}  # s, t and bias change: one undo step

    directory: StringProperty(name="Report Folder", subtype="DIR_PATH", default="//hlod_tuning",
                              options=BLEND_RELATIVE_PATH)
    repeat: IntProperty(name="Repeats", default=1, min=1, max=10, description="Passes over the animation per round")

    def execute(self, context):
        props = context.scene.hlod
        try:
            report, folder = evaluation.tune(context, bpy.path.abspath(self.directory), self.repeat)
        except (HlodError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        p = report["psnr_target"]
        c = p["chosen"]
        props.bias, props.s, props.t = "P", c["s"], c["t"]  # bias P: s and t take effect
        props.last_tuning = (f"{p['target_db']:g} dB: s {c['s']:g}, t {c['t']:g}, {c['dn']:.1f} nodes "
                             f"(Bool {p['bool_dn']:.1f}), lowest PSNR-Y {c['psnr_y']:.1f} dB"
                             + ("" if p["met"] else " (target not met)"))
        where = os.path.join(folder, "report.md")
        extra = "" if report["figures"] else NO_FIGURES
        if p["met"]:
            self.report({"INFO"}, f"HLOD tuned: {props.last_tuning}; {len(p['candidates'])} (s, t) tried; "
                                  f"report {where}{extra}")
        else:
            self.report({"WARNING"}, f"HLOD tuning: {p['note']} s and t set to it; report {where}{extra}")
        return {"FINISHED"}


CLASSES = [HLOD_OT_benchmark, HLOD_OT_tune_psnr]
