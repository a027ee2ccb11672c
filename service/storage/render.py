"""PNG renderings of a reconstructed p0: maximum-intensity projections (MIPs) and depth
slices, with axes in mm (matplotlib, Agg canvas, no pyplot state: thread-safe) or as raw
pixels (one pixel per sample, Pillow).

Images follow DESIGN §3: ``p0`` is ``(n_z, n_y, n_x)`` (3-D) or ``(n_z, n_x)`` (2-D), row 0
at the sensor plane z = 0, with coordinate vectors ``z``, ``y``, ``x`` in m.

MIP planes (max over the named axis):

=======  ===========  ==================  =====================================
plane    max over     array shape         drawn as
=======  ===========  ==================  =====================================
``xy``   z (axis 0)   (n_y, n_x)          x to the right, y upwards
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
from typing import Any

import numpy as np

PLANES = ("xy", "xz", "yz")
_AXIS = {"xy": 0, "xz": 1, "yz": 2}


def mip(p0: np.ndarray, plane: str) -> np.ndarray:
    """The maximum-intensity projection of ``p0`` on ``plane`` (table above).

    Raises ValueError for an unknown plane, a plane a 2-D image does not have, or a
    ``p0`` that is not 2-D/3-D.
    """
    p0 = np.asarray(p0)
    if plane not in PLANES:
        raise ValueError(f"plane must be one of {', '.join(PLANES)}, not {plane!r}")
    if p0.ndim == 2:
        if plane != "xz":
            raise ValueError("a 2-D image (n_z, n_x) has only the xz plane")
        return p0
    if p0.ndim != 3:
        raise ValueError(f"p0 must be (n_z, n_x) or (n_z, n_y, n_x), got shape {p0.shape}")
    return p0.max(axis=_AXIS[plane])


def _levels(img: np.ndarray, vmin: float | None, vmax: float | None) -> tuple[float, float]:
    finite = img[np.isfinite(img)]
    lo = 0.0 if vmin is None else float(vmin)
    hi = (float(finite.max()) if finite.size else lo) if vmax is None else float(vmax)
    return lo, hi


def to_uint8(img: np.ndarray, vmin: float | None = None, vmax: float | None = None) -> np.ndarray:
    """Grey levels 0..255 of a 2-D array (module docstring); NaN → 0."""
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
               depth_down: bool, title: str | None = None, cmap: str = "gray",
               vmin: float | None = None, vmax: float | None = None, annotate: bool = True,
               colorbar_label: str = "p0 (input units)", bad_colour: Any = None) -> bytes:
    """PNG of a 2-D array ``img`` ``(len(v), len(h))``: row i at vertical coordinate
    ``v[i]`` (m), column j at ``h[j]`` (m).

    ``annotate=True``: matplotlib figure with axes in mm, labels, title and a colour bar;
    ``depth_down`` puts ``v[0]`` at the top (depth axes), else at the bottom.
    ``annotate=False``: exactly one pixel per sample, row 0 at the top, grey levels of
    :func:`to_uint8` (``cmap`` applied if not ``"gray"``). ``bad_colour`` (a matplotlib
    colour, annotated figures only): NaN pixels (e.g. masked) drawn in it instead of at
    ``vmin``. Raises ValueError on shape mismatch or an unknown colormap.
    """
    img = np.asarray(img)
    if img.ndim != 2 or img.shape != (len(v), len(h)):
        raise ValueError(f"image shape {img.shape} does not match axes ({len(v)}, {len(h)})")
    import matplotlib
    try:
        colormap = matplotlib.colormaps[cmap]
    except KeyError:
        raise ValueError(f"unknown colormap {cmap!r}") from None
    if not annotate:
        from PIL import Image as PILImage
        grey = to_uint8(img, vmin, vmax)
        if cmap == "gray":
            pil = PILImage.fromarray(grey, mode="L")
        else:
            pil = PILImage.fromarray((colormap(grey)[..., :3] * 255 + 0.5).astype(np.uint8), "RGB")
        buf = io.BytesIO()
        pil.save(buf, format="PNG")
        return buf.getvalue()

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    lo, hi = _levels(np.asarray(img, dtype=np.float64), vmin, vmax)
    if not hi > lo:
        hi = lo + 1.0
    h0, h1 = (e * 1e3 for e in _edges(h))
    v0, v1 = (e * 1e3 for e in _edges(v))
    aspect = abs(v1 - v0) / max(abs(h1 - h0), 1e-12)
    width = 6.0
    height = float(np.clip(width * 0.8 * aspect + 1.2, 2.4, 9.0))
    fig = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
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
    ax.set_xlabel(f"{hlabel} (mm)")
    ax.set_ylabel(f"{vlabel} (mm)")
    if title:
        ax.set_title(title)
    cb = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
    cb.set_label(colorbar_label)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


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
    """PNG of the MIP of ``p0`` on ``plane`` (module docstring); ``options`` go to
    :func:`render_png` (``cmap``, ``vmin``, ``vmax``, ``annotate``, ``title``).
    Raises ValueError (bad plane, shapes)."""
    z, x, y = _coords(p0, z, x, y)
    img = mip(p0, plane)
    h, hl = (y, "y") if plane == "yz" else (x, "x")
    v, vl, down = (y, "y", False) if plane == "xy" else (z, "z", True)
    options.setdefault("title", f"MIP {plane}" if np.ndim(p0) == 3 else "p0 (x, z)")
    return render_png(img, h, v, hlabel=hl, vlabel=vl, depth_down=down, **options)


def render_mips(p0: np.ndarray, z: Any, x: Any, y: Any = None, **options: Any) -> dict[str, bytes]:
    """``{plane: PNG}`` for every plane the image has (xy, xz, yz in 3-D; xz in 2-D)."""
    planes = PLANES if np.ndim(p0) == 3 else ("xz",)
    return {plane: render_mip(p0, z, x, y, plane, **dict(options)) for plane in planes}


def render_slice(p0: np.ndarray, z: Any, x: Any, y: Any, index: int, **options: Any) -> bytes:
    """PNG of the depth slice ``p0[index]`` (x to the right, y upwards) of a 3-D volume.

    Grey levels default to the slice's own maximum. Raises ValueError (2-D image, index
    out of range, shapes)."""
    z, x, y = _coords(p0, z, x, y)
    if np.ndim(p0) != 3:
        raise ValueError("depth slices need a 3-D volume (n_z, n_y, n_x)")
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)):
        raise ValueError(f"index must be an integer, got {index!r}")
    if not 0 <= index < len(z):
        raise ValueError(f"index {index} out of range [0, {len(z)})")
    options.setdefault("title", f"depth slice z = {z[index] * 1e3:.3f} mm")
    return render_png(np.asarray(p0)[index], x, y, hlabel="x", vlabel="y", depth_down=False,
                      **options)
