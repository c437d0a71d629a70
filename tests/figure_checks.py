"""Checks of written figures: the PNG signature, and whether a matplotlib figure's texts can be read
(none overlapping another, none cut by the figure's edge), by matplotlib's own text extents."""
from __future__ import annotations

import contextlib
import itertools

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@contextlib.contextmanager
def _recording_drawn_texts(drawn: list):
    """While active, every Text matplotlib draws is appended to `drawn` as (text, glyph extent in
    display pixels): what is on the picture, not what exists (tick labels outside the view are not
    drawn; an Annotation's own extent would include its arrow, Text's is the glyphs alone)."""
    from matplotlib.text import Text

    original = Text.draw

    def draw(self, renderer):
        original(self, renderer)
        if self.get_visible() and self.get_text().strip():
            drawn.append((self.get_text(), Text.get_window_extent(self, renderer)))

    Text.draw = draw
    try:
        yield
    finally:
        Text.draw = original


def drawn_texts(fig) -> list:
    """[(text, extent)] of every text drawn when `fig` is drawn."""
    drawn = []
    with _recording_drawn_texts(drawn):
        fig.canvas.draw()
    return drawn


def overlapping(texts) -> list:
    """Pairs of drawn texts whose extents overlap."""
    return [(a, b) for (a, box_a), (b, box_b) in itertools.combinations(texts, 2) if box_a.overlaps(box_b)]


def legible(fig) -> list:
    """What keeps `fig`'s texts from being read: pairs of overlapping texts, and texts cut by the
    figure's edge (as ("cut", text))."""
    texts = drawn_texts(fig)
    edge = fig.bbox
    cut = [("cut", t) for t, box in texts
           if box.x0 < edge.x0 or box.y0 < edge.y0 or box.x1 > edge.x1 or box.y1 > edge.y1]
    return overlapping(texts) + cut
