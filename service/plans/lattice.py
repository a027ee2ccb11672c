"""The scanner lattice: the points an FP scanner can address (docs/architecture.md, "Conventions")."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from fpscan.physics.axes import centred_axis, centred_index, centred_positions

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

__all__ = ["Lattice"]


def _check_length(name: str, value: Any) -> float:
    if isinstance(value, str):  # text with a unit ("60um"): the one unit parser
        from fpscan.driver.units import parse_quantity

        value = parse_quantity(value, "length", name=name)
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number in m, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {v}")
    return v


@dataclass(frozen=True)
class Lattice:
    """``n_x × n_y`` addressable points at pitch ``pitch`` (m), centred on the optical axis.

    Coordinates follow docs/architecture.md: ``x_i = (i - (n_x - 1)/2) * pitch``,
    ``i = 0..n_x-1``, and the same for y. A 2-D (line) scanner has ``n_y = 1`` (y = 0).
    Indices are ``(i_x, i_y)``; positions ``(x, y)`` in m.

    Parameters
    ----------
    n_x, n_y : int
        Number of lattice points along x and y, >= 1 each (``n_y = 1``: a line scanner).
    pitch : float or str
        Distance between neighbouring points, m (> 0, finite); a text with a unit
        (``"60um"``) is parsed by ``fpscan.driver.units.parse_quantity``.

    Attributes
    ----------
    n_x, n_y : int
        As given.
    pitch : float
        In m.
    n_points : int
        ``n_x * n_y``.
    x, y : ndarray, shapes ``(n_x,)`` and ``(n_y,)``
        Coordinates of the points along each axis, m.
    is_line : bool
        True for a line lattice (``n_y = 1``, 2-D imaging).
    half_extent : tuple of float
        Distance from the centre to the outermost points along x and y, m.
    bounds : tuple of (float, float)
        Covered area ``((x_lo, x_hi), (y_lo, y_hi))`` in m (outermost points ± pitch/2);
        ``((x_lo, x_hi),)`` on a line lattice.
    area : float
        Covered area, m² (m on a line lattice).

    Raises
    ------
    ValueError
        n_x or n_y not a positive integer, pitch <= 0 or non-finite.

    Examples
    --------
    >>> from fpscan.service.plans import Lattice
    >>> lat = Lattice(5, 3, 1e-4)  # 5 x 3 points, 0.1 mm apart
    >>> lat.n_points, lat.is_line
    (15, False)
    >>> lat.x  # m, centred on the optical axis
    array([-0.0002, -0.0001,  0.    ,  0.0001,  0.0002])
    >>> lat.positions([[0, 0], [4, 2]])  # (i_x, i_y) -> (x, y) in m
    array([[-0.0002, -0.0001],
           [ 0.0002,  0.0001]])
    >>> lat.snap([[1.4e-4, -0.6e-4]])  # (x, y) in m -> nearest (i_x, i_y)
    array([[3, 0]])
    >>> Lattice(0, 1, 1e-4)
    Traceback (most recent call last):
    ...
    ValueError: n_x must be a positive integer, got 0
    """

    n_x: int
    n_y: int
    pitch: float

    def __post_init__(self) -> None:
        for name in ("n_x", "n_y"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or int(v) < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
            object.__setattr__(self, name, int(v))
        p = _check_length("pitch", self.pitch)
        if p <= 0:
            raise ValueError(f"pitch must be > 0 m, got {p}")
        object.__setattr__(self, "pitch", p)

    # -- geometry -----------------------------------------------------------------
    @property
    def is_line(self) -> bool:
        """True for a 2-D imaging lattice (a line of points, n_y = 1)."""
        return self.n_y == 1

    @property
    def n_points(self) -> int:
        return self.n_x * self.n_y

    @property
    def x(self) -> np.ndarray:
        """``(n_x,)`` x coordinates in m."""
        return centred_axis(self.n_x, self.pitch)

    @property
    def y(self) -> np.ndarray:
        """``(n_y,)`` y coordinates in m."""
        return centred_axis(self.n_y, self.pitch)

    @property
    def half_extent(self) -> tuple[float, float]:
        """Distance (m) from the centre to the outermost lattice points along x and y."""
        return ((self.n_x - 1) / 2 * self.pitch, (self.n_y - 1) / 2 * self.pitch)

    @property
    def bounds(self) -> tuple[tuple[float, float], ...]:
        """The area the lattice covers, ``((x_lo, x_hi), (y_lo, y_hi))`` in m
        (outermost points ± pitch/2); a line lattice gives ``((x_lo, x_hi),)``."""
        hx, hy = self.half_extent
        h = self.pitch / 2
        if self.is_line:
            return ((-hx - h, hx + h),)
        return ((-hx - h, hx + h), (-hy - h, hy + h))

    @property
    def area(self) -> float:
        """Covered area in m² (m for a line lattice)."""
        if self.is_line:
            return self.n_x * self.pitch
        return self.n_x * self.n_y * self.pitch**2

    def positions(self, indices: ArrayLike) -> np.ndarray:
        """Positions of lattice indices.

        Parameters
        ----------
        indices : array_like of int, shape ``(n, 2)``
            Lattice indices (i_x, i_y).

        Returns
        -------
        ndarray, shape ``(n, 2)``
            Positions (x, y), m.

        Raises
        ------
        ValueError
            Indices outside the lattice, not integers, or of the wrong shape.

        Examples
        --------
        >>> from fpscan.service.plans import Lattice
        >>> Lattice(5, 3, 1e-4).positions([[2, 1]])
        array([[0., 0.]])
        >>> Lattice(5, 3, 1e-4).positions([[5, 0]])
        Traceback (most recent call last):
        ...
        ValueError: indices outside the 5 x 3 lattice
        """
        idx = np.asarray(indices)
        if idx.ndim != 2 or idx.shape[1] != 2:
            raise ValueError(f"indices must have shape (n, 2), got {idx.shape}")
        if idx.size and not np.issubdtype(idx.dtype, np.integer):
            if not np.all(np.isfinite(idx)) or np.any(idx != np.round(idx)):
                raise ValueError("indices must be integers")
        idx = idx.astype(np.int64)
        if np.any(idx < 0) or np.any(idx[:, 0] >= self.n_x) or np.any(idx[:, 1] >= self.n_y):
            raise ValueError(f"indices outside the {self.n_x} x {self.n_y} lattice")
        out = np.empty(idx.shape, dtype=np.float64)
        out[:, 0] = centred_positions(idx[:, 0], self.n_x, self.pitch)
        out[:, 1] = centred_positions(idx[:, 1], self.n_y, self.pitch)
        return out

    def snap(self, positions: ArrayLike) -> np.ndarray:
        """Nearest lattice indices of positions.

        Ties (a position exactly half-way between two lattice points) are broken away from the
        lattice centre, so snapping commutes with the lattice's mirror symmetries everywhere
        except on the centre lines of an even-sized lattice.

        Parameters
        ----------
        positions : array_like, shape ``(n, 2)``, ``(n, 1)`` or ``(n,)``
            (x, y) or x, m.

        Returns
        -------
        ndarray of int64, shape ``(n, 2)``
            Lattice indices (i_x, i_y).

        Raises
        ------
        ValueError
            Non-finite positions or positions more than half a pitch outside the lattice.

        Examples
        --------
        >>> from fpscan.service.plans import Lattice
        >>> lat = Lattice(5, 3, 1e-4)
        >>> lat.snap([[0.5e-4, 0.0], [-0.5e-4, 0.0]])  # ties go away from the centre
        array([[3, 1],
               [1, 1]])
        >>> lat.snap([[1e-3, 0.0]])
        Traceback (most recent call last):
        ...
        ValueError: position (0.001, 0) m lies outside the 5 x 3 lattice (pitch 0.0001 m)
        """
        pos = np.asarray(positions, dtype=np.float64)
        if pos.ndim == 1:
            pos = pos[:, None]
        if pos.ndim != 2 or pos.shape[1] not in (1, 2):
            raise ValueError(f"positions must have shape (n, 2) or (n, 1), got {pos.shape}")
        if not np.all(np.isfinite(pos)):
            raise ValueError("positions contain non-finite values")
        if pos.shape[1] == 1:
            pos = np.column_stack((pos[:, 0], np.zeros(pos.shape[0])))
        idx = np.empty(pos.shape, dtype=np.int64)
        for a, n in enumerate((self.n_x, self.n_y)):
            u = np.round(pos[:, a] / self.pitch, 9)  # pitches from the centre; float noise killed so ties are ties
            rel = centred_index(u, n, 1.0)  # index coordinate
            # round half away from the centre
            r = np.where(u >= 0, np.floor(rel + 0.5), np.ceil(rel - 0.5))
            # exactly half a pitch beyond the outermost point still snaps onto it
            edge = (np.abs(rel - np.clip(rel, 0, n - 1)) <= 0.5 + 1e-9)
            r = np.where(edge, np.clip(r, 0, n - 1), r)
            if np.any(r < 0) or np.any(r > n - 1):
                bad = pos[(r < 0) | (r > n - 1)][0]
                raise ValueError(
                    f"position ({bad[0]:.6g}, {bad[1]:.6g}) m lies outside the "
                    f"{self.n_x} x {self.n_y} lattice (pitch {self.pitch:g} m)"
                )
            idx[:, a] = r.astype(np.int64)
        return idx

    def contains(self, x: float, y: float = 0.0) -> bool:
        """Whether a lateral point lies within the lattice's outermost points.

        Parameters
        ----------
        x, y : float
            Lateral position, m (y default 0).

        Returns
        -------
        bool

        Examples
        --------
        >>> from fpscan.service.plans import Lattice
        >>> Lattice(5, 3, 1e-4).contains(2e-4, 1e-4), Lattice(5, 3, 1e-4).contains(3e-4)
        (True, False)
        """
        hx, hy = self.half_extent
        tol = 1e-9 * self.pitch
        return abs(x) <= hx + tol and abs(y) <= hy + tol

    def to_dict(self) -> dict:
        """The lattice as JSON-safe dict (the plan JSON's ``lattice``).

        Returns
        -------
        dict
            ``{"n_x", "n_y", "pitch"}``, pitch in m.

        Examples
        --------
        >>> from fpscan.service.plans import Lattice
        >>> Lattice(5, 3, 1e-4).to_dict()
        {'n_x': 5, 'n_y': 3, 'pitch': 0.0001}
        """
        return {"n_x": self.n_x, "n_y": self.n_y, "pitch": self.pitch}
