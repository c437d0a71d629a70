"""Evaluation (docs/evaluation.md): methods run over camera paths, image error against run time,
tuning (s, t) to a PSNR target, and the report as JSON, Markdown, HTML and figures.

- evaluate: the evaluate command's work, from the run to the written report;
- runner: one method over a path (the run command); interleaved: variants timed frame by frame;
- rows: a report's rows and tables; image_error: PSNR between two renders;
- draw_cost: the draws and texture bytes of a frame's drawn nodes;
- tuning: (s, t) to a PSNR target; alpha_study: the alpha estimators compared;
- markdown, html_page: report.md and report.html; per_frame_file: per_frame.npz;
- figures, per_frame_figure, showcase: the figures, with figure_style and label_placement.
"""
