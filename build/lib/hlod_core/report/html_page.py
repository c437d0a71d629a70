"""The evaluation report as one self-contained HTML page (report.html): report.md's text and tables
rendered, every figure embedded as a base64 PNG data URI; no script, no link to anything outside
the file, so it opens anywhere (a browser offline, a mail attachment, Blender's file browser).

Data form: in, the report dict (evaluate's report.json), the method labels and the folder holding
the figures' PNG files; out, one HTML string. The Markdown it renders is the subset `markdown`
writes: `#`/`##` headings, paragraphs, pipe tables (`---:` right-aligned), image lines
`![caption](file)` with an optional `*caption*` line after them, and inline `code`, **strong** and
*emphasis*.
"""
from __future__ import annotations

import base64
import html
import re
from pathlib import Path

from .markdown import markdown

IMAGE_LINE = re.compile(r"^!\[(?P<alt>[^\]]*)\]\((?P<file>[^)]+)\)$")
CAPTION_LINE = re.compile(r"^\*(?P<text>[^*].*[^*])\*$")
INLINE = ((re.compile(r"`([^`]+)`"), r"<code>\1</code>"), (re.compile(r"\*\*([^*]+)\*\*"), r"<strong>\1</strong>"),
          (re.compile(r"(?<![\w*])\*([^*\s][^*]*[^*\s]|[^*\s])\*(?![\w*])"), r"<em>\1</em>"))
MIME_TYPES = {".png": "image/png"}
STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, "DejaVu Sans", sans-serif; margin: 2em auto;
       max-width: 1100px; padding: 0 1em; color: #1a1a1a; line-height: 1.45; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.8em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.8em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; } th { background: #f2f2f2; }
td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; }
tbody tr:nth-child(even) { background: #fafafa; }
figure { margin: 1.2em 0; } figure img { max-width: 100%; height: auto; border: 1px solid #eee; }
figcaption { font-size: 0.9em; color: #444; margin-top: 0.3em; }
code { background: #f2f2f2; padding: 0 0.2em; }
"""


def page(report: dict, *, labels: dict[str, str], folder: str | Path) -> str:
    """report.html of a report (evaluate's JSON), its figures read from `folder` and embedded."""
    return render(markdown(report, labels=labels), folder=Path(folder))


def render(text: str, *, folder: Path) -> str:
    """One HTML page of `markdown`'s Markdown subset (module docstring); images from `folder`."""
    blocks = _blocks(text.splitlines())
    body, title = [], "HLOD evaluation"
    i = 0
    while i < len(blocks):
        block = blocks[i]
        image = IMAGE_LINE.match(block[0]) if len(block) == 1 else None
        if block[0].startswith("# "):
            title = block[0][2:].strip()
            body.append(f"<h1>{_inline(title)}</h1>")
        elif block[0].startswith("## "):
            body.append(f"<h2>{_inline(block[0][3:].strip())}</h2>")
        elif block[0].startswith("|"):
            body.append(_table(block))
        elif image:
            caption = None
            if i + 1 < len(blocks) and len(blocks[i + 1]) == 1 and CAPTION_LINE.match(blocks[i + 1][0]):
                caption = CAPTION_LINE.match(blocks[i + 1][0])["text"]
                i += 1
            body.append(_figure(folder, image["file"], alt=image["alt"], caption=caption))
        else:
            body.append(f"<p>{_inline(' '.join(block))}</p>")
        i += 1
    return ("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
            f"<title>{html.escape(title)}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n"
            + "\n".join(body) + "\n</body>\n</html>\n")


def _blocks(lines: list[str]) -> list[list[str]]:
    """Runs of non-blank lines; a heading is a block of its own."""
    blocks, current = [], []
    for line in lines:
        if not line.strip() or line.startswith("#"):
            if current:
                blocks.append(current)
            current = []
            if line.startswith("#"):
                blocks.append([line])
            continue
        current.append(line)
    if current:
        blocks.append(current)
    return blocks


def _inline(text: str) -> str:
    out = html.escape(text, quote=False)
    for pattern, replacement in INLINE:
        out = pattern.sub(replacement, out)
    return out


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def _table(block: list[str]) -> str:
    header, rows = _cells(block[0]), [_cells(line) for line in block[2:]]
    right = [c.endswith(":") for c in _cells(block[1])] if len(block) > 1 else []
    right += [False] * (len(header) - len(right))

    def cell(tag: str, text: str, j: int) -> str:
        numeric = ' class="num"' if j < len(right) and right[j] else ""
        return f"<{tag}{numeric}>{_inline(text)}</{tag}>"

    head = "".join(cell("th", c, j) for j, c in enumerate(header))
    body = "\n".join("<tr>" + "".join(cell("td", c, j) for j, c in enumerate(r)) + "</tr>" for r in rows)
    return f"<table>\n<thead><tr>{head}</tr></thead>\n<tbody>\n{body}\n</tbody>\n</table>"


def _figure(folder: Path, file: str, *, alt: str, caption: str | None) -> str:
    """A figure with its PNG inlined as a data URI (a note in its place when the file is missing)."""
    path = folder / file
    mime = MIME_TYPES.get(path.suffix.lower())
    if mime is None or not path.is_file():
        return f"<p><em>(figure {html.escape(file)} is missing from {html.escape(str(folder))})</em></p>"
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    shown = _inline(caption) if caption else html.escape(alt)
    return (f"<figure><img src=\"data:{mime};base64,{data}\" alt=\"{html.escape(alt)}\">"
            f"<figcaption>{shown}</figcaption></figure>")
