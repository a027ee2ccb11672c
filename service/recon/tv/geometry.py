"""tv's geometry numbers: the step's ‖BA‖ estimate and the noise image's RMS, kept per geometry.

Both depend on the geometry alone (the operator, the preconditioner P and the seeded starts):
‖BA‖ (B = P Aᵀ) from `POWER_STEPS` power iterations from a seeded white image
(`_gain_estimate`; the solver raises its L where the iterates show more), and the RMS of the
noise image B n̂ of one seeded white-noise record n̂ of unit σ, whose product with σ̂ is the
image's noise level of the automatic λ (`fpscan.service.recon.tv.lam`). `geometry_numbers` keeps
them for the last `GEOMETRY_KEPT` geometries (`GeometryMemo`), so a repeated scan plan
spends no operator pairs on them and gets the numbers a fresh process computes. Why two
power iterations: docs/tv-measurements.md, "Solver".
"""
from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from fpscan.service.progress import Span
    from fpscan.service.recon.operator import PlanarOperator
    from fpscan.service.recon.tv.problem import Model

__all__ = ["POWER_STEPS", "GEOMETRY_KEPT", "GEOMETRY", "GeometryMemo", "geometry_numbers"]

#: power iterations for the first step 1 / ‖BA‖ (the solver raises L where it sees more)
POWER_STEPS = 2


def geometry_numbers(model: Model, progress: Span) -> tuple[float, float, bool]:
    """The geometry's numbers of a run (module doc): the step's ‖BA‖ estimate and the noise
    image's RMS, kept per geometry in `GEOMETRY`.

    ‖BA‖ (B = P Aᵀ) from `POWER_STEPS` power iterations from a seeded white image, and the RMS
    of B n̂ for one seeded white-noise record n̂ of unit σ (its product with σ̂ is the image's
    noise level of the automatic λ, `fpscan.service.recon.tv.lam`).

    Parameters
    ----------
    model : Model
        The run's A and B (`fpscan.service.recon.tv.problem.Model`: its ``op``, ``shape``,
        ``dx``, ``dz`` (m), ``pos``, ``dtype``, ``g``, ``forward`` and ``B``).
    progress : callable
        ``progress(fraction)`` after each power iteration (fractions k / `POWER_STEPS`).

    Returns
    -------
    tuple
        ``(gain, noise_rms, geometry_kept)``: the ‖BA‖ estimate (dimensionless for P's
        normalisation), the noise image's RMS per unit σ, and whether both were kept from an
        earlier run on this geometry.

    Examples
    --------
    A model whose A and B are the identity on a 2 x 3 image (the numbers of the seeded starts):

    >>> import numpy as np
    >>> from types import SimpleNamespace
    >>> from fpscan.service.recon.tv.geometry import GEOMETRY, geometry_numbers
    >>> op = SimpleNamespace(dt=1e-8, n_t=3, c=1500.0, t0=0.0, eps=1e-6, band=None, periodic=False,
    ...                      padded_shape=(2, 3))
    >>> model = SimpleNamespace(op=op, shape=(2, 3), dx=1e-4, dz=1e-4, pos=None, dtype=np.float64,
    ...                         g=np.zeros((2, 3)), forward=lambda v: v.copy(), B=lambda r: np.array(r))
    >>> GEOMETRY.clear()
    >>> gain, rms, kept = geometry_numbers(model, lambda f: None)
    >>> round(gain, 12), kept
    (1.0, False)
    >>> geometry_numbers(model, lambda f: None)[2]  # the same geometry again: kept
    True
    """
    key = _geometry_key(model.op, model.shape, model.dx, model.dz, model.pos, model.dtype, model.g.shape)
    kept = GEOMETRY.get(key)
    geometry_kept = kept is not None
    if kept is None:
        start = np.random.default_rng(0).standard_normal(model.shape).astype(model.dtype)
        gain = _gain_estimate(lambda v: model.B(model.forward(v)), start, POWER_STEPS,
                              step=lambda k, n: progress(k / n))
        del start
        noise_image = model.B(np.random.default_rng(0).standard_normal(model.g.shape)).ravel()
        if isinstance(noise_image, np.ndarray):
            total = float(np.einsum("i,i->", noise_image, noise_image, dtype=np.float64))  # accumulated in float64
        else:  # a GPU run's image (CuPy)
            wide = noise_image.astype(np.float64)
            total = float(wide @ wide)
        noise_rms = math.sqrt(total / noise_image.size)
        del noise_image
        kept = (gain, noise_rms)
        GEOMETRY.put(key, kept)
    gain, noise_rms = kept
    return gain, noise_rms, geometry_kept


def _gain_estimate(apply: Callable[[np.ndarray], np.ndarray], start: np.ndarray, steps: int,
                   step: Callable[[int, int], None] | None = None) -> float:
    """Largest gain ‖BA v‖ / ‖v‖ of ``apply`` (= B A, B the NER/NEDNER of a residual) by
    ``steps`` power iterations from ``start`` (an image; not modified)."""
    v = start / np.linalg.norm(start)
    gain = 0.0
    for k in range(steps):
        u = apply(v)
        if isinstance(u, np.ndarray):
            u = np.asarray(u, dtype=v.dtype).reshape(v.shape)
            gain = float(np.linalg.norm(u))
        else:  # a GPU run's image (CuPy)
            u = u.astype(v.dtype, copy=False).reshape(v.shape)
            gain = float((u.astype(np.float64) ** 2).sum() ** 0.5)
        if gain == 0.0:
            return 0.0
        v = np.divide(u, gain, out=u) if isinstance(u, np.ndarray) else u / gain
        if step is not None:
            step(k + 1, steps)
    return gain


class GeometryMemo:
    """The last few geometries' ‖BA‖ estimate and noise-image RMS (`geometry_numbers`).

    Numbers of the operator, the preconditioner and the seeded starts alone, so a repeated scan
    plan (the same mask, grid, sampling and band) skips the 2.5 operator pairs that make them,
    and its result is the one a fresh process computes. At most ``size`` entries (a few floats
    each), the least recently used dropped first; safe across threads. ``get(key)``,
    ``put(key, value)``, ``clear()``.

    Parameters
    ----------
    size : int
        Entries kept.

    Attributes
    ----------
    get : callable
        ``get(key)``: the kept ``(gain, noise_rms)`` of a geometry, or None (it becomes the most
        recent).
    put : callable
        ``put(key, value)``: keep a geometry's numbers.
    clear : callable
        ``clear()``: forget every geometry.

    Examples
    --------
    >>> from fpscan.service.recon.tv.geometry import GeometryMemo
    >>> memo = GeometryMemo(2)
    >>> memo.put("a", (1.0, 0.5)); memo.put("b", (2.0, 0.5)); memo.put("c", (3.0, 0.5))
    >>> memo.get("a"), memo.get("c")  # "a", the oldest, was dropped
    (None, (3.0, 0.5))
    """

    def __init__(self, size: int) -> None:
        import threading

        self._size, self._lock = size, threading.Lock()
        self._items: dict[tuple, tuple[float, float]] = {}

    def get(self, key: tuple) -> tuple[float, float] | None:
        with self._lock:
            value = self._items.pop(key, None)
            if value is not None:
                self._items[key] = value  # most recent last
            return value

    def put(self, key: tuple, value: tuple[float, float]) -> None:
        with self._lock:
            self._items.pop(key, None)
            self._items[key] = value
            while len(self._items) > self._size:
                self._items.pop(next(iter(self._items)))

    def clear(self) -> None:
        with self._lock:
            self._items.clear()


#: geometries kept (`GeometryMemo`): a lab alternates between a few scan plans
GEOMETRY_KEPT = 8
#: the process's memo of `geometry_numbers` (``GEOMETRY.clear()`` forgets every geometry)
GEOMETRY = GeometryMemo(GEOMETRY_KEPT)


def _geometry_key(op: PlanarOperator, shape: tuple[int, ...], dx: float, dz: float, pos: np.ndarray | None,
                  rdtype: npt.DTypeLike, data_shape: tuple[int, ...]) -> tuple:
    """What ‖BA‖ and the noise image depend on: the operator's grid, sampling, band, sensors
    (their bytes' digest), precision and the data's shape (the noise record's)."""
    import hashlib

    where = None if pos is None else hashlib.sha256(np.ascontiguousarray(pos, dtype=np.float64).tobytes()).hexdigest()
    return (tuple(shape), float(dx), float(dz), float(op.dt), int(op.n_t), float(op.c), float(op.t0), float(op.eps),
            op.band, bool(op.periodic), op.padded_shape, np.dtype(rdtype).name, tuple(data_shape), where)
