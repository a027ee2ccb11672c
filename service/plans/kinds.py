"""``make_mask``: one entry point from a mask kind name + parameters (HTTP layer, CLI)."""
from __future__ import annotations

import inspect
from collections.abc import Callable

from .angular import equiangular_mask, equisteradian_mask
from .grids import full_mask, hexagonal_mask, points_mask, poisson_mask, random_mask, subgrid_mask
from .lattice import Lattice
from .mask import Mask

__all__ = ["MASK_KINDS", "make_mask"]

#: kind name -> mask function (first argument: the lattice).
MASK_KINDS: dict[str, Callable[..., Mask]] = {
    "full": full_mask,
    "subgrid": subgrid_mask,
    "hexagonal": hexagonal_mask,
    "random": random_mask,
    "poisson": poisson_mask,
    "points": points_mask,
    "equiangular": equiangular_mask,
    "equisteradian": equisteradian_mask,
}
_ALIASES = {"equispaced": "subgrid", "grid": "subgrid", "hex": "hexagonal", "poisson-disc": "poisson", "user": "points"}


def make_mask(kind: str, lattice, **params) -> Mask:
    """Make a sensor mask of kind ``kind`` on ``lattice`` (a ``Lattice`` or a dict with
    n_x, n_y, pitch). Kinds and their parameters (SI units; m for lengths):

    - ``full``: no parameters.
    - ``subgrid`` (aliases ``equispaced``, ``grid``): ``interval`` (int ≥ 1, lattice points between
      sensors), ``n_per_side`` (int or [n_x, n_y]; default as many as fit), centred.
    - ``hexagonal`` (``hex``): ``spacing`` (m, ≥ pitch).
    - ``random``: ``n_points``, ``seed`` (default 0).
    - ``poisson`` (``poisson-disc``): ``min_distance`` (m), ``seed`` (default 0),
      ``n_points`` (optional cap).
    - ``points`` (``user``): ``points`` [[x, y], ...] in m (snapped) or ``indices``
      [[i_x, i_y], ...].
    - ``equiangular`` (line lattice, n_y = 1): ``depth`` (m), ``n_points``, ``poi`` (x in m
      or [x, y]; default the centre).
    - ``equisteradian`` (2-D lattice): ``depth`` (m), ``n_points``, ``poi`` ([x, y] in m;
      default the centre).

    Raises ValueError: unknown kind, unknown or missing parameters, and every bad value
    the kind's function rejects (see each function).
    """
    if not isinstance(lattice, Lattice):
        if isinstance(lattice, dict):
            try:
                lattice = Lattice(**lattice)
            except TypeError as exc:
                raise ValueError(f"lattice must have n_x, n_y and pitch: {exc}") from None
        else:
            raise ValueError(f"lattice must be a Lattice or a dict, got {type(lattice).__name__}")
    if not isinstance(kind, str):
        raise ValueError(f"mask kind must be a string, got {kind!r}")
    name = _ALIASES.get(kind.lower(), kind.lower())
    if name not in MASK_KINDS:
        raise ValueError(f"unknown mask kind {kind!r}; known: {', '.join(sorted(MASK_KINDS))}")
    fn = MASK_KINDS[name]
    sig = inspect.signature(fn)
    allowed = list(sig.parameters)[1:]
    unknown = sorted(set(params) - set(allowed))
    if unknown:
        raise ValueError(f"unknown parameter(s) for mask {name!r}: {', '.join(unknown)}; allowed: {', '.join(allowed) or 'none'}")
    missing = [p for p in allowed if sig.parameters[p].default is inspect.Parameter.empty and p not in params]
    if missing:
        raise ValueError(f"mask {name!r} needs parameter(s): {', '.join(missing)}")
    return fn(lattice, **params)
