"""A sparse scan taken out of dense data: the A-lines a sensor mask (or a scan plan) would
have measured, from a dense scan or a k-Wave simulation on the same lattice.

It is the replay scan without the scanner (docs/protocol.md Appendix B: ``fpscan sim
--source replay FILE``, then ``fpscan scan``): the same rule picks the A-lines (the mask's
lattice centred on the data's grid at the same pitch; plan point (i_x, i_y) is grid point
(i_x + (N_x − n_x)/2, i_y + (N_y − n_y)/2); a plan's dt must be the data's and its n_t at most
the data's samples, which are cut to it), the scanner's int16 digitisation
(:func:`fpscan.driver.aline.quantise`) and the scan file's reading (``sample·scale``), so that the
point data, and every reconstruction of them, equal the replay scan's to the last bit.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from fpscan.service.recon.dataset import GridDataset, PointDataset, lattice_axes

if TYPE_CHECKING:
    from fpscan.service.plans import Mask, Plan

__all__ = ["subsample", "check_fit", "MaskMismatch"]


class MaskMismatch(ValueError):
    """A mask (or plan) that cannot sample the data, with the reason (the command line names
    its ``--plan``, the server its ``plan_id``)."""


def _grid(dataset: GridDataset | PointDataset) -> GridDataset:
    """The dense data as a grid (a full-lattice scan turns into one); ValueError otherwise."""
    if isinstance(dataset, PointDataset):
        if not dataset.full_lattice:
            raise MaskMismatch("subsample needs dense data: every point of a regular grid (a k-Wave sensor plane or "
                             "line, or a full-lattice scan), got a sensor mask's points")
        return dataset.to_grid()
    return dataset


def _offsets(data_shape: tuple[int, ...], n_x: int, n_y: int) -> tuple[int, int]:
    """Where the mask's lattice sits on the grid: (off_x, off_y) grid points, centred."""
    big_x, big_y = data_shape[-1], (data_shape[1] if len(data_shape) == 3 else 1)
    off_x, off_y = (big_x - n_x) / 2, (big_y - n_y) / 2
    if off_x < 0 or off_y < 0 or off_x % 1 or off_y % 1:
        raise MaskMismatch(f"the mask's lattice {n_x}x{n_y} does not sit centred on the data's grid {big_x}x{big_y} "
                         "(both are centred on the optical axis: each side must be smaller by an even number)")
    return int(off_x), int(off_y)


def _mask_or_plan(mask: Mask | Plan | dict) -> Mask | Plan:
    """A plan document (``fpscan.load_plan``'s dict) as a :class:`fpscan.service.plans.Plan` (validated)."""
    if isinstance(mask, dict):
        from fpscan.service.plans import Plan

        return Plan.from_dict(mask)
    return mask


def check_fit(data_shape: tuple[int, ...] | list[int], spacings: tuple[float | None, ...], dt: float,
              mask: Mask | Plan | dict) -> tuple[int, int, int]:
    """Whether ``mask`` can sample dense data of this shape (the rule of :func:`subsample`,
    checked before any data is read, e.g. by the server on a stored dataset's record).

    Parameters
    ----------
    data_shape : tuple of int
        ``(n_t, N_x)`` or ``(n_t, N_y, N_x)``.
    spacings : tuple of float or None
        ``(dx, dy)`` of the data, m (None: not known, not checked).
    dt : float
        The data's sample interval, s.
    mask : fpscan.service.plans.Mask, fpscan.service.plans.Plan or dict
        The mask, a plan, or a plan document.

    Returns
    -------
    off_x, off_y, n_t : int
        Where the mask's lattice sits on the grid (grid points), and the samples an A-line keeps
        (a plan's n_t, else all).

    Raises
    ------
    MaskMismatch
        (a ValueError) A line lattice on plane data or the reverse, a pitch or a plan's dt that differs (1e-6
        relative), a lattice that does not sit centred on the grid, a plan's n_t beyond the data's.
    """
    from fpscan.service.plans import Plan

    mask = _mask_or_plan(mask)
    shape = tuple(int(n) for n in data_shape)
    lattice = mask.lattice_obj if isinstance(mask, Plan) else mask.lattice
    n_t = shape[0]
    if isinstance(mask, Plan):
        plan_dt, n_t = float(mask.acquisition.dt), int(mask.acquisition.n_t)
        if abs(plan_dt - dt) > 1e-6 * dt:
            raise MaskMismatch(f"the plan's dt {plan_dt:g} s differs from the data's {dt:g} s")
        if n_t > shape[0]:
            raise MaskMismatch(f"the plan's n_t {n_t} exceeds the data's {shape[0]} samples")
    if (len(shape) == 2) != lattice.is_line:
        raise MaskMismatch(f"a {'line' if lattice.is_line else 'plane'} lattice cannot sample "
                         f"{len(shape) - 1}-D sensor data {list(shape)}")
    for name, d in zip(("dx", "dy"), spacings, strict=False):
        if d is not None and abs(lattice.pitch - d) > 1e-6 * d:
            raise MaskMismatch(f"the mask's lattice pitch {lattice.pitch:g} m differs from the data's {name} {d:g} m")
    off_x, off_y = _offsets(shape, lattice.n_x, lattice.n_y)
    return off_x, off_y, n_t


def subsample(dataset: GridDataset | PointDataset, mask: Mask | Plan | dict, *, quantise: bool = True) -> PointDataset:
    """The A-lines ``mask`` picks out of dense ``dataset``, with the mask's quadrature weights.

    Parameters
    ----------
    dataset : GridDataset or PointDataset
        Dense data: ``(n_t, n_y, n_x)`` / ``(n_t, n_x)`` grid data (a k-Wave file), or a scan of
        every lattice point.
    mask : fpscan.service.plans.Mask, fpscan.service.plans.Plan or dict
        The sensor mask, or a scan plan (or its document, as ``fpscan.load_plan`` reads it) (its points in scan order; its dt must be the data's,
        to 1e-6, and its n_t at most the data's samples: the A-lines are cut to n_t). Its
        lattice pitch must be the data's spacing (to 1e-6) and its lattice centred on the
        data's grid, each side smaller by an even number of points (or equal).
    quantise : bool, optional
        Digitise each A-line as the scanner does (int16, per-A-line scale: what a replay scan
        records; default); False keeps the data's own values.

    Returns
    -------
    PointDataset
        ``alines`` ``(n, n_t)`` float64 in the data's unit, ``positions`` ``(n, 2)`` (x, y) m
        (``(n, 1)`` on a line lattice), the mask's ``weights`` (m², m on a line), its
        ``indices`` and ``lattice``, ``grid`` the lattice's axes, the data's ``c``, ``dt``,
        ``t0``, ``wavelengths`` and ``lateral_shift``; ``source`` ``"subsample"``, ``meta``
        ``plan_id`` (a plan), ``mask_kind`` and ``dense_shape``.

    Raises
    ------
    MaskMismatch
        (a ValueError) Data that are not dense, a 2-D/3-D mismatch, a pitch or dt that differs, a lattice that
        does not sit centred on the grid, a plan's n_t beyond the data's samples.

    Examples
    --------
    A dense 8 × 8 plane of A-lines, and the 3 × 3 subgrid of every third point:

    >>> import numpy as np
    >>> import fpscan
    >>> dense = fpscan.GridDataset(np.random.default_rng(0).standard_normal((64, 8, 8)), dx=1e-4, dt=1e-8,
    ...                            sound_speed=1500.0)
    >>> mask = fpscan.make_mask("equispaced", fpscan.Lattice(8, 8, 1e-4), interval=3)
    >>> sparse = fpscan.subsample(dense, mask)
    >>> sparse.alines.shape, sparse.positions.shape, float(sparse.weights.sum()) == mask.covered_area
    ((9, 64), (9, 2), True)
    >>> fpscan.subsample(dense, fpscan.make_mask("full", fpscan.Lattice(7, 7, 1e-4)))
    Traceback (most recent call last):
    ...
    fpscan.service.subsample.MaskMismatch: the mask's lattice 7x7 does not sit centred on the data's grid 8x8 (both are centred on the optical axis: each side must be smaller by an even number)
    """
    from fpscan.driver.aline import quantise as digitise
    from fpscan.service.plans import Plan

    mask = _mask_or_plan(mask)
    grid = _grid(dataset)
    off_x, off_y, n_t = check_fit(grid.data.shape, (grid.dx, grid.dy if grid.data.ndim == 3 else None), grid.dt,
                                  mask)
    if isinstance(mask, Plan):
        lattice = mask.lattice_obj
        indices, positions, weights = mask.indices_array(), mask.positions_array(), mask.weights_array()
        kind, plan_id = mask.mask.kind, mask.id
    else:
        lattice, indices, positions = mask.lattice, np.asarray(mask.indices), mask.positions
        weights, kind, plan_id = np.asarray(mask.weights, dtype=np.float64), mask.kind, None
    ix, iy = indices[:, 0].astype(np.intp) + off_x, indices[:, 1].astype(np.intp) + off_y
    picked = grid.data[:n_t, ix] if grid.data.ndim == 2 else grid.data[:n_t, iy, ix]
    alines = np.ascontiguousarray(picked.T).astype(np.float64)  # (n, n_t), as the replay source renders them
    if quantise:
        samples, scale = digitise(alines)
        alines = samples.astype(np.float64)
        alines *= scale[:, None]  # the scan file's reading: sample·scale (+ offset 0) / dc level 1
    lat = {"n_x": lattice.n_x, "n_y": lattice.n_y, "pitch": float(lattice.pitch)}
    gx, gy = lattice_axes(lat)
    meta = {k: v for k, v in (grid.meta or {}).items() if k == "p0_unit"}
    meta.update({"mask_kind": kind, "dense_shape": list(grid.data.shape), "quantised": bool(quantise)})
    if plan_id is not None:
        meta["plan_id"] = plan_id
    return PointDataset(alines=alines, positions=positions[:, :1].copy() if lattice.is_line else positions,
                        weights=weights, dt=grid.dt, sound_speed=grid.sound_speed, grid=(gx,) if lattice.is_line else (gx, gy),
                        t0=grid.t0, source="subsample", meta=meta, indices=indices.astype(np.int64).reshape(-1, 2),
                        lattice=lat, wavelengths=grid.wavelengths, lateral_shift=grid.lateral_shift)
