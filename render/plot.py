"""Log-log line and marker plots rasterised with numpy: axes, decade ticks, labels, a legend.

No matplotlib, no physics: series of (x, y) numbers in, an `(H, W, 3) uint8` image out (write it
with `render.write_png`). Text uses a built-in 5x7 bitmap font (digits, upper-case letters and a
little punctuation; lower case is drawn upper case).

    fig = loglog([Series(x=[0.1, 1, 10], y=[1e-2, 3e-3, 1e-3], label="cantilever")],
                 x_label="wall time [s]", y_label="error")
    write_png("accuracy.png", fig.image)
"""

import math
from dataclasses import dataclass, field

import numpy as np

_GLYPHS = {
    "0": "01110 10001 10011 10101 11001 10001 01110", "1": "00100 01100 00100 00100 00100 00100 01110",
    "2": "01110 10001 00001 00010 00100 01000 11111", "3": "11111 00010 00100 00010 00001 10001 01110",
    "4": "00010 00110 01010 10010 11111 00010 00010", "5": "11111 10000 11110 00001 00001 10001 01110",
    "6": "00110 01000 10000 11110 10001 10001 01110", "7": "11111 00001 00010 00100 01000 01000 01000",
    "8": "01110 10001 10001 01110 10001 10001 01110", "9": "01110 10001 10001 01111 00001 00010 01100",
    "A": "01110 10001 10001 11111 10001 10001 10001", "B": "11110 10001 10001 11110 10001 10001 11110",
    "C": "01110 10001 10000 10000 10000 10001 01110", "D": "11100 10010 10001 10001 10001 10010 11100",
    "E": "11111 10000 10000 11110 10000 10000 11111", "F": "11111 10000 10000 11110 10000 10000 10000",
    "G": "01110 10001 10000 10111 10001 10001 01111", "H": "10001 10001 10001 11111 10001 10001 10001",
    "I": "01110 00100 00100 00100 00100 00100 01110", "J": "00111 00010 00010 00010 00010 10010 01100",
    "K": "10001 10010 10100 11000 10100 10010 10001", "L": "10000 10000 10000 10000 10000 10000 11111",
    "M": "10001 11011 10101 10101 10001 10001 10001", "N": "10001 10001 11001 10101 10011 10001 10001",
    "O": "01110 10001 10001 10001 10001 10001 01110", "P": "11110 10001 10001 11110 10000 10000 10000",
    "Q": "01110 10001 10001 10001 10101 10010 01101", "R": "11110 10001 10001 11110 10100 10010 10001",
    "S": "01111 10000 10000 01110 00001 00001 11110", "T": "11111 00100 00100 00100 00100 00100 00100",
    "U": "10001 10001 10001 10001 10001 10001 01110", "V": "10001 10001 10001 10001 10001 01010 00100",
    "W": "10001 10001 10001 10101 10101 10101 01010", "X": "10001 10001 01010 00100 01010 10001 10001",
    "Y": "10001 10001 10001 01010 00100 00100 00100", "Z": "11111 00001 00010 00100 01000 10000 11111",
    " ": "00000 00000 00000 00000 00000 00000 00000", ".": "00000 00000 00000 00000 00000 01100 01100",
    "-": "00000 00000 00000 11111 00000 00000 00000", "+": "00000 00100 00100 11111 00100 00100 00000",
    "/": "00000 00001 00010 00100 01000 10000 00000", "(": "00010 00100 01000 01000 01000 00100 00010",
    ")": "01000 00100 00010 00010 00010 00100 01000", ":": "00000 01100 01100 00000 01100 01100 00000",
    "=": "00000 00000 11111 00000 11111 00000 00000", ",": "00000 00000 00000 00000 01100 00100 01000",
    "%": "11000 11001 00010 00100 01000 10011 00011", "_": "00000 00000 00000 00000 00000 00000 11111",
    "^": "00100 01010 10001 00000 00000 00000 00000", "?": "01110 10001 00001 00010 00100 00000 00100",
    "[": "01110 01000 01000 01000 01000 01000 01110", "]": "01110 00010 00010 00010 00010 00010 01110",
}
_FONT = {c: np.array([[b == "1" for b in row] for row in g.split()]) for c, g in _GLYPHS.items()}
GLYPH_W, GLYPH_H, ADVANCE = 5, 7, 6  # font pixels (before scaling)
MARKERS = ("o", "s", "^", "D", "x")
PALETTE = ((31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189), (255, 127, 14),
           (23, 190, 207), (140, 86, 75), (227, 119, 194), (188, 189, 34), (127, 127, 127))


@dataclass(frozen=True, kw_only=True)
class Series:
    """One data series. x, y: positive numbers [N] (others are skipped); label: legend text ("" for
    none); colour: RGB 0-255; marker: one of MARKERS or "" for none; line: join the points in the
    given order; dashed: dashed line."""

    x: tuple
    y: tuple
    label: str = ""
    colour: tuple = PALETTE[0]
    marker: str = "o"
    line: bool = True
    dashed: bool = False

    def __post_init__(self):
        if len(self.x) != len(self.y):
            raise ValueError(f"x and y must have the same length, got {len(self.x)} and {len(self.y)}")
        if self.marker not in MARKERS + ("",):
            raise ValueError(f"marker must be one of {MARKERS} or '', got {self.marker!r}")


@dataclass(frozen=True)
class Axes:
    """Pixel box of the plot area (columns left..right, rows top..bottom, inclusive) and its data
    ranges as log10 decades (x_lo, x_hi), (y_lo, y_hi)."""

    left: int
    top: int
    right: int
    bottom: int
    x_log: tuple
    y_log: tuple

    def to_pixel(self, x, y):
        """(column, row) float pixel coordinates of data points x, y (arrays, > 0)."""
        u = (np.log10(np.asarray(x, dtype=float)) - self.x_log[0]) / (self.x_log[1] - self.x_log[0])
        v = (np.log10(np.asarray(y, dtype=float)) - self.y_log[0]) / (self.y_log[1] - self.y_log[0])
        return self.left + u * (self.right - self.left), self.bottom - v * (self.bottom - self.top)


@dataclass
class Figure:
    """A drawn plot: the (H, W, 3) uint8 image and the axes' pixel geometry."""

    image: np.ndarray
    axes: Axes
    legend: list = field(default_factory=list)


def text_width(text: str, scale: int) -> int:
    """Width in pixels of `text` drawn at `scale`."""
    return max(0, len(text) * ADVANCE * scale - scale)


def draw_text(image, col: int, row: int, text: str, colour=(0, 0, 0), scale: int = 2) -> None:
    """Blit `text` with its top-left corner at (col, row); clipped at the image border."""
    h, w = image.shape[:2]
    for k, ch in enumerate(text.upper()):
        mask = np.kron(_FONT.get(ch, _FONT["?"]), np.ones((scale, scale), dtype=bool))
        r0, c0 = row, col + k * ADVANCE * scale
        rr, cc = np.nonzero(mask)
        rr, cc = rr + r0, cc + c0
        keep = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
        image[rr[keep], cc[keep]] = colour


def _disk(radius: float):
    r = int(math.ceil(radius))
    dr, dc = np.mgrid[-r:r + 1, -r:r + 1]
    inside = dr * dr + dc * dc <= radius * radius + 0.25
    return dr[inside], dc[inside]


def _paint(image, rows, cols, colour, box=None):
    """Set pixels (rows, cols) (integer arrays) to colour, clipped to the image or to box
    (left, top, right, bottom)."""
    h, w = image.shape[:2]
    left, top, right, bottom = box if box is not None else (0, 0, w - 1, h - 1)
    keep = (rows >= top) & (rows <= bottom) & (cols >= left) & (cols <= right)
    image[rows[keep], cols[keep]] = colour


def draw_polyline(image, cols, rows, colour, width: float = 3.0, dashed: bool = False, box=None):
    """A polyline through float pixel points (cols, rows) [N], `width` pixels thick, sampled every
    half pixel; dashed: 8 pixels on, 6 off along its length."""
    cols, rows = np.asarray(cols, dtype=float), np.asarray(rows, dtype=float)
    if len(cols) < 2:
        return
    seg = np.hypot(np.diff(cols), np.diff(rows))
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    s = np.linspace(0.0, arc[-1], max(2, int(2 * arc[-1]) + 2))
    pc, pr = np.interp(s, arc, cols), np.interp(s, arc, rows)
    if dashed:
        on = (s % 14.0) < 8.0
        pc, pr = pc[on], pr[on]
    dr, dc = _disk(max(0.0, (width - 1) / 2))
    r = (np.rint(pr)[:, None] + dr[None]).ravel().astype(int)
    c = (np.rint(pc)[:, None] + dc[None]).ravel().astype(int)
    _paint(image, r, c, colour, box)


def draw_marker(image, col: float, row: float, marker: str, colour, size: int = 5) -> None:
    """A marker of half-size `size` pixels centred on (col, row)."""
    dr, dc = np.mgrid[-size:size + 1, -size:size + 1]
    shapes = {"o": dr * dr + dc * dc <= size * size + 0.5, "s": np.ones_like(dr, dtype=bool),
              "D": np.abs(dr) + np.abs(dc) <= size,
              "^": (dr >= -size) & (np.abs(dc) <= (dr + size) / 2.0 + 0.5),
              "x": (np.abs(np.abs(dr) - np.abs(dc)) <= 1)}
    mask = shapes[marker]
    _paint(image, (dr[mask] + round(row)).astype(int), (dc[mask] + round(col)).astype(int), colour)


def decade_range(values) -> tuple:
    """(lo, hi) whole log10 decades covering the positive finite values (one decade if empty)."""
    v = np.asarray([x for x in values if np.isfinite(x) and x > 0], dtype=float)
    if len(v) == 0:
        return (0.0, 1.0)
    lo, hi = math.floor(np.log10(v.min())), math.ceil(np.log10(v.max()))
    return (float(lo), float(hi if hi > lo else lo + 1))


def _decade_label(d: int) -> str:
    return f"1E{d}" if d < -2 or d > 3 else f"{10.0 ** d:g}"


def layout(width: int, height: int, x_log: tuple, y_log: tuple, legend_width: int, scale: int = 2) -> Axes:
    """The plot area: margins for tick labels (left, bottom), the title (top) and the legend (right)."""
    label_w = max(text_width(_decade_label(d), scale) for d in range(int(y_log[0]), int(y_log[1]) + 1))
    left = label_w + 4 * scale + 10
    top = (GLYPH_H + 6) * scale * 2
    bottom = height - 1 - (GLYPH_H + 5) * scale * 2
    right = width - 1 - (legend_width + 20 if legend_width else 12)
    if right - left < 40 or bottom - top < 40:
        raise ValueError(f"a {width}x{height} image leaves no room for the plot area")
    return Axes(left, top, right, bottom, tuple(x_log), tuple(y_log))


def _draw_axes(image, ax: Axes, scale: int, x_label: str, y_label: str, title: str):
    grid, ink = (225, 225, 225), (0, 0, 0)
    for axis, (lo, hi) in (("x", ax.x_log), ("y", ax.y_log)):
        step = max(1, math.ceil((hi - lo) / 10))
        for d in range(int(lo), int(hi) + 1):
            for m in range(1, 10):
                value = math.log10(m) + d
                if value > hi + 1e-9:
                    break
                c, r = ax.to_pixel(10 ** value if axis == "x" else 10 ** ax.x_log[0],
                                   10 ** value if axis == "y" else 10 ** ax.y_log[0])
                tick = 3 * scale if m > 1 else 5 * scale
                if axis == "x":
                    c = int(round(float(c)))
                    if m == 1:
                        image[ax.top:ax.bottom, c] = grid
                    image[ax.bottom - tick:ax.bottom + 1, c] = ink
                    if m == 1 and (d - int(lo)) % step == 0:
                        lab = _decade_label(d)
                        draw_text(image, c - text_width(lab, scale) // 2, ax.bottom + 4 * scale, lab, ink, scale)
                else:
                    r = int(round(float(r)))
                    if m == 1:
                        image[r, ax.left:ax.right] = grid
                    image[r, ax.left:ax.left + tick + 1] = ink
                    if m == 1 and (d - int(lo)) % step == 0:
                        lab = _decade_label(d)
                        draw_text(image, ax.left - 4 * scale - text_width(lab, scale),
                                  r - GLYPH_H * scale // 2, lab, ink, scale)
    image[ax.top, ax.left:ax.right + 1] = image[ax.bottom, ax.left:ax.right + 1] = ink
    image[ax.top:ax.bottom + 1, ax.left] = image[ax.top:ax.bottom + 1, ax.right] = ink
    below = ax.bottom + (4 + GLYPH_H + 4) * scale
    draw_text(image, (ax.left + ax.right - text_width(x_label, scale)) // 2, below, x_label, ink, scale)
    draw_text(image, ax.left, ax.top - (GLYPH_H + 3) * scale, y_label, ink, scale)
    draw_text(image, (ax.left + ax.right - text_width(title, scale)) // 2, 3 * scale, title, ink, scale)


def _draw_legend(image, ax: Axes, entries, scale: int):
    """Entries (label, colour, marker, line, dashed) listed to the right of the plot area."""
    col, row = ax.right + 16, ax.top
    pitch = (GLYPH_H + 5) * scale
    for label, colour, marker, line, dashed in entries:
        mid = row + GLYPH_H * scale // 2
        if line:
            draw_polyline(image, [col, col + 24], [mid, mid], colour, dashed=dashed)
        if marker:
            draw_marker(image, col + 12, mid, marker, colour, size=4)
        draw_text(image, col + 32, row, label, (0, 0, 0), scale)
        row += pitch


def loglog(series, *, width: int = 960, height: int = 600, x_range=None, y_range=None, title: str = "",
           x_label: str = "", y_label: str = "", legend=None, text_scale: int = 2) -> Figure:
    """Draw `series` (Series) on log-log axes. x_range, y_range: (lo, hi) data limits (> 0),
    default the whole decades covering the data. legend: entries (label, colour, marker, line,
    dashed); default one per labelled series. Returns a Figure (image and axes geometry)."""
    series = list(series)
    xs = [v for s in series for v in s.x]
    ys = [v for s in series for v in s.y]
    x_log = decade_range(xs) if x_range is None else tuple(math.log10(v) for v in x_range)
    y_log = decade_range(ys) if y_range is None else tuple(math.log10(v) for v in y_range)
    if x_log[1] <= x_log[0] or y_log[1] <= y_log[0]:
        raise ValueError(f"ranges must be increasing, got x {x_range} and y {y_range}")
    if legend is None:
        legend = [(s.label, s.colour, s.marker, s.line, s.dashed) for s in series if s.label]
    legend_w = max([text_width(e[0], text_scale) + 32 for e in legend], default=0)
    image = np.full((height, width, 3), 255, dtype=np.uint8)
    ax = layout(width, height, x_log, y_log, legend_w, text_scale)
    _draw_axes(image, ax, text_scale, x_label, y_label, title)
    box = (ax.left + 1, ax.top + 1, ax.right - 1, ax.bottom - 1)
    for s in series:
        x, y = np.asarray(s.x, dtype=float), np.asarray(s.y, dtype=float)
        ok = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
        cols, rows = ax.to_pixel(x[ok], y[ok])
        if s.line:
            draw_polyline(image, cols, rows, s.colour, dashed=s.dashed, box=box)
        if s.marker:
            for c, r in zip(cols, rows):
                if box[0] <= c <= box[2] and box[1] <= r <= box[3]:
                    draw_marker(image, c, r, s.marker, s.colour)
    _draw_legend(image, ax, legend, text_scale)
    return Figure(image=image, axes=ax, legend=list(legend))
