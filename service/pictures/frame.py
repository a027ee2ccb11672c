"""The frame of an image picture drawn with Pillow: the same layout, fonts and information as
the matplotlib figures of :mod:`fpscan.service.pictures.render` (axes in mm at equal aspect, ticks and
tick labels, axis labels, title, a colour bar with its ticks and label), at a fraction of their
cost (~10 ms against ~200 ms a picture: a matplotlib figure builds and lays out dozens of
artists for three small images), so that a result's pictures cost a fraction of its
reconstruction.

Used by :func:`fpscan.service.pictures.render.render_png` for every annotated raster picture (result
MIPs, depth slices, the live preview). Sizes follow the matplotlib figures: 600 px wide at
150 dpi (``FIGURE_WIDTH_IN``, ``FIGURE_DPI``), the same margins in inches, the colour bar's
fraction and pad of ``Figure.colorbar(fraction=0.046, pad=0.04)``, DejaVu Sans (matplotlib's
own font file) at ``FONT_PT`` / ``TICK_PT``, ticks from matplotlib's ``MaxNLocator`` with the
step set of its default locator and the tick count ``Axis.get_tick_space`` gives.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from PIL import Image, ImageDraw, ImageFont

__all__ = ["Frame", "frame_layout", "draw_frame", "colour_lut", "tick_values", "tick_labels", "power_in_label"]

_MINUS = "\u2212"


@dataclass(frozen=True)
class Frame:
    """Pixel layout of a picture: the canvas, the plotting area (the image) and the colour bar.

    All are integer pixel edges, row 0 at the top; the plotting area is
    ``[left, right) × [top, bottom)``, the colour bar ``[cb_left, cb_right) × [cb_top, cb_bottom)``.

    Attributes
    ----------
    width, height : int
        The canvas's size in pixels.
    left, right : int
        The plotting area's left (inclusive) and right (exclusive) column.
    top, bottom : int
        The plotting area's top (inclusive) and bottom (exclusive) row.
    cb_left, cb_right : int
        The colour bar's left (inclusive) and right (exclusive) column.
    cb_top, cb_bottom : int
        The colour bar's top (inclusive) and bottom (exclusive) row.
    """

    width: int
    height: int
    left: int
    right: int
    top: int
    bottom: int
    cb_left: int
    cb_right: int
    cb_top: int
    cb_bottom: int


def frame_layout(width_mm: float, height_mm: float, *, width_in: float, dpi: int, two_line_title: bool = False
                 ) -> Frame:
    """The layout of a picture of a ``width_mm`` × ``height_mm`` plotting area at equal aspect.

    It follows the figure size of ``render._figure`` and the margins of ``render._finish``
    (0.75 in left, 0.85 in right, 0.6 in bottom, 0.45 in top, 0.8 in with a two-line title);
    the image's cell takes 91.4 % of the area's width, anchored right, the colour bar 4.6 % at
    its right with a box aspect of 20 (matplotlib's ``make_axes_gridspec`` with
    ``fraction=0.046, pad=0.04``). The figure's height follows the aspect, clipped to
    1.6-6 in.

    Parameters
    ----------
    width_mm, height_mm : float
        The plotting area's extent in mm (only their ratio counts; signs are ignored).
    width_in : float
        The figure's width in inches.
    dpi : int
        Pixels per inch.
    two_line_title : bool, optional
        Leave room for a title of two lines; default False.

    Returns
    -------
    Frame
        The pixel layout.
    """
    aspect = abs(height_mm) / max(abs(width_mm), 1e-12)
    height_in = float(np.clip((width_in - 2.0) * aspect + 1.05, 1.6, 6.0))
    w_px, h_px = int(round(width_in * dpi)), int(round(height_in * dpi))
    area_l, area_r = 0.75 * dpi, w_px - 0.85 * dpi
    area_t, area_b = (0.8 if two_line_title else 0.45) * dpi, h_px - 0.6 * dpi
    area_w, area_h = area_r - area_l, area_b - area_t
    cell_r = area_l + 0.914 * area_w
    cb_cell_l = area_r - 0.046 * area_w
    img_w = min(cell_r - area_l, area_h / max(aspect, 1e-12))
    img_h = img_w * aspect
    right = int(round(cell_r))
    left = right - max(1, int(round(img_w)))
    top = int(round(area_t + (area_h - img_h) / 2))
    bottom = top + max(1, int(round(img_h)))
    cb_h = min(area_h, 20.0 * (area_r - cb_cell_l))
    cb_w = max(2.0, cb_h / 20.0)
    cb_top = int(round(area_t + (area_h - cb_h) / 2))
    cb_left = int(round(cb_cell_l))
    return Frame(w_px, h_px, left, right, top, bottom, cb_left, cb_left + int(round(cb_w)), cb_top,
                 cb_top + int(round(cb_h)))


def tick_values(lo: float, hi: float, length_px: float, *, font_pt: float, dpi: int, horizontal: bool
                ) -> np.ndarray:
    """Tick positions as matplotlib's default locator puts them on an axis.

    ``MaxNLocator`` with steps 1, 2, 2.5, 5, 10 and as many bins as ``Axis.get_tick_space``
    allows (length in points over 3 × the font size across, 2 × along a vertical axis; 1..9).

    Parameters
    ----------
    lo, hi : float
        The axis's ends, in data units (either order).
    length_px : float
        The axis's length in pixels.
    font_pt : float
        The tick labels' font size in points.
    dpi : int
        Pixels per inch.
    horizontal : bool
        True for a horizontal axis, False for a vertical one.

    Returns
    -------
    ndarray, shape (n_ticks,)
        Float64 tick positions inside ``[min(lo, hi), max(lo, hi)]``; ``[lo]`` alone when
        ``lo == hi``.
    """
    from matplotlib.ticker import MaxNLocator

    a, b = sorted((float(lo), float(hi)))
    if not b > a:
        return np.array([a])
    length_pt = length_px / dpi * 72.0
    bins = int(np.clip(math.floor(length_pt / (font_pt * (3.0 if horizontal else 2.0))), 1, 9))
    ticks = np.asarray(MaxNLocator(nbins=bins, steps=[1, 2, 2.5, 5, 10]).tick_values(a, b), dtype=np.float64)
    eps = 1e-9 * (b - a)
    return ticks[(ticks >= a - eps) & (ticks <= b + eps)]


def tick_labels(ticks: np.ndarray) -> tuple[list[str], str]:
    """Labels of evenly spaced ``ticks``, and their common power of ten.

    Parameters
    ----------
    ticks : ndarray, shape (n_ticks,)
        Evenly spaced tick positions.

    Returns
    -------
    labels : list of str
        One label per tick, with as few decimals as their step needs (after division by the
        common power); minus signs as U+2212.
    power : str
        The common power of ten drawn once beside the axis (``"1e−5"``); ``""`` when the
        largest magnitude lies between 1e-3 and 1e4, as matplotlib's ``ScalarFormatter``.
    """
    t = np.asarray(ticks, dtype=np.float64)
    big = float(np.max(np.abs(t))) if t.size else 0.0
    exponent = 0
    if big > 0 and not 1e-3 <= big < 1e4:
        exponent = int(math.floor(math.log10(big)))
        t = t / 10.0 ** exponent
    step = float(np.min(np.diff(t))) if t.size > 1 else (abs(float(t[0])) or 1.0)
    decimals = 0
    while decimals < 10 and abs(round(step, decimals) - step) > 1e-6 * step:
        decimals += 1
    labels = []
    for v in t:
        text = f"{0.0 if abs(v) < 1e-9 * max(step, 1e-300) else v:.{decimals}f}"
        labels.append(text.replace("-", _MINUS))
    return labels, (f"1e{exponent}".replace("-", _MINUS) if exponent else "")


_SUPERSCRIPT = str.maketrans("0123456789-\u2212", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻⁻")


def power_in_label(label: str, power: str) -> str:
    """A colour bar's ``label`` with the common power of ten of its tick labels inside its unit.

    ``"p0 (a.u.)"`` → ``"p0 (×10⁶ a.u.)"``; a label without a unit gets one
    (``"weight (×10⁶)"``). Drawn so, the power sits with the unit it scales rather than
    above the bar, where it met the title.

    Parameters
    ----------
    label : str
        The colour bar's label, its unit (if any) in parentheses at its end.
    power : str
        The common power of ten as :func:`tick_labels` gives it (``"1e6"``); ``""``: none.

    Returns
    -------
    str
        The label with the power; ``label`` as it is when ``power`` is ``""``.

    Examples
    --------
    >>> power_in_label("p0 (a.u.)", "1e6"), power_in_label("sO2", "1e\u22123")
    ('p0 (×10⁶ a.u.)', 'sO2 (×10⁻³)')
    """
    if not power:
        return label
    factor = "×10" + power.split("e", 1)[1].translate(_SUPERSCRIPT)
    if label.endswith(")") and "(" in label:
        head, _, unit = label[:-1].rpartition("(")
        return f"{head}({factor} {unit})"
    return f"{label} ({factor})"


def colour_lut(cmap: Any, n: int = 256) -> np.ndarray:
    """The colours of a matplotlib colormap over its range, as a lookup table.

    Parameters
    ----------
    cmap : matplotlib.colors.Colormap
        The colormap (any callable mapping values in [0, 1] to RGBA rows).
    n : int, optional
        The number of colours; default 256.

    Returns
    -------
    ndarray, shape (n, 3)
        uint8 RGB colours, from the colormap's low end (row 0) to its high end.
    """
    return (np.asarray(cmap(np.linspace(0.0, 1.0, n)))[:, :3] * 255.0 + 0.5).astype(np.uint8)


@functools.lru_cache(maxsize=8)
def _font(size_px: int) -> ImageFont.FreeTypeFont:
    """DejaVu Sans (the font file matplotlib ships and draws with) at ``size_px``."""
    import os

    import matplotlib
    from PIL import ImageFont

    return ImageFont.truetype(os.path.join(matplotlib.get_data_path(), "fonts", "ttf", "DejaVuSans.ttf"),
                              size_px)


def _text_width(draw: ImageDraw.ImageDraw, text: str, font: ImageFont.FreeTypeFont) -> float:
    return float(draw.textlength(text, font=font)) if text else 0.0


def _vertical_text(canvas: Image.Image, text: str, font: ImageFont.FreeTypeFont, centre: tuple[float, float], right_edge: float | None = None,
                   left_edge: float | None = None) -> None:
    """``text`` rotated 90° (read bottom to top), centred vertically on ``centre[1]``, with its
    right (or left) edge at ``right_edge`` (``left_edge``); horizontally centred on
    ``centre[0]`` without either."""
    from PIL import Image, ImageDraw

    box = ImageDraw.Draw(canvas).textbbox((0, 0), text, font=font, anchor="lt")
    w, h = int(math.ceil(box[2] - box[0])) + 2, int(math.ceil(box[3] - box[1])) + 2
    mask = Image.new("L", (w, h), 0)
    ImageDraw.Draw(mask).text((1 - box[0], 1 - box[1]), text, font=font, fill=255, anchor="lt")
    mask = mask.rotate(90, expand=True)
    x = (right_edge - mask.width if right_edge is not None
         else left_edge if left_edge is not None else centre[0] - mask.width / 2)
    canvas.paste((0, 0, 0), (int(round(x)), int(round(centre[1] - mask.height / 2))), mask)


def draw_frame(rgb: np.ndarray, colourbar: np.ndarray, frame: Frame, *, extent_mm: tuple[float, float, float, float],
               levels: tuple[float, float], hlabel: str, vlabel: str | None, title: str | None,
               colorbar_label: str, font_pt: float, tick_pt: float, dpi: int, grey: bool = False) -> bytes:
    """Draw the PNG of a picture: the image, its axes, ticks, labels, title and colour bar.

    Parameters
    ----------
    rgb : ndarray, shape (n_rows, n_cols, 3)
        uint8 image, row 0 drawn at the top, scaled (nearest sample) into the plotting area.
    colourbar : ndarray, shape (n, 3)
        uint8 colours of the colour bar, from ``levels[0]`` (bottom) to ``levels[1]`` (top).
    frame : Frame
        The pixel layout (:func:`frame_layout`).
    extent_mm : tuple of float
        ``(left, right, bottom, top)``: the positions in mm at the plotting area's edges.
    levels : tuple of float
        ``(low, high)``: the values at the colour bar's bottom and top.
    hlabel : str
        The horizontal axis's name (`` (mm)`` is appended).
    vlabel : str or None
        The vertical axis's name (`` (mm)`` is appended); None: no vertical ticks or label (a
        line picture).
    title : str or None
        The title above the plotting area (may have two lines); None: none.
    colorbar_label : str
        The colour bar's label (:func:`power_in_label` adds its ticks' power of ten).
    font_pt : float
        Font size of the axis labels and title in points.
    tick_pt : float
        Font size of the tick labels in points.
    dpi : int
        Pixels per inch.
    grey : bool, optional
        Every colour given is a grey (R = G = B): the PNG is stored as greyscale (mode
        ``L``); default False.

    Returns
    -------
    bytes
        The PNG file's bytes.
    """
    import io

    from PIL import Image, ImageDraw

    f = frame
    px = dpi / 72.0  # pixels a point
    canvas = Image.new("RGB", (f.width, f.height), (255, 255, 255))
    picture = Image.fromarray(np.ascontiguousarray(rgb, dtype=np.uint8), "RGB")
    canvas.paste(picture.resize((f.right - f.left, f.bottom - f.top), Image.Resampling.NEAREST), (f.left, f.top))
    bar = np.ascontiguousarray(colourbar[::-1][:, None, :].repeat(2, axis=1))  # the top of the bar: the highest
    canvas.paste(Image.fromarray(bar, "RGB").resize((f.cb_right - f.cb_left, f.cb_bottom - f.cb_top),
                                                    Image.Resampling.BILINEAR), (f.cb_left, f.cb_top))
    draw = ImageDraw.Draw(canvas)
    line = max(1, int(round(0.8 * px)))
    tick_len, pad = 3.5 * px, 3.5 * px
    tick_font, label_font = _font(int(round(tick_pt * px))), _font(int(round(font_pt * px)))
    for box in ((f.left, f.top, f.right, f.bottom), (f.cb_left, f.cb_top, f.cb_right, f.cb_bottom)):
        draw.rectangle((box[0] - line // 2 - 1, box[1] - line // 2 - 1, box[2] + (line - 1) // 2,
                        box[3] + (line - 1) // 2), outline=(0, 0, 0), width=line)

    h_left, h_right, v_bottom, v_top = extent_mm
    # horizontal axis: ticks below the plotting area
    ticks = tick_values(h_left, h_right, f.right - f.left, font_pt=tick_pt, dpi=dpi, horizontal=True)
    labels, power = tick_labels(ticks)
    label_bottom = f.bottom + tick_len + pad
    for t, text in zip(ticks, labels):
        x = f.left + (t - h_left) / (h_right - h_left) * (f.right - f.left)
        draw.line((x, f.bottom, x, f.bottom + tick_len), fill=(0, 0, 0), width=line)
        b = draw.textbbox((x, f.bottom + tick_len + pad), text, font=tick_font, anchor="ma")
        draw.text((x, f.bottom + tick_len + pad), text, font=tick_font, fill=(0, 0, 0), anchor="ma")
        label_bottom = max(label_bottom, b[3])
    if power:
        draw.text((f.right, label_bottom), power, font=tick_font, fill=(0, 0, 0), anchor="ra")
    draw.text(((f.left + f.right) / 2, label_bottom + 4 * px), f"{hlabel} (mm)", font=label_font,
              fill=(0, 0, 0), anchor="ma")

    # vertical axis: ticks left of the plotting area (none for a line picture)
    if vlabel:
        ticks = tick_values(v_bottom, v_top, f.bottom - f.top, font_pt=tick_pt, dpi=dpi, horizontal=False)
        labels, power = tick_labels(ticks)
        label_left = f.left - tick_len - pad
        for t, text in zip(ticks, labels):
            y = f.top + (t - v_top) / (v_bottom - v_top) * (f.bottom - f.top)
            draw.line((f.left - tick_len, y, f.left, y), fill=(0, 0, 0), width=line)
            draw.text((f.left - tick_len - pad, y), text, font=tick_font, fill=(0, 0, 0), anchor="rm")
            label_left = min(label_left, f.left - tick_len - pad - _text_width(draw, text, tick_font))
        if power:
            draw.text((f.left, f.top - 2 * px), power, font=tick_font, fill=(0, 0, 0), anchor="ld")
        _vertical_text(canvas, f"{vlabel} (mm)", label_font, (0.0, (f.top + f.bottom) / 2),
                       right_edge=label_left - 4 * px)

    # colour bar: ticks and labels at its right, its label beyond them
    lo, hi = levels
    ticks = tick_values(lo, hi, f.cb_bottom - f.cb_top, font_pt=tick_pt, dpi=dpi, horizontal=False)
    labels, power = tick_labels(ticks)
    label_right = f.cb_right + tick_len + pad
    for t, text in zip(ticks, labels):
        y = f.cb_bottom - (t - lo) / (hi - lo) * (f.cb_bottom - f.cb_top)
        draw.line((f.cb_right, y, f.cb_right + tick_len, y), fill=(0, 0, 0), width=line)
        draw.text((f.cb_right + tick_len + pad, y), text, font=tick_font, fill=(0, 0, 0), anchor="lm")
        label_right = max(label_right, f.cb_right + tick_len + pad + _text_width(draw, text, tick_font))
    # the common power goes into the label's unit ("p0 (×10⁶ a.u.)"), not above the bar by the title
    _vertical_text(canvas, power_in_label(colorbar_label, power), label_font, (0.0, (f.cb_top + f.cb_bottom) / 2),
                   left_edge=label_right + 4 * px)

    if title:
        draw.multiline_text(((f.left + f.right) / 2, f.top - 6 * px), title, font=label_font, fill=(0, 0, 0),
                            anchor="md", align="center")
    if grey:  # every colour on it is a grey: one byte a pixel (a quarter of the time to encode)
        canvas = canvas.convert("L")
    buf = io.BytesIO()
    canvas.save(buf, format="PNG", compress_level=1)
    return buf.getvalue()
