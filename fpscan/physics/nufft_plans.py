"""Lateral NUFFT plans made once per sensor mask and reused.

The lateral transforms of NEDNER (type 1: A-lines at the sensor positions -> k-space,
paper eq. (5)), of the planar operator's adjoint (type 1) and of the point forward model
(type 2: k-space -> the sensor positions) see the same sensor positions call after call:
the live preview refreshes, repeated jobs on one plan, and the model-based iterations.
FINUFFT splits a transform into planning (kernel set-up, FFTW plan, sorting the points:
``finufft.Plan`` and ``Plan.setpts``) and execution (``Plan.execute``); this module keeps
the planned part in a small least-recently-used cache keyed on the mask's coordinates and
the transform's sizes, so that only ``execute`` runs again.

Source: FINUFFT's guru interface (Barnett, Magland, af Klinteberg, SIAM J. Sci. Comput. 41
(2019) C479; ``finufft.Plan``). The cache changes no result: a planned transform and the
one-shot ``finufft.nufft*`` functions run the same code with the same options.
"""
from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from typing import Any

import finufft
import numpy as np

__all__ = ["MAX_PLANS", "lateral_plan", "clear_plans"]

#: plans kept (each holds one fine grid: ~(1.25..2)^d x the mode count x 8..16 bytes with
#: one thread, and the sorted points)
MAX_PLANS = 8

_lock = threading.Lock()
_plans: OrderedDict[tuple, _Entry] = OrderedDict()


class _Entry:
    """One planned transform, its coordinates (FINUFFT keeps pointers to them) and a lock:
    a plan executes one transform at a time."""

    def __init__(self, plan: Any, coords: tuple[np.ndarray, ...]) -> None:
        self.plan = plan
        self.coords = coords
        self.lock = threading.Lock()

    def execute(self, data: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        with self.lock:
            return self.plan.execute(data, out=out)


def lateral_plan(nufft_type: int, coords: tuple[np.ndarray, ...], n_modes: tuple[int, ...], n_trans: int, *,
                 eps: float, isign: int, dtype: Any, upsampfac: float | None = None) -> _Entry:
    """A planned FINUFFT transform over ``coords`` (cached; see module doc).

    Parameters
    ----------
    nufft_type : int
        1 (non-uniform points -> modes) or 2 (modes -> points).
    coords : tuple of ndarray
        One (n_points,) array per dimension in FINUFFT's order (the order of ``n_modes``),
        in radians ([-3π, 3π)); float64 or float32 as ``dtype``'s real part.
    n_modes : tuple of int
        Mode counts per dimension, e.g. ``(n_x,)`` or ``(n_y, n_x)``.
    n_trans : int
        Transforms per ``execute`` call (the leading axis of its data).
    eps, isign, upsampfac
        FINUFFT's tolerance, exponent sign and oversampling factor (``None``: FINUFFT's
        choice). ``modeord=1`` (FFT order) and one thread always.
    dtype
        complex64 or complex128: the precision of data, modes and coordinates.

    Returns
    -------
    An object whose ``execute(data, out=None)`` runs the transform: type 1 takes
    ``(n_trans, n_points)`` strengths and returns ``(n_trans, *n_modes)``; type 2 the
    reverse.

    Raises
    ------
    ValueError
        Coordinates of unequal lengths or non-finite, ``n_trans`` < 1.

    References
    ----------
    .. [1] A. H. Barnett, J. Magland, L. af Klinteberg, "A parallel nonuniform fast Fourier
       transform library based on an 'exponential of semicircle' kernel", SIAM J. Sci.
       Comput. 41 (2019).

    Examples
    --------
    A type-2 transform is the sum over the modes k (FFT order: 0, 1, -2, -1) of
    ``modes[k]·exp(i k x)`` at each point x; a second request for the same transform gets
    the cached plan.

    >>> import numpy as np
    >>> from fpscan.physics.nufft_plans import lateral_plan
    >>> x = np.array([0.0, 0.5, -2.0])  # rad
    >>> modes = np.array([[1, 2, 3, 4]], dtype=complex)  # (n_trans, n_x)
    >>> plan = lateral_plan(2, (x,), (4,), 1, eps=1e-12, isign=1, dtype=np.complex128)
    >>> k = np.fft.fftfreq(4, 1 / 4)
    >>> bool(np.allclose(plan.execute(modes)[0], np.exp(1j * np.outer(x, k)) @ modes[0]))
    True
    >>> lateral_plan(2, (x,), (4,), 1, eps=1e-12, isign=1, dtype=np.complex128) is plan
    True
    """
    dtype = np.dtype(dtype)
    ftype = np.float32 if dtype == np.complex64 else np.float64
    coords = tuple(np.ascontiguousarray(c, dtype=ftype) for c in coords)
    if len(coords) != len(n_modes) or len({len(c) for c in coords}) != 1:
        raise ValueError("give one coordinate array per mode dimension, all of one length")
    if n_trans < 1:
        raise ValueError(f"n_trans must be >= 1, got {n_trans}")
    if not all(np.all(np.isfinite(c)) for c in coords):
        raise ValueError("NUFFT coordinates must be finite")
    digest = hashlib.blake2b(b"".join(c.tobytes() for c in coords), digest_size=16).hexdigest()
    key = (nufft_type, tuple(int(n) for n in n_modes), int(n_trans), float(eps), int(isign), dtype.str,
           upsampfac, len(coords[0]), digest)
    with _lock:
        entry = _plans.get(key)
        if entry is not None:
            _plans.move_to_end(key)
            return entry
    opts: dict[str, Any] = dict(modeord=1, nthreads=1)
    if upsampfac is not None:
        opts["upsampfac"] = upsampfac
    plan = finufft.Plan(nufft_type, tuple(int(n) for n in n_modes), n_trans=int(n_trans), eps=float(eps),
                        isign=int(isign), dtype=dtype.name, **opts)
    plan.setpts(*coords)
    entry = _Entry(plan, coords)
    with _lock:
        _plans[key] = entry
        while len(_plans) > MAX_PLANS:
            _plans.popitem(last=False)
    return entry


def clear_plans() -> None:
    """Drop every cached plan (frees their memory).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.nufft_plans import clear_plans, lateral_plan
    >>> x = np.array([0.0, 1.0])
    >>> plan = lateral_plan(2, (x,), (4,), 1, eps=1e-9, isign=1, dtype=np.complex128)
    >>> clear_plans()
    >>> lateral_plan(2, (x,), (4,), 1, eps=1e-9, isign=1, dtype=np.complex128) is plan  # planned anew
    False
    """
    with _lock:
        _plans.clear()
