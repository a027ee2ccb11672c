"""The ONE rendering path for every picture fpscan draws: result MIPs, the live preview
of a running scan, depth slices and the mask preview of a plan. Axes in mm with equal
aspect (a millimetre is as long across as down), a colour bar in p0 units (or the mask's
weight): image pictures drawn with Pillow in the frame of :mod:`fpscan.service.pictures.frame` (the
layout, fonts and ticks of the matplotlib figures, ~20 ms a picture), the mask's points, its
lattice and the sO2 map with matplotlib on an Agg canvas (no pyplot state: thread-safe); or raw
pixels (one pixel per sample, Pillow) in the same orientation.

Orientation, the same in every picture and every file (docs/file-formats.md,
"Orientation"): **row 0 of the array at the top, column 0 at the left** -- the way napari,
ImageJ/Fiji and matplotlib's ``imshow`` show an array, so a PNG, the web page, the OME-TIFF
and OME-Zarr exports and the HDF5 volume read with h5py show the same picture. x points to
the right; in lateral pictures (xy MIP, depth slice, mask preview) y points **down** (the
smallest y at the top); in depth pictures (xz, yz) depth z points **down** from the sensor
plane at the top. Raw-pixel PNGs follow the same rule (a PNG row is an array row).

Annotated PNGs carry their geometry as a PNG text chunk ``fpscan:axes`` (JSON:
``left``, ``top``, ``right``, ``bottom`` pixel edges of the plotting area and
``extent_mm`` ``[left, right, bottom, top]``: the mm at those edges as the axes are
drawn), so a client can map a pixel to mm.

Images follow docs/file-formats.md ("Orientation"): ``p0`` is ``(n_z, n_y, n_x)`` (3-D) or
``(n_z, n_x)`` (2-D), row 0 at the sensor plane z = 0, with coordinate vectors ``z``, ``y``,
``x`` in m.

MIP planes (max over the named axis):

=======  ===========  ==================  =====================================
plane    max over     array shape         drawn as
=======  ===========  ==================  =====================================
``xy``   z (axis 0)   (n_y, n_x)          x to the right, y downwards
``xz``   y (axis 1)   (n_z, n_x)          x to the right, depth z downwards
``yz``   x (axis 2)   (n_z, n_y)          y to the right, depth z downwards
=======  ===========  ==================  =====================================

A 2-D image ``(n_z, n_x)`` has only the ``xz`` plane (the image itself).

Grey levels: ``vmin`` → black, ``vmax`` → white, linear, clipped; defaults ``vmin = 0``
(negative p0 is not physical and shows black) and ``vmax`` = the maximum of the
projection; an image whose maximum is not above ``vmin`` renders black.
"""
from __future__ import annotations

import io
import json
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.cm import ScalarMappable
    from matplotlib.colorbar import Colorbar
    from matplotlib.colors import Colormap
    from matplotlib.figure import Figure

from fpscan.service.metrics.projections import mip

PLANES = ("xy", "xz", "yz")
AXES_KEY = "fpscan:axes"

__all__ = ["PLANES", "AXES_KEY", "mip", "to_uint8", "render_png", "render_mip", "render_mips",
           "render_result_slice", "render_lateral", "render_points", "render_lattice",
           "png_axes", "render_so2", "so2_rgb"]


def _levels(img: np.ndarray, vmin: float | None, vmax: float | None) -> tuple[float, float]:
    finite = img[np.isfinite(img)]
    lo = 0.0 if vmin is None else float(vmin)
    hi = (float(finite.max()) if finite.size else lo) if vmax is None else float(vmax)
    return lo, hi


def to_uint8(img: np.ndarray, vmin: float | None = None, vmax: float | None = None) -> np.ndarray:
    """Grey levels 0..255 of a 2-D array (module docstring); NaN → 0.

    Parameters
    ----------
    img : ndarray, shape (n_rows, n_cols)
        The image (any real dtype).
    vmin : float or None, optional
        The value shown black; default None: 0.
    vmax : float or None, optional
        The value shown white; default None: the image's largest finite value.

    Returns
    -------
    ndarray, shape (n_rows, n_cols)
        uint8 grey levels, linear between ``vmin`` and ``vmax``, clipped; all 0 when
        ``vmax`` is not above ``vmin``.
    """
    img = np.asarray(img, dtype=np.float64)
    lo, hi = _levels(img, vmin, vmax)
    if not hi > lo:
        return np.zeros(img.shape, np.uint8)
    scaled = np.clip((np.nan_to_num(img, nan=lo) - lo) / (hi - lo), 0.0, 1.0)
    return np.floor(scaled * 255.0 + 0.5).astype(np.uint8)


def _edges(v: np.ndarray) -> tuple[float, float]:
    v = np.asarray(v, dtype=np.float64)
    half = (v[1] - v[0]) / 2 if len(v) > 1 else 0.5e-4
    return float(v[0] - half), float(v[-1] + half)


def render_png(img: np.ndarray, h: np.ndarray, v: np.ndarray, *, hlabel: str, vlabel: str,
               depth_down: bool = True, title: str | None = None, cmap: str = "gray",
               vmin: float | None = None, vmax: float | None = None, annotate: bool = True,
               colorbar_label: str = "p0 (a.u.)", bad_colour: Any = None) -> bytes:
    """PNG of a 2-D array ``img``: row i at vertical coordinate ``v[i]``, column j at ``h[j]``.

    ``annotate=True``: a figure (:mod:`fpscan.service.pictures.frame`; a greyscale PNG when every
    colour is grey) with axes in mm (equal aspect), labels, title, a colour bar labelled
    ``colorbar_label`` and the ``fpscan:axes`` chunk. ``annotate=False``: exactly one pixel
    per sample in the same orientation (the first PNG row is ``v[0]`` when ``depth_down``,
    else ``v[-1]``), grey levels of :func:`to_uint8` (``cmap`` applied if not ``"gray"``).

    Parameters
    ----------
    img : ndarray, shape (len(v), len(h))
        The image.
    h : ndarray, shape (n_h,)
        Horizontal coordinate of each column in m.
    v : ndarray, shape (n_v,)
        Vertical coordinate of each row in m.
    hlabel, vlabel : str
        The axes' names (`` (mm)`` is appended), annotated pictures only.
    depth_down : bool, optional
        Put ``v[0]`` at the top, as napari and ``imshow`` show row 0 (the default, and what
        every fpscan picture uses: module docstring); False puts it at the bottom (a y-up plot,
        for a caller that wants one).
    title : str or None, optional
        The title; default None: none.
    cmap : str, optional
        A matplotlib colormap name; default ``"gray"``.
    vmin, vmax : float or None, optional
        The values at the colour scale's ends; default None: 0 and the image's maximum.
    annotate : bool, optional
        Draw a figure with axes (default True) or raw pixels (False).
    colorbar_label : str, optional
        The colour bar's label; default ``"p0 (a.u.)"``.
    bad_colour : matplotlib colour or None, optional
        Annotated figures only: NaN pixels (e.g. masked) drawn in it instead of at ``vmin``;
        default None.

    Returns
    -------
    bytes
        The PNG file's bytes.

    Raises
    ------
    ValueError
        If ``img`` is not 2-D of shape ``(len(v), len(h))``, or ``cmap`` is unknown.
    """
    img = np.asarray(img)
    if img.ndim != 2 or img.shape != (len(v), len(h)):
        raise ValueError(f"image shape {img.shape} does not match axes ({len(v)}, {len(h)})")
    colormap = _colormap(cmap)
    if not annotate:
        from PIL import Image as PILImage
        grey = to_uint8(img, vmin, vmax)
        if not depth_down:  # v[0] at the bottom: the largest v in the first row
            grey = np.ascontiguousarray(grey[::-1])
        if cmap == "gray":
            pil = PILImage.fromarray(grey, mode="L")
        else:
            pil = PILImage.fromarray((colormap(grey)[..., :3] * 255 + 0.5).astype(np.uint8), "RGB")
        buf = io.BytesIO()
        pil.save(buf, format="PNG")
        return buf.getvalue()

    lo, hi = _levels(np.asarray(img, dtype=np.float64), vmin, vmax)
    if not hi > lo:
        hi = lo + 1.0
    h0, h1 = (e * 1e3 for e in _edges(h))
    v0, v1 = (e * 1e3 for e in _edges(v))
    if _FAST_FRAME:
        return _render_framed(img, colormap, lo, hi, (h0, h1, v0, v1), depth_down=depth_down, hlabel=hlabel,
                              vlabel=vlabel, title=title, colorbar_label=colorbar_label, bad_colour=bad_colour)
    fig, ax = _figure(h1 - h0, v1 - v0)
    extent = (h0, h1, v1, v0) if depth_down else (h0, h1, v0, v1)
    shown = np.asarray(img, dtype=np.float64)
    if bad_colour is not None:
        colormap = colormap.with_extremes(bad=bad_colour)
        shown = np.ma.masked_invalid(shown)
    else:
        shown = np.nan_to_num(shown, nan=lo)
    im = ax.imshow(shown, cmap=colormap,
                   vmin=lo, vmax=hi, extent=extent, origin="upper" if depth_down else "lower",
                   interpolation="nearest", aspect="equal")
    return _finish(fig, ax, im, hlabel=hlabel, vlabel=vlabel, title=title,
                   colorbar_label=colorbar_label)


#: draw annotated raster pictures with :mod:`fpscan.service.pictures.frame` (Pillow, ~10 ms a picture)
#: rather than a matplotlib figure (~200 ms); the same layout, fonts, ticks, colour bar and
#: ``fpscan:axes`` chunk
_FAST_FRAME = True


def _render_framed(img: np.ndarray, colormap: Any, lo: float, hi: float, edges_mm: tuple[float, float, float, float],
                   *, depth_down: bool, hlabel: str, vlabel: str, title: str | None, colorbar_label: str,
                   bad_colour: Any) -> bytes:
    """:func:`render_png`'s annotated picture drawn by :func:`fpscan.service.pictures.frame.draw_frame`:
    the colours matplotlib's ``imshow`` gives (``colormap``'s 256 colours over ``[lo, hi]``,
    clipped; NaN at ``lo`` or in ``bad_colour``), ``edges_mm`` ``(h0, h1, v0, v1)``: the mm at
    the first and last sample's outer edges; with the ``fpscan:axes`` chunk."""
    from fpscan.service.pictures.frame import colour_lut, draw_frame, frame_layout

    shown = np.asarray(img, dtype=np.float64)
    bad = ~np.isfinite(shown)
    index = np.clip(np.floor((np.nan_to_num(shown, nan=lo, posinf=hi, neginf=lo) - lo) / (hi - lo) * 256.0),
                    0, 255).astype(np.intp)
    lut = colour_lut(colormap)
    rgb = lut[index]
    if bad_colour is not None and bad.any():
        from matplotlib.colors import to_rgb

        rgb[bad] = (np.asarray(to_rgb(bad_colour)) * 255.0 + 0.5).astype(np.uint8)
    h0, h1, v0, v1 = edges_mm
    if not depth_down:  # v[0] at the bottom: the last row drawn first
        rgb = rgb[::-1]
    extent = (h0, h1, v1, v0) if depth_down else (h0, h1, v0, v1)  # left, right, bottom, top
    frame = frame_layout(h1 - h0, v1 - v0, width_in=FIGURE_WIDTH_IN, dpi=FIGURE_DPI,
                         two_line_title=bool(title and "\n" in title))
    png = draw_frame(rgb, lut, frame, extent_mm=extent, levels=(lo, hi), hlabel=hlabel, vlabel=vlabel,
                     title=title, colorbar_label=colorbar_label, font_pt=FONT_PT, tick_pt=TICK_PT,
                     dpi=FIGURE_DPI, grey=bool((rgb[..., 0] == rgb[..., 1]).all() and (rgb[..., 1] == rgb[..., 2]).all()
                                               and (lut[:, 0] == lut[:, 1]).all() and (lut[:, 1] == lut[:, 2]).all()))
    geometry = {"left": float(frame.left), "right": float(frame.right), "top": float(frame.top),
                "bottom": float(frame.bottom), "extent_mm": [float(e) for e in extent]}
    return _with_text_chunk(png, AXES_KEY, json.dumps(geometry))


def so2_rgb(so2: np.ndarray, thb: np.ndarray, *, threshold: float = 0.1, cmap: str = "RdYlBu_r",
            gamma: float = 0.5) -> np.ndarray:
    """The colours of an sO2 picture as the PATATO / iThera maps draw them.

    Colour (hue) from sO2 through ``cmap`` over 0 (blue) .. 1 (red); brightness from THb:
    ``(thb / max(thb)) ** gamma`` (``gamma`` < 1 lifts weak vessels); black where sO2 is
    unknown (NaN) or THb is below ``threshold`` · max(THb) -- the background, which would
    otherwise show noise at full saturation. An image with no THb above 0 is all black.

    Parameters
    ----------
    so2 : ndarray, shape S
        Oxygen saturation as a fraction 0..1, NaN where unknown.
    thb : ndarray, shape S
        Total haemoglobin (any unit, >= 0).
    threshold : float, optional
        THb below this fraction of its maximum is shown black; in [0, 1), default 0.1.
    cmap : str, optional
        A matplotlib colormap name; default ``"RdYlBu_r"``.
    gamma : float, optional
        Exponent of the brightness, > 0; default 0.5.

    Returns
    -------
    ndarray, shape ``(*S, 3)``
        Float RGB colours in [0, 1].

    Raises
    ------
    ValueError
        If the shapes differ, ``threshold`` lies outside [0, 1), ``gamma`` is not > 0, or
        ``cmap`` is unknown.
    """
    so2 = np.asarray(so2, dtype=np.float64)
    thb = np.asarray(thb, dtype=np.float64)
    if so2.shape != thb.shape:
        raise ValueError(f"sO2 {so2.shape} and THb {thb.shape} must have one shape")
    if not 0.0 <= float(threshold) < 1.0:
        raise ValueError(f"threshold must lie in [0, 1), got {threshold}")
    if not float(gamma) > 0:
        raise ValueError(f"gamma must be > 0, got {gamma}")
    finite = np.isfinite(thb)
    top = float(thb[finite].max()) if finite.any() else 0.0
    if not top > 0:
        return np.zeros((*so2.shape, 3))
    level = np.clip(np.where(finite, thb, 0.0) / top, 0.0, 1.0)
    shown = np.isfinite(so2) & (level >= float(threshold)) & (level > 0)
    rgb = _colormap(cmap)(np.clip(np.nan_to_num(so2, nan=0.0), 0.0, 1.0))[..., :3]
    return np.where(shown[..., None], rgb * (level ** float(gamma))[..., None], 0.0)


def render_so2(so2: np.ndarray, thb: np.ndarray, h: np.ndarray, v: np.ndarray, *, hlabel: str,
               vlabel: str, title: str | None = None, threshold: float = 0.1,
               cmap: str = "RdYlBu_r") -> bytes:
    """PNG of an sO2 map, with brightness from total haemoglobin and the background black.

    The colours are :func:`so2_rgb`'s, in the frame of every picture (module docstring: axes
    in mm, equal aspect, row 0 = ``v[0]`` at the top, ``fpscan:axes`` chunk); the colour bar
    is sO2 in % (0..100).

    Parameters
    ----------
    so2 : ndarray, shape (len(v), len(h))
        Oxygen saturation as a fraction 0..1, NaN where unknown.
    thb : ndarray, shape (len(v), len(h))
        Total haemoglobin (any unit, >= 0).
    h : ndarray, shape (n_h,)
        Horizontal coordinate of each column in m.
    v : ndarray, shape (n_v,)
        Vertical coordinate of each row in m.
    hlabel, vlabel : str
        The axes' names (`` (mm)`` is appended).
    title : str or None, optional
        The title; default None: none.
    threshold : float, optional
        THb below this fraction of its maximum is shown black; default 0.1.
    cmap : str, optional
        A matplotlib colormap name; default ``"RdYlBu_r"``.

    Returns
    -------
    bytes
        The PNG file's bytes.

    Raises
    ------
    ValueError
        As :func:`so2_rgb`, and if ``so2`` is not 2-D of shape ``(len(v), len(h))``.
    """
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    so2 = np.asarray(so2)
    if so2.ndim != 2 or so2.shape != (len(v), len(h)):
        raise ValueError(f"sO2 shape {so2.shape} does not match axes ({len(v)}, {len(h)})")
    rgb = so2_rgb(so2, thb, threshold=threshold, cmap=cmap)
    h0, h1 = (e * 1e3 for e in _edges(h))
    v0, v1 = (e * 1e3 for e in _edges(v))
    fig, ax = _figure(h1 - h0, v1 - v0)
    ax.set_facecolor("black")
    ax.imshow(rgb, extent=(h0, h1, v1, v0), origin="upper", interpolation="nearest", aspect="equal")
    bar = ScalarMappable(norm=Normalize(0.0, 100.0), cmap=_colormap(cmap))
    return _finish(fig, ax, bar, hlabel=hlabel, vlabel=vlabel, title=title,
                   colorbar_label=f"sO2 (%) · brightness: THb · black: THb < {threshold:.0%} of max")


#: figure width, inches, and resolution: 600 px wide, sized for display (a thumbnail of about
#: 300 px, full size when enlarged), with text of FONT_PT (tick labels TICK_PT) that stays
#: readable at half size (about 12 px at 300 px)
FIGURE_WIDTH_IN, FIGURE_DPI = 4.0, 150
FONT_PT, TICK_PT = 12.0, 11.0


def _figure(width_mm: float, height_mm: float, *, dpi: int = FIGURE_DPI) -> tuple[Figure, Axes]:
    """A figure sized for a plot ``width_mm`` × ``height_mm`` at equal aspect."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    aspect = abs(height_mm) / max(abs(width_mm), 1e-12)
    width = FIGURE_WIDTH_IN
    height = float(np.clip((width - 2.0) * aspect + 1.05, 1.6, 6.0))
    fig = Figure(figsize=(width, height), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig, fig.add_subplot(1, 1, 1)


#: larger units a colour bar's label switches to when its values reach 10⁴ of the smaller:
#: weights in mm² (mm) rather than 10⁶ µm²
_LARGER_UNIT = {"µm²": ("mm²", 1e6), "µm": ("mm", 1e3)}


def _colourbar_scale(label: str, lo: float, hi: float) -> tuple[float, str]:
    """The divisor of a colour bar's tick values and its label: ``µm²`` / ``µm`` become ``mm²``
    / ``mm`` for values of 10⁴ and more (no factor on a weight), and any power of ten still
    left (values outside [1e-3, 1e4), as ``fpscan.service.pictures.frame.tick_labels``) goes into the
    label's unit (``"p0 (×10⁶ a.u.)"``), never beside the bar where it met the title."""
    import math

    from fpscan.service.pictures.frame import power_in_label

    big = max(abs(lo), abs(hi))
    divisor = 1.0
    if label.endswith(")") and "(" in label:
        head, _, unit = label[:-1].rpartition("(")
        if unit in _LARGER_UNIT and big >= 1e4:
            unit, divisor = _LARGER_UNIT[unit]
            label = f"{head}({unit})"
    scaled = big / divisor
    if scaled > 0 and not 1e-3 <= scaled < 1e4:
        exponent = int(math.floor(math.log10(scaled)))
        divisor *= 10.0 ** exponent
        label = power_in_label(label, f"1e{exponent}")
    return divisor, label


def _fit_title(fig: Figure, ax: Axes, title: str) -> int:
    """Set ``title`` on ``ax`` at FONT_PT (centred over the plot, as every picture's), each
    line wrapped at spaces so that it stays inside the figure (the mask preview's
    "equisteradian: 1653 of 1625 requested points on 226×226" was cut at both sides); returns
    the number of lines drawn. Call once the axes have their final horizontal place."""
    import textwrap

    box = ax.get_position()
    centre = (box.x0 + box.x1) / 2  # figure fraction
    room_px = 2 * min(centre, 1 - centre) * fig.get_size_inches()[0] * fig.dpi * 0.97
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]  # Agg canvas (_figure)
    text = ax.set_title(title, fontsize=FONT_PT)
    for chars in range(max(len(line) for line in title.split("\n")), 8, -1):
        if text.get_window_extent(renderer).width <= room_px:
            break
        text.set_text("\n".join(textwrap.fill(line, chars, break_long_words=False) for line in title.split("\n")))
    return text.get_text().count("\n") + 1


def _finish(fig: Figure, ax: Axes, mappable: ScalarMappable, *, hlabel: str, vlabel: str | None, title: str | None,
            colorbar_label: str) -> bytes:
    """Labels, title (wrapped to fit: :func:`_fit_title`) and colour bar (its units chosen so
    no factor sits beside it: :func:`_colourbar_scale`) of every picture; the PNG with its
    ``fpscan:axes`` geometry chunk (module docstring)."""
    from matplotlib.ticker import FuncFormatter

    ax.set_xlabel(f"{hlabel} (mm)")
    if vlabel:
        ax.set_ylabel(f"{vlabel} (mm)")
    cb = fig.colorbar(mappable, ax=ax, fraction=0.046, pad=0.04)
    lo, hi = mappable.get_clim()
    divisor, colorbar_label = _colourbar_scale(colorbar_label, float(lo), float(hi))
    if divisor != 1.0:
        cb.formatter = FuncFormatter(lambda v, _pos: f"{v / divisor:g}".replace("-", "\u2212"))
        cb.update_ticks()
    cb.set_label(colorbar_label)
    _readable_text(ax, cb)
    # fixed margins in inches (a layout engine costs a second full draw): the sides first, then
    # the title fitted between them, then the top by its lines
    w_in, h_in = fig.get_size_inches()
    fig.subplots_adjust(left=0.75 / w_in, right=1 - 0.85 / w_in, bottom=0.6 / h_in, top=1 - 0.45 / h_in)
    lines = _fit_title(fig, ax, title) if title else 0
    top_in = 0.25 + 0.22 * lines if lines else 0.45
    if h_in - top_in - 0.6 < 1.2:  # room for the plot under a long title
        h_in = top_in + 0.6 + 1.2
        fig.set_size_inches(w_in, h_in)
    fig.subplots_adjust(bottom=0.6 / h_in, top=1 - top_in / h_in)
    buf = io.BytesIO()
    fig.savefig(buf, format="png")  # draws the figure: the axes' pixel box is final now
    height_px = fig.bbox.height
    box = ax.get_window_extent()
    (x0, x1), (y_bottom, y_top) = ax.get_xlim(), ax.get_ylim()
    geometry = {"left": float(box.x0), "right": float(box.x1),
                "top": float(height_px - box.y1), "bottom": float(height_px - box.y0),
                # mm at the plotting area's edges, as the axes are drawn
                "extent_mm": [float(x0), float(x1), float(y_bottom), float(y_top)]}
    return _with_text_chunk(buf.getvalue(), AXES_KEY, json.dumps(geometry))


def _readable_text(ax: Axes, cb: Colorbar) -> None:
    """Text sizes of a picture shown at about half its pixel width (FONT_PT, TICK_PT)."""
    ax.xaxis.label.set_fontsize(FONT_PT)
    ax.yaxis.label.set_fontsize(FONT_PT)
    ax.title.set_fontsize(FONT_PT)
    ax.tick_params(labelsize=TICK_PT)
    cb.ax.tick_params(labelsize=TICK_PT)
    cb.ax.yaxis.label.set_fontsize(FONT_PT)


def _with_text_chunk(png: bytes, key: str, text: str) -> bytes:
    """``png`` with a ``tEXt`` chunk ``key``/``text`` inserted before ``IEND`` (PNG spec
    §11.3.4.3; Latin-1 text)."""
    import struct
    import zlib

    body = key.encode("latin-1") + b"\0" + text.encode("latin-1")
    chunk = struct.pack(">I", len(body)) + b"tEXt" + body + struct.pack(">I", zlib.crc32(b"tEXt" + body))
    end = png.rindex(b"IEND") - 4  # the IEND chunk starts with its 4-byte length
    return png[:end] + chunk + png[end:]


def png_axes(png: bytes) -> dict:
    """The ``fpscan:axes`` geometry of an annotated PNG (module docstring).

    Parameters
    ----------
    png : bytes
        The PNG file's bytes.

    Returns
    -------
    dict
        ``left``, ``top``, ``right``, ``bottom``: the plotting area's pixel edges; ``extent_mm``
        ``[left, right, bottom, top]``: the mm at those edges.

    Raises
    ------
    ValueError
        When the PNG has no such chunk (not an annotated fpscan picture).
    """
    from PIL import Image as PILImage

    with PILImage.open(io.BytesIO(png)) as im:
        text = getattr(im, "text", {}) or im.info
        raw = text.get(AXES_KEY)
    if raw is None:
        raise ValueError("the PNG carries no fpscan:axes geometry (not an annotated fpscan picture)")
    return json.loads(raw)


def render_points(positions: np.ndarray, values: np.ndarray, bounds: tuple, *,
                  title: str | None = None, colorbar_label: str = "weight",
                  marker_size: float | None = None, poi: tuple | None = None,
                  cmap: str = "viridis") -> bytes:
    """PNG of scattered lateral points coloured by their values, inside the lattice outline.

    Same frame as every other picture: axes in mm, equal aspect, y down (the smallest y at
    the top, as every picture), colour bar, ``fpscan:axes`` chunk.

    Parameters
    ----------
    positions : ndarray, shape (n, 2) or (n, 1)
        Lateral positions (x, y) in m, or x alone for a line.
    values : ndarray, shape (n,)
        The value of each point (its colour).
    bounds : tuple
        The lattice outline in m: ``((x_lo, x_hi), (y_lo, y_hi))``, or ``((x_lo, x_hi),)`` for
        a line.
    title : str or None, optional
        The title; default None: none.
    colorbar_label : str, optional
        The colour bar's label; default ``"weight"``.
    marker_size : float or None, optional
        Marker area in points²; default None: from the number of points (0.5-30).
    poi : tuple or None, optional
        A point of interest (x, y) in m, marked ``+``; default None.
    cmap : str, optional
        A matplotlib colormap name; default ``"viridis"``.

    Returns
    -------
    bytes
        The PNG file's bytes.

    Raises
    ------
    ValueError
        If ``positions`` is not ``(n, 2)`` or ``(n, 1)`` or ``values`` not ``(n,)``.
    """
    from matplotlib.patches import Rectangle

    pos = np.asarray(positions, dtype=np.float64)
    val = np.asarray(values, dtype=np.float64)
    if pos.ndim != 2 or pos.shape[1] not in (1, 2) or val.shape != (len(pos),):
        raise ValueError(f"positions {pos.shape} / values {val.shape} must be (n, 2) or (n, 1) / (n,)")
    mm = 1e3
    line = len(bounds) == 1 or pos.shape[1] == 1
    (x_lo, x_hi) = bounds[0]
    (y_lo, y_hi) = (0.0, 0.0) if line else bounds[1]
    fig, ax = _figure((x_hi - x_lo) * mm, max((y_hi - y_lo) * mm, 0.45 * (x_hi - x_lo) * mm))
    ys = np.zeros(len(pos)) if line else pos[:, 1]
    if line:
        ax.plot([x_lo * mm, x_hi * mm], [0, 0], color="0.8", lw=4, zorder=0)
        ax.set_yticks([])
    else:
        ax.add_patch(Rectangle((x_lo * mm, y_lo * mm), (x_hi - x_lo) * mm, (y_hi - y_lo) * mm,
                               fill=False, edgecolor="0.6", lw=1, zorder=1))
    size = marker_size if marker_size is not None else max(0.5, min(30.0, 6e3 / max(len(pos), 1)))
    sc = ax.scatter(pos[:, 0] * mm, ys * mm, c=val, s=size, marker="o" if line else "s", lw=0,
                    cmap=cmap, zorder=2)
    if poi is not None:
        ax.plot([poi[0] * mm], [0.0 if line else poi[1] * mm], marker="+", color="red", ms=14,
                mew=2, zorder=3)
    pad = 0.02 * max(x_hi - x_lo, 1e-9) * mm
    ax.set_xlim(x_lo * mm - pad, x_hi * mm + pad)
    if not line:
        ax.set_ylim(y_hi * mm + pad, y_lo * mm - pad)  # y down: the smallest y at the top
        ax.set_aspect("equal")
    return _finish(fig, ax, sc, hlabel="x", vlabel=None if line else "y", title=title,
                   colorbar_label=colorbar_label)


def render_lattice(indices: np.ndarray, values: np.ndarray, n_x: int, n_y: int, pitch: float, *,
                   title: str | None = None, colorbar_label: str = "weight", poi: tuple | None = None,
                   cmap: str = "viridis", empty_colour: Any = "0.9") -> bytes:
    """PNG of a mask as an image on its lattice: one cell per lattice point.

    For masks of many points, where :func:`render_points`' markers cost time linear in the
    points (≈ 1.7 s for 51 076) and merge into one another. The lattice is centred
    (``x_i = (i - (n_x - 1)/2)·pitch``); a line lattice (``n_y == 1``) is drawn as a band.
    The same frame as every picture: axes in mm, equal aspect, y down (row 0 = the smallest
    y at the top), colour bar, ``fpscan:axes`` chunk.

    Parameters
    ----------
    indices : ndarray, shape (n, 2)
        Lattice indices (i_x, i_y) of the mask's points.
    values : ndarray, shape (n,)
        The value of each point (its colour).
    n_x, n_y : int
        The lattice's size, >= 1.
    pitch : float
        Lattice spacing in m, > 0.
    title : str or None, optional
        The title; default None: none.
    colorbar_label : str, optional
        The colour bar's label; default ``"weight"``.
    poi : tuple or None, optional
        A point of interest (x, y) in m, marked ``+``; default None.
    cmap : str, optional
        A matplotlib colormap name; default ``"viridis"``.
    empty_colour : matplotlib colour, optional
        The colour of lattice points not in the mask; default ``"0.9"`` (light grey).

    Returns
    -------
    bytes
        The PNG file's bytes.

    Raises
    ------
    ValueError
        If the shapes do not match, indices lie outside the lattice, ``n_x`` or ``n_y`` is
        below 1, ``pitch`` is not > 0, or ``cmap`` is unknown.
    """
    idx = np.asarray(indices, dtype=np.int64).reshape(-1, 2)
    val = np.asarray(values, dtype=np.float64)
    n_x, n_y = int(n_x), int(n_y)
    if val.shape != (len(idx),):
        raise ValueError(f"indices {idx.shape} / values {val.shape} must be (n, 2) / (n,)")
    if n_x < 1 or n_y < 1 or not float(pitch) > 0:
        raise ValueError(f"lattice {n_x} x {n_y} at pitch {pitch} m: need n >= 1 and pitch > 0")
    if len(idx) and (idx.min() < 0 or idx[:, 0].max() >= n_x or idx[:, 1].max() >= n_y):
        raise ValueError(f"indices outside the {n_x} x {n_y} lattice")
    img = np.full((n_y, n_x), np.nan)
    img[idx[:, 1], idx[:, 0]] = val
    mm = float(pitch) * 1e3
    x0, x1 = -n_x / 2 * mm, n_x / 2 * mm  # outermost points ± pitch/2
    line = n_y == 1
    band = 0.45 * (x1 - x0) if line else n_y * mm  # a line lattice: a band as render_points draws it
    fig, ax = _figure(x1 - x0, band)
    colormap = _colormap(cmap).with_extremes(bad=empty_colour)
    finite = val[np.isfinite(val)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    if not hi - lo > 1e-9 * max(abs(lo), abs(hi)):  # equal weights (up to rounding): one colour
        lo, hi = lo - 0.5 * abs(lo or 1.0), hi + 0.5 * abs(hi or 1.0)
    im = ax.imshow(np.ma.masked_invalid(img), cmap=colormap, vmin=lo, vmax=hi, origin="upper",
                   extent=(x0, x1, band / 2, -band / 2), interpolation="nearest",
                   aspect="auto" if line else "equal")
    if line:
        ax.set_yticks([])
    if poi is not None:
        ax.plot([poi[0] * 1e3], [0.0 if line else poi[1] * 1e3], marker="+", color="red", ms=14, mew=2)
    return _finish(fig, ax, im, hlabel="x", vlabel=None if line else "y", title=title,
                   colorbar_label=colorbar_label)


def _colormap(name: str) -> Colormap:
    import matplotlib
    try:
        return matplotlib.colormaps[name]
    except KeyError:
        raise ValueError(f"unknown colormap {name!r}") from None


def _coords(p0: np.ndarray, z: Any, x: Any, y: Any) -> tuple[np.ndarray, np.ndarray, Any]:
    p0 = np.asarray(p0)
    z = np.asarray(z, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    if p0.ndim not in (2, 3):
        raise ValueError(f"p0 must be (n_z, n_x) or (n_z, n_y, n_x), got shape {p0.shape}")
    if z.shape != (p0.shape[0],) or x.shape != (p0.shape[-1],):
        raise ValueError(f"z {z.shape} / x {x.shape} do not match p0 {p0.shape}")
    if p0.ndim == 3:
        if y is None:
            raise ValueError("a 3-D p0 needs its y coordinates")
        y = np.asarray(y, dtype=np.float64)
        if y.shape != (p0.shape[1],):
            raise ValueError(f"y {y.shape} does not match p0 {p0.shape}")
    return z, x, y


def render_mip(p0: np.ndarray, z: Any, x: Any, y: Any = None, plane: str = "xy",
               **options: Any) -> bytes:
    """PNG of the maximum intensity projection (MIP) of ``p0`` on ``plane`` (module docstring).

    Parameters
    ----------
    p0 : ndarray, shape (n_z, n_y, n_x) or (n_z, n_x)
        The image, row 0 at the sensor plane.
    z : array_like, shape (n_z,)
        Depth of each row in m.
    x : array_like, shape (n_x,)
        Lateral x of each column in m.
    y : array_like, shape (n_y,), or None, optional
        Lateral y in m (required for a 3-D ``p0``); default None.
    plane : str, optional
        ``"xy"``, ``"xz"`` or ``"yz"`` (only ``"xz"`` in 2-D); default ``"xy"``.
    **options
        Passed to :func:`render_png` (``cmap``, ``vmin``, ``vmax``, ``annotate``, ``title``,
        ...); the default title is ``"MIP {plane}"`` (``"p0 (x, z)"`` in 2-D).

    Returns
    -------
    bytes
        The PNG file's bytes.

    Raises
    ------
    ValueError
        A bad plane, or shapes of ``p0``, ``z``, ``x``, ``y`` that do not match.
    """
    z, x, y = _coords(p0, z, x, y)
    img = mip(p0, plane)
    h, hl = (y, "y") if plane == "yz" else (x, "x")
    v, vl = (y, "y") if plane == "xy" else (z, "z")
    options.setdefault("title", f"MIP {plane}" if np.ndim(p0) == 3 else "p0 (x, z)")
    return render_png(img, h, v, hlabel=hl, vlabel=vl, **options)


def render_mips(p0: np.ndarray, z: Any, x: Any, y: Any = None, *, title_prefix: str = "",
                **options: Any) -> dict[str, bytes]:
    """The MIP pictures of every plane the image has (xy, xz, yz in 3-D; xz in 2-D).

    Parameters
    ----------
    p0 : ndarray, shape (n_z, n_y, n_x) or (n_z, n_x)
        The image, row 0 at the sensor plane.
    z : array_like, shape (n_z,)
        Depth of each row in m.
    x : array_like, shape (n_x,)
        Lateral x of each column in m.
    y : array_like, shape (n_y,), or None, optional
        Lateral y in m (required for a 3-D ``p0``); default None.
    title_prefix : str, optional
        Text put before each default title; default ``""``.
    **options
        Passed to :func:`render_mip` for every plane.

    Returns
    -------
    dict of str to bytes
        ``{plane: PNG}``.

    Raises
    ------
    ValueError
        As :func:`render_mip`.
    """
    planes = PLANES if np.ndim(p0) == 3 else ("xz",)
    out = {}
    for plane in planes:
        opts = dict(options)
        if title_prefix and "title" not in opts:
            opts["title"] = title_prefix + (f"MIP {plane}" if np.ndim(p0) == 3 else "p0 (x, z)")
        out[plane] = render_mip(p0, z, x, y, plane, **opts)
    return out


def render_result_slice(path: Any, index: int, **options: Any) -> bytes:
    """PNG of the depth slice ``index`` of a result file, read without loading the whole volume.

    A 2-D result gives its image row at that depth.

    Parameters
    ----------
    path : str or os.PathLike
        The result file (``fpscan.service.storage.results``).
    index : int
        The depth row, in ``[0, n_z)``.
    **options
        Passed to :func:`render_png`.

    Returns
    -------
    bytes
        The PNG file's bytes.

    Raises
    ------
    ValueError
        If ``index`` is out of range.
    OSError
        If the file cannot be read (FileNotFoundError if it is missing).
    """
    from fpscan.service.formats.result import read_slice

    img, z, x, y = read_slice(path, index)
    if img.ndim == 1:  # a 2-D result: the row at this depth
        options.setdefault("title", f"p0 at depth z = {z[index] * 1e3:.3f} mm")
        return render_png(img[None, :], x, z[index:index + 1], hlabel="x", vlabel="z",
                          depth_down=True, **options)
    return render_lateral(img, x, y, float(z[index]), **options)


def render_lateral(img: np.ndarray, x: Any, y: Any, depth: float, **options: Any) -> bytes:
    """PNG of one lateral plane (x to the right, y down: row 0 at the top).

    Parameters
    ----------
    img : ndarray, shape (n_y, n_x)
        The plane.
    x : array_like, shape (n_x,)
        Lateral x in m.
    y : array_like, shape (n_y,)
        Lateral y in m.
    depth : float
        The plane's depth in m (shown in mm in the default title).
    **options
        Passed to :func:`render_png`.

    Returns
    -------
    bytes
        The PNG file's bytes.

    Raises
    ------
    ValueError
        As :func:`render_png` (shape mismatch, unknown colormap).
    """
    options.setdefault("title", f"depth slice z = {depth * 1e3:.3f} mm")
    return render_png(np.asarray(img), np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64),
                      hlabel="x", vlabel="y", **options)
