"""Sensor masks, weights and scan plans (DESIGN §3.3, §4; issue 3).

Where the scanner measures and with what weight each A-line enters the reconstruction:
``Lattice`` (the addressable points), masks (``make_mask`` and the per-kind functions),
``Plan`` (an ordered mask plus acquisition settings, content-hashed; JSON and HDF5),
orderings and a preview PNG. Depends on numpy/scipy (+ pydantic for ``Plan``;
matplotlib is imported only inside ``preview_png``).
"""
from __future__ import annotations

from .angular import equiangular_mask, equisteradian_mask, equisteradian_rings
from .grids import full_mask, hexagonal_mask, points_mask, poisson_mask, random_mask, subgrid_mask
from .lattice import Lattice
from .mask import Mask, distance_law_weights, weight_ratio
from .kinds import MASK_KINDS, make_mask
from .ordering import nearest_neighbour_order, ring_order, scan_order, serpentine_order
from .plan import PLAN_FORMAT, Acquisition, Plan, canonical_json, content_id, make_plan, plan_from_spec
from .preview import preview_png

__all__ = [
    "Lattice", "Mask", "make_mask", "MASK_KINDS",
    "full_mask", "subgrid_mask", "hexagonal_mask", "random_mask", "poisson_mask", "points_mask",
    "equiangular_mask", "equisteradian_mask", "equisteradian_rings",
    "distance_law_weights", "weight_ratio",
    "scan_order", "serpentine_order", "ring_order", "nearest_neighbour_order",
    "Plan", "Acquisition", "PLAN_FORMAT", "make_plan", "plan_from_spec", "canonical_json", "content_id",
    "preview_png",
]
