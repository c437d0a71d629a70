"""Evaluation (docs/evaluation.md): methods run over camera paths, image error against run time,
tuning (s, t) to a PSNR target, and the report as JSON, Markdown, HTML and figures."""
