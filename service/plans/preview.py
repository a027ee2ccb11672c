"""Preview PNG of a mask or plan: points on the lattice, weight as colour, the point of
interest marked, counts and weight ratio in the caption (matplotlib, Agg backend)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["preview_png"]


def preview_png(mask_or_plan, path: str | Path | None = None, *, dpi: int = 100,
                size_in: float = 6.0) -> bytes:
    """Render a ``Mask`` or ``Plan`` as PNG bytes (also written to ``path`` if given).

    Axes in mm (x right, y up; a line lattice shows x only); the lattice outline is drawn,
    each point coloured by its weight (µm², or µm on a line); a ``+`` marks the point of
    interest (a plan's mask params ``poi``). The title states kind, obtained/requested
    points and the outer/inner weight ratio. Raises ValueError for other objects."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from .mask import Mask, weight_ratio
    from .plan import Plan

    if isinstance(mask_or_plan, Mask):
        lat = mask_or_plan.lattice
        pos = mask_or_plan.positions
        w = mask_or_plan.weights
        kind = mask_or_plan.kind
        requested, obtained = mask_or_plan.requested_points, mask_or_plan.obtained_points
        ratio: float | None = mask_or_plan.weight_ratio
        poi = mask_or_plan.poi
    elif isinstance(mask_or_plan, Plan):
        lat = mask_or_plan.lattice_obj
        pos = mask_or_plan.positions_array()
        w = mask_or_plan.weights_array()
        kind = mask_or_plan.mask.kind
        requested, obtained = mask_or_plan.mask.requested_points, mask_or_plan.mask.obtained_points
        ratio = mask_or_plan.mask.weight_ratio
        if ratio is None:
            ratio = weight_ratio(pos, w, (0.0, 0.0))
        p = mask_or_plan.mask.params.get("poi")
        poi = None if p is None else (float(np.ravel(p)[0]), float(np.ravel(p)[1]) if np.size(p) > 1 else 0.0)
    else:
        raise ValueError(f"preview_png needs a Mask or a Plan, got {type(mask_or_plan).__name__}")

    fig = Figure(figsize=(size_in, size_in if not lat.is_line else size_in * 0.45), dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    (x_lo, x_hi), *rest = lat.bounds
    mm = 1e3
    if lat.is_line:
        scale, unit = 1e6, "µm"
        ax.plot([x_lo * mm, x_hi * mm], [0, 0], color="0.8", lw=4, zorder=0)
        sc = ax.scatter(pos[:, 0] * mm, np.zeros(len(pos)), c=w * scale, s=18, cmap="viridis", zorder=2)
        if poi is not None:
            ax.plot([poi[0] * mm], [0], marker="+", color="red", ms=14, mew=2, zorder=3)
        ax.set_yticks([])
        ax.set_xlabel("x (mm)")
    else:
        scale, unit = 1e12, "µm²"
        (y_lo, y_hi) = rest[0]
        ax.add_patch(_rect(fig, x_lo * mm, y_lo * mm, (x_hi - x_lo) * mm, (y_hi - y_lo) * mm))
        ms = max(0.5, min(30.0, 6e3 / max(len(pos), 1)))
        sc = ax.scatter(pos[:, 0] * mm, pos[:, 1] * mm, c=w * scale, s=ms, marker="s", lw=0,
                        cmap="viridis", zorder=2)
        if poi is not None:
            ax.plot([poi[0] * mm], [poi[1] * mm], marker="+", color="red", ms=14, mew=2, zorder=3)
        ax.set_aspect("equal")
        ax.set_xlim(x_lo * mm, x_hi * mm)
        ax.set_ylim(y_lo * mm, y_hi * mm)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    cb = fig.colorbar(sc, ax=ax, shrink=0.8)
    cb.set_label(f"weight ({unit})")
    ax.set_title(
        f"{kind}: {obtained} of {requested} requested points on {lat.n_x}×{lat.n_y}\n"
        f"outer/inner weight ratio {ratio:.3g}",
        fontsize=10,
    )
    fig.tight_layout()
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    data = buf.getvalue()
    if path is not None:
        Path(path).write_bytes(data)
    return data


def _rect(fig, x, y, w, h):
    from matplotlib.patches import Rectangle

    return Rectangle((x, y), w, h, fill=False, edgecolor="0.6", lw=1, zorder=1)
