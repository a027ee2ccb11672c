"""Sensor masks, weights and scan plans (the paper §5 and its appendix).

Where the scanner measures and with what weight each A-line enters the reconstruction:

- ``Lattice(n_x, n_y, pitch)``: the addressable points, centred on the optical axis
  (``x_i = (i - (n_x - 1)/2) * pitch``; a line scanner has ``n_y = 1``).
- Masks (``Mask``: ``indices`` (n, 2), ``positions`` (n, 2) in m, ``weights`` (n,) in m²
  (m on a line), requested/obtained points, ``weight_ratio``): ``make_mask(kind, lattice,
  **params)`` (kinds and their parameter models declared once in ``KINDS``,
  ``fpscan.service.plans.kinds``) or the per-kind functions — full, subgrid (kind ``equispaced``), hexagonal, random, poisson,
  points, and the paper's ``equiangular_mask`` (2-D) / ``equisteradian_mask`` (3-D).
  Default weights: clipped Voronoi areas (``fpscan.physics.weights.voronoi_weights``);
  equiangular / equi-steradian: r² / r³ about the point of interest (paper §5.2).
- ``Plan``: an ordered mask plus acquisition settings with its content hash as id, in the
  JSON of docs/architecture.md ("Plan JSON") and in HDF5; ``make_plan`` /
  ``plan_from_spec``; orders serpentine, rings (alternating), nearest-neighbour.
- ``preview_png``: the mask on its lattice, weight as colour (matplotlib, Agg).

Example (the paper's 3-D mask)::

    lattice = Lattice(226, 226, 60e-6)
    plan = make_plan("equisteradian", lattice=lattice, params={"depth": 3.6e-3, "n_points": 1625})
    plan.to_json("plan.json")     # 1653 points, outer/inner weight ratio 9.69

Depends on numpy/scipy (+ pydantic for ``Plan``; matplotlib only inside ``preview_png``).
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

#: public name -> submodule. Loaded on first use (PEP 562), so that the cheap parts (the
#: kinds' parameter models that `fpscan`'s argument parser is built from) do not pay for
#: numpy/scipy at start-up.
_EXPORTS = {
    **dict.fromkeys(["equiangular_mask", "equisteradian_mask", "equisteradian_rings"], "angular"),
    **dict.fromkeys(["full_mask", "subgrid_mask", "hexagonal_mask", "random_mask", "poisson_mask",
                     "points_mask"], "grids"),
    **dict.fromkeys(["KINDS", "MASK_KINDS", "kind_fields", "make_mask", "resolve_kind"], "kinds"),
    "Lattice": "lattice",
    **dict.fromkeys(["Mask", "distance_law_weights", "weight_ratio"], "mask"),
    **dict.fromkeys(["nearest_neighbour_order", "ring_order", "scan_order", "serpentine_order"], "ordering"),
    **dict.fromkeys(["PLAN_FORMAT", "Acquisition", "Plan", "canonical_json", "content_id", "make_plan",
                     "plan_from_spec", "check_plausible_request"], "plan"),
    "preview_png": "preview",
}

if TYPE_CHECKING:
    from fpscan.service.plans.angular import equiangular_mask, equisteradian_mask, equisteradian_rings
    from fpscan.service.plans.grids import (
        full_mask,
        hexagonal_mask,
        points_mask,
        poisson_mask,
        random_mask,
        subgrid_mask,
    )
    from fpscan.service.plans.kinds import KINDS, MASK_KINDS, kind_fields, make_mask, resolve_kind
    from fpscan.service.plans.lattice import Lattice
    from fpscan.service.plans.mask import Mask, distance_law_weights, weight_ratio
    from fpscan.service.plans.ordering import (
        nearest_neighbour_order,
        ring_order,
        scan_order,
        serpentine_order,
    )
    from fpscan.service.plans.plan import (
        PLAN_FORMAT,
        Acquisition,
        Plan,
        canonical_json,
        check_plausible_request,
        content_id,
        make_plan,
        plan_from_spec,
    )
    from fpscan.service.plans.preview import preview_png


def __getattr__(name: str) -> Any:
    """Load a public name's submodule on first use (PEP 562)."""
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    globals()[name] = value
    return value


__all__ = [
    "Lattice", "Mask", "make_mask", "MASK_KINDS", "KINDS", "resolve_kind", "kind_fields",
    "full_mask", "subgrid_mask", "hexagonal_mask", "random_mask", "poisson_mask", "points_mask",
    "equiangular_mask", "equisteradian_mask", "equisteradian_rings",
    "distance_law_weights", "weight_ratio",
    "scan_order", "serpentine_order", "ring_order", "nearest_neighbour_order",
    "Plan", "Acquisition", "PLAN_FORMAT", "make_plan", "plan_from_spec", "canonical_json", "content_id",
    "preview_png",
    "check_plausible_request",
]
