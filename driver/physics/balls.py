"""Exact photoacoustic signals of uniform balls (spheres) at point sensors.

A ball of radius R and initial pressure A centred at distance r from a point sensor
(in a homogeneous, lossless medium of sound speed c, with p_t(., 0) = 0) produces the
N-shaped wave

    p(t) = A (r - c t) / (2 r)    for |r - c t| <= R,    0 otherwise

(Diebold & Westervelt 1988; Wang & Wu, "Biomedical Optics", eq. 12.32). fpscan samples
it as a sensor of finite bandwidth would: each sample n is the mean of p over the
interval [t_n - dt/2, t_n + dt/2], computed in closed form, so the A-lines are free of
the aliasing that point samples of the discontinuous N-wave would carry.
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from driver.constants import C_DEFAULT

__all__ = ["Ball", "ball_alines", "ball_p0"]


@dataclass(frozen=True)
class Ball:
    """A uniform ball of initial pressure.

    Attributes: centre ``x``, ``y`` (lateral) and ``z`` (depth below the sensor plane,
    z > 0) in m; ``radius`` in m; ``amplitude`` (p0 inside the ball) in Pa.
    """

    x: float
    y: float
    z: float
    radius: float
    amplitude: float = 1.0

    def __post_init__(self) -> None:
        vals = (self.x, self.y, self.z, self.radius, self.amplitude)
        if not all(np.isfinite(v) for v in vals):
            raise ValueError(f"Ball parameters must be finite, got {vals}")
        if self.radius <= 0:
            raise ValueError(f"Ball radius must be > 0 m, got {self.radius}")


def _as_balls(balls: Iterable[Ball] | Ball) -> list[Ball]:
    if isinstance(balls, Ball):
        return [balls]
    out = list(balls)
    if not out:
        raise ValueError("at least one Ball is required")
    for b in out:
        if not isinstance(b, Ball):
            raise ValueError(f"expected Ball instances, got {type(b).__name__}")
    return out


def _positions_3d(positions: np.ndarray) -> np.ndarray:
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim != 2 or pos.shape[1] not in (1, 2):
        raise ValueError(f"positions must have shape (n_points, 2) or (n_points, 1), got {pos.shape}")
    if not np.all(np.isfinite(pos)):
        raise ValueError("positions must be finite")
    if pos.shape[1] == 1:
        pos = np.column_stack([pos[:, 0], np.zeros(len(pos))])
    return pos


def ball_alines(
    positions: np.ndarray,
    balls: Sequence[Ball] | Ball,
    dt: float,
    n_t: int,
    c: float = C_DEFAULT,
    t0: float = 0.0,
) -> np.ndarray:
    """A-lines of uniform balls at point sensors on the plane z = 0.

    Parameters
    ----------
    positions : (n_points, 2) array of sensor (x, y) in m ((n_points, 1): y = 0).
    balls : one `Ball` or a sequence of them.
    dt : sample interval in s (> 0).  n_t : samples per A-line (>= 1).
    c : sound speed in m/s (> 0).  t0 : time of sample 0 in s (t_n = t0 + n dt).

    Returns
    -------
    (n_points, n_t) float64 array of pressure in Pa: sample n is the exact mean of the
    N-shaped wave A (r - c t)/(2 r) over t in [t_n - dt/2, t_n + dt/2] (the wave is
    even in t, so intervals reaching below t = 0 use |t|).

    Raises
    ------
    ValueError for non-finite or mis-shaped positions, dt/c <= 0, n_t < 1, or no balls.
    """
    pos = _positions_3d(positions)
    balls = _as_balls(balls)
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a finite number > 0 s, got {dt}")
    if not (np.isfinite(c) and c > 0):
        raise ValueError(f"c must be a finite number > 0 m/s, got {c}")
    if int(n_t) != n_t or n_t < 1:
        raise ValueError(f"n_t must be an integer >= 1, got {n_t}")
    if not np.isfinite(t0):
        raise ValueError("t0 must be finite")
    t = t0 + dt * np.arange(int(n_t))
    out = np.zeros((len(pos), int(n_t)))
    for b in balls:
        r = np.sqrt((pos[:, 0] - b.x) ** 2 + (pos[:, 1] - b.y) ** 2 + b.z**2)[:, None]
        out += b.amplitude * _mean_n_wave(r, t - dt / 2, t + dt / 2, b.radius, c) / dt
    return out


def _mean_n_wave(r, ta, tb, radius, c):
    """Integral over t in [ta, tb] of (r - c|t|)/(2r) restricted to |r - c|t|| <= R."""
    # Split intervals that straddle t = 0 (the wave is even in t).
    neg = ta < 0
    total = np.zeros(np.broadcast_shapes(r.shape, ta.shape))
    a = np.where(neg, 0.0, ta)
    total += _integral_positive(r, a, np.maximum(tb, 0.0), radius, c)
    if np.any(neg):
        total += _integral_positive(r, np.zeros_like(ta), np.where(neg, -ta, 0.0), radius, c)
    return total


def _integral_positive(r, ta, tb, radius, c):
    # u = r - c t runs from r - c ta down to r - c tb; integrand u/(2r) dt = -u du/(2 r c)
    u_hi = np.minimum(r - c * ta, radius)
    u_lo = np.maximum(r - c * tb, -radius)
    valid = u_hi > u_lo
    val = (u_hi**2 - u_lo**2) / (4.0 * r * c)
    return np.where(valid, val, 0.0)


def ball_p0(
    balls: Sequence[Ball] | Ball,
    z: np.ndarray,
    x: np.ndarray,
    y: np.ndarray | None = None,
    supersample: int = 1,
) -> np.ndarray:
    """Initial pressure p0 of uniform balls sampled on a grid.

    Parameters
    ----------
    balls : one `Ball` or a sequence.
    z, x, y : 1-D coordinate vectors in m (depth, lateral). ``y=None`` gives the 2-D
        slice y = 0.
    supersample : s >= 1 averages an s x s (x s) sub-grid per voxel (partial-volume).

    Returns
    -------
    (n_z, n_y, n_x) array (or (n_z, n_x) for ``y=None``) of p0 in Pa.
    """
    balls = _as_balls(balls)
    z = np.asarray(z, float)
    x = np.asarray(x, float)
    yy = np.zeros(1) if y is None else np.asarray(y, float)
    s = int(supersample)
    if s < 1:
        raise ValueError("supersample must be >= 1")

    def offsets(v):
        d = np.diff(v).mean() if len(v) > 1 else 0.0
        return ((np.arange(s) + 0.5) / s - 0.5) * d

    out = np.zeros((len(z), len(yy), len(x)))
    oz, ox = offsets(z), offsets(x)
    oy = offsets(yy) if y is not None else np.zeros(1)
    for dz_ in oz:
        for dy_ in oy:
            for dx_ in ox:
                Z = (z + dz_)[:, None, None]
                Y = (yy + dy_)[None, :, None]
                X = (x + dx_)[None, None, :]
                for b in balls:
                    inside = (X - b.x) ** 2 + (Y - b.y) ** 2 + (Z - b.z) ** 2 <= b.radius**2
                    out += b.amplitude * inside
    out /= len(oz) * len(oy) * len(ox)
    return out[:, 0, :] if y is None else out
