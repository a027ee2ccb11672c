"""Preview PNG of a mask or plan: points on the lattice, weight as colour, the point of
interest marked, counts and weight ratio in the caption; drawn by the one picture path of
fpscan (``fpscan.service.pictures.render.render_points``: mm axes, equal aspect, y down as in every picture)."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from fpscan.service.plans.mask import Mask
    from fpscan.service.plans.plan import Plan

__all__ = ["preview_png"]


def preview_png(mask_or_plan: Mask | Plan, path: str | Path | None = None) -> bytes:
    r"""Render a ``Mask`` or ``Plan`` as a PNG picture.

    Axes in mm (x right, y down; a line lattice shows x only); the lattice outline is drawn,
    each point coloured by its weight (µm², or µm on a line); a ``+`` marks the point of
    interest (a plan's mask params ``poi``). The title states kind, obtained/requested points
    and the outer/inner weight ratio.

    Parameters
    ----------
    mask_or_plan : Mask or Plan
        What to draw.
    path : str or Path, optional
        Also write the PNG there.

    Returns
    -------
    bytes
        The PNG file's content.

    Raises
    ------
    ValueError
        For anything but a Mask or a Plan.

    Examples
    --------
    >>> from fpscan.service.plans import Lattice, full_mask, preview_png
    >>> png = preview_png(full_mask(Lattice(5, 5, 1e-4)))
    >>> png[:8]  # the PNG signature
    b'\x89PNG\r\n\x1a\n'
    >>> preview_png("mask")
    Traceback (most recent call last):
    ...
    ValueError: preview_png needs a Mask or a Plan, got str
    """
    from fpscan.service.pictures.render import render_points
    from fpscan.service.plans.mask import Mask, weight_ratio
    from fpscan.service.plans.plan import Plan

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

    line = lat.is_line
    scale, unit = (1e6, "µm") if line else (1e12, "µm²")
    title = (f"{kind}: {obtained} of {requested} requested points on {lat.n_x}×{lat.n_y}\n"
             f"outer/inner weight ratio {ratio:.3g}")
    data = render_points(pos[:, :1] if line else pos[:, :2], np.asarray(w) * scale, tuple(lat.bounds),
                         title=title, colorbar_label=f"weight ({unit})", poi=poi)
    if path is not None:
        Path(path).write_bytes(data)
    return data
