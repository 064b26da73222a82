"""The live preview's images in the terminal: two pixels a cell (an upper half block, coloured as the upper pixel on
the lower's colour), shrunk (`preview.shrink`) to the widget's cells, the range of the colours in words under them.
A region of interest is marked: its edge in MARK, the pixels outside it dimmed (DIM); the colours span the region's."""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
from rich.color import Color as RichColor
from rich.style import Style as RichStyle
from rich.text import Text
from textual.widgets import Static

from .preview import IrView, shrink

RGB = tuple[int, int, int]
#: the region's edge: magenta, in neither the depth's colours nor the IR's greys
MARK: RGB = (255, 0, 255)
#: the pixels outside the region: their colour times this
DIM = 0.35
#: near to far: viridis's colours, bright for near (Matplotlib's `viridis` at 1, 0.75, 0.5, 0.25, 0)
DEPTH_COLOURS = ((253, 231, 37), (94, 201, 98), (33, 145, 140), (59, 82, 139), (68, 1, 84))


def depth_colour(t: float) -> RGB:
    """The colour at `t` in [0, 1] (0: near) of DEPTH_COLOURS, interpolated."""
    t = min(max(t, 0.0), 1.0) * (len(DEPTH_COLOURS) - 1)
    i = min(int(t), len(DEPTH_COLOURS) - 2)
    f = t - i
    r, g, b = (round(a + (b - a) * f) for a, b in zip(DEPTH_COLOURS[i], DEPTH_COLOURS[i + 1]))
    return r, g, b


def grey(t: float) -> RGB:
    """Black at `t` = 0 to white at 1."""
    level = round(255 * min(max(t, 0.0), 1.0))
    return level, level, level


def region_edge(inside: np.ndarray) -> np.ndarray:
    """The cells of `inside` (a boolean image) with a 4-neighbour outside it (or beyond the image)."""
    p = np.pad(inside, 1, constant_values=False)
    return inside & ~(p[:-2, 1:-1] & p[2:, 1:-1] & p[1:-1, :-2] & p[1:-1, 2:])


class CellImage(Static):
    """An image shrunk to this widget's cells, two pixels a cell; `plain` holds its legend."""

    plain = ""

    def blocks_for(self, shape: tuple[int, int], legend_lines: int = 1) -> tuple[int, int]:
        """(rows, columns) of pixels that fill this widget's cells (but the legend's lines) and keep the image's
        aspect."""
        height = (self.content_size.height or 9) - legend_lines
        rows, cols = 2 * max(1, height), max(1, self.content_size.width or 38)
        wide = round(rows * shape[1] / shape[0])
        return (rows, wide) if wide <= cols else (max(2, round(cols * shape[0] / shape[1])), cols)

    def draw(self, image: np.ndarray, inside: np.ndarray | None, empty: str,
             legend: Callable[[float, float], tuple[str, Callable[[float], RGB]]]) -> None:
        """Show `image` (NaN: black) with the region `inside` (each pixel's fraction in it; None: no region) marked.
        `legend(lo, hi)` gives the words under the image and each value's colour for the 2nd to 98th percentile of
        the region's values; `empty`: what to say when it has none."""
        have = image[np.isfinite(image) & (True if inside is None else inside > 0)]
        if have.size == 0:
            self.plain = empty
            self.update(empty)
            return
        lo, hi = (float(v) for v in np.percentile(have, [2, 98]))
        self.plain, colour = legend(lo, hi)
        blocks = self.blocks_for(image.shape, math.ceil(len(self.plain) / max(1, self.content_size.width or 38)))
        image = shrink(image, blocks)
        into = np.ones(image.shape, bool) if inside is None else shrink(inside, blocks) > 0
        edge = region_edge(into) if inside is not None else np.zeros(image.shape, bool)

        def cell(value: float, r: int, c: int) -> RichColor:
            rgb = colour(value) if math.isfinite(value) else (0, 0, 0)
            rgb = MARK if edge[r, c] else rgb if into[r, c] else tuple(round(DIM * v) for v in rgb)
            return RichColor.from_rgb(*rgb)

        text = Text()
        for r in range(0, image.shape[0], 2):
            for c in range(image.shape[1]):
                bottom = cell(image[r + 1, c], r + 1, c) if r + 1 < image.shape[0] else RichColor.from_rgb(0, 0, 0)
                text.append("▀", RichStyle(color=cell(image[r, c], r, c), bgcolor=bottom))
            text.append("\n")
        text.append(self.plain)
        self.update(text)


class DepthImage(CellImage):
    """A depth image: near bright, far dark, no depth black."""

    def show_image(self, image_m: np.ndarray, inside: np.ndarray | None = None) -> None:
        def legend(near: float, far: float) -> tuple[str, Callable[[float], RGB]]:
            span = max(far - near, 1e-6)
            return f"bright {near:.3f} to dark {far:.3f} m, black: none", lambda z: depth_colour((z - near) / span)

        self.draw(image_m, inside, "no pixel has a depth", legend)


class IrImage(CellImage):
    """An IR image in grey levels, dark to bright; "no IR image" when the camera gives none."""

    def show_ir(self, ir: IrView | None, inside: np.ndarray | None = None) -> None:
        if ir is None:
            self.plain = "no IR image"
            self.update(self.plain)
            return

        def legend(lo: float, hi: float) -> tuple[str, Callable[[float], RGB]]:
            span = max(hi - lo, 1e-6)
            return f"IR: black {lo:.0f} to white {hi:.0f} DN", lambda dn: grey((dn - lo) / span)

        self.draw(ir.image_dn, inside, "no IR image", legend)
