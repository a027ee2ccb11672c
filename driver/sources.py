"""A-line sources of the simulated FP scanner: what pressure reaches each sensor point.

Every source is prepared for one uploaded plan (:meth:`Source.prepare`), which checks the
plan against the source and returns a function ``pressure(ks, ws=None) -> (len(ks), n_t)``
float64 in Pa for point indices ``ks`` of that plan at excitation wavelength indices ``ws``
(``None``: the first; deterministic: the same point and wavelength always give the same
A-line). Sources:

* :class:`BallSource` — analytic balls: exact N-shaped waves averaged over each sample
  interval (``fpscan.physics.ball_alines``; docs/protocol.md Appendix B). With ``so2``
  given, each ball is blood-like tissue, a mixture of HbO2 and Hb at that oxygen
  saturation, and its amplitude follows its absorption at each wavelength:
  p0 = Γ·Φ·μa(λ) with μa from Prahl's molar extinction table (``fpscan.physics.spectra``).
  Without, balls have the same amplitude at every wavelength, as do the other sources.
* :class:`VolumeSource` — any p0 volume (HDF5 ``p0`` ``(n_z, n_y, n_x)``) through the exact
  planar forward model ``fpscan.physics.forward.forward_points``.
* :class:`ReplaySource` — a recorded dense dataset in k-Wave layout (``sensor_data/clean``
  ``(t, y, z)`` with ``sensor_yz_index``); plan point (i_x, i_y) replays
  ``data[:, i_y, i_x]`` — the paper's way of picking a sensor mask out of dense data.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from fpscan.constants import C_DEFAULT
from fpscan.driver.kwave_layout import lateral_spacings
from fpscan.driver.plan_image import DevicePlan

__all__ = ["PressureFn", "Source", "SOURCE_MAX_BYTES", "default_phantom", "BallSource", "VolumeSource", "ReplaySource"]

#: the most bytes one dataset of a volume or replay file may declare (the service's bound on any
#: input, ``fpscan.service.formats.MAX_BYTES``); the file is vetted (``fpscan.driver.hdf5_checks``) before it is read
SOURCE_MAX_BYTES = 1 << 34

PressureFn = Callable[..., np.ndarray]  # pressure(ks, ws=None) -> (len(ks), n_t)


class Source(Protocol):
    """What the simulator needs of a source (:class:`BallSource`, :class:`VolumeSource`,
    :class:`ReplaySource`).

    Attributes
    ----------
    peak : float
        Reference amplitude for the SNR, Pa.
    """

    @property
    def peak(self) -> float:
        """Reference amplitude for the SNR, Pa."""
        ...

    def prepare(self, plan: DevicePlan) -> PressureFn:
        """The pressure function of ``plan``'s points: point indices -> A-lines."""
        ...

    def describe(self) -> str:
        """A one-line description (stored in the simulator's record)."""
        ...


def default_phantom() -> list:
    """The demo phantom: four balls and a curved "tube" (a chain of small balls).

    Sized for a 226 × 226 lattice at 60 µm (13.5 mm aperture): balls of radius 0.15–0.3 mm
    at depths 1.5–4.5 mm, and a tube of radius 0.1 mm bending through depth 2.5–3.5 mm.
    Returns a list of ``fpscan.physics.Ball`` (m, Pa).

    Returns
    -------
    list of Ball
        The balls: positions and radii in m, amplitudes in Pa.
    """
    from fpscan.physics import Ball

    balls = [Ball(0.0, 0.0, 3.6e-3, 0.3e-3, 1.0),
             Ball(-2.5e-3, 1.5e-3, 1.5e-3, 0.2e-3, 1.0),
             Ball(2.0e-3, -2.0e-3, 4.5e-3, 0.25e-3, 0.8),
             Ball(1.5e-3, 2.5e-3, 2.0e-3, 0.15e-3, 1.2)]
    # curved tube: arc in the x-y plane, sagging in depth, balls overlapping by half
    r_tube, step = 0.1e-3, 0.1e-3
    s = np.arange(-3.0e-3, 3.0e-3 + step / 2, step)
    for si in s:
        x = si
        y = -3.0e-3 + 0.12 * (si * 1e3) ** 2 * 1e-3
        z = 2.5e-3 + 1.0e-3 * np.cos(np.pi * si / 6.0e-3)
        balls.append(Ball(float(x), float(y), float(z), r_tube, 0.6))
    return balls


@dataclass
class BallSource:
    """Analytic balls (``fpscan.physics.Ball``) in a medium of sound speed ``c`` (m/s).

    Spectral phantom (optional): ``so2`` — one oxygen saturation (0..1) per ball;
    ``thb`` — total haemoglobin per ball (or one for all), mol/m³ (default whole blood,
    ``fpscan.physics.spectra.BLOOD_THB`` ≈ 2.33 mol/m³); ``gruneisen`` Γ (dimensionless)
    and ``fluence`` Φ (J/m², the same everywhere). Ball i then has the initial pressure
    p0_i(λ) = Γ·Φ·μa_i(λ), μa_i(λ) = ln 10 · thb_i · (so2_i·ε_HbO2(λ) + (1 − so2_i)·ε_Hb(λ))
    (Prahl's table, ``fpscan.physics.spectra.absorption``), and its ``amplitude`` is not
    used. Raises ``ValueError`` (at construction) for so2/thb of the wrong length or out of
    range, and (in :meth:`prepare`) for wavelengths outside the table.

    Attributes
    ----------
    balls : list of Ball
        The balls (positions and radii in m, amplitudes in Pa).
    c : float
        Sound speed, m/s (default ``fpscan.constants.C_DEFAULT``).
    so2 : sequence of float or None
        Oxygen saturation per ball, 0..1 (None: no spectral phantom; the amplitudes are used).
    thb : float or sequence of float or None
        Total haemoglobin per ball (or one for all), mol/m³ (None: ``BLOOD_THB``).
    gruneisen : float
        Grüneisen parameter Γ, dimensionless (default 0.2).
    fluence : float
        Fluence Φ, J/m² (default 100).
    """

    balls: list
    c: float = C_DEFAULT
    so2: Sequence[float] | None = None
    thb: float | Sequence[float] | None = None
    gruneisen: float = 0.2
    fluence: float = 100.0

    def __post_init__(self) -> None:
        if self.so2 is None:
            self._amplitudes = np.array([[b.amplitude for b in self.balls]], dtype=np.float64)
            return
        from fpscan.physics import spectra

        so2 = np.asarray(self.so2, dtype=np.float64)
        thb = np.asarray(spectra.BLOOD_THB if self.thb is None else self.thb, dtype=np.float64)
        if so2.shape != (len(self.balls),) or thb.shape not in ((), so2.shape):
            raise ValueError(f"so2 (and thb, if not one value) need one value per ball "
                             f"({len(self.balls)}), got shapes {so2.shape}, {thb.shape}")
        thb = np.broadcast_to(thb, so2.shape)
        if not (self.gruneisen > 0 and self.fluence > 0):
            raise ValueError("gruneisen and fluence must be > 0")
        spectra.absorption(7.5e-7, so2, thb)  # checks so2 in [0, 1], thb >= 0
        self._so2, self._thb = so2, np.array(thb)
        self._amplitudes = np.zeros((1, len(self.balls)))

    def amplitudes(self, wavelengths: Sequence[float]) -> np.ndarray:
        """Ball amplitudes ``(n_wavelengths, n_balls)`` in Pa at ``wavelengths`` (m)."""
        if self.so2 is None:
            return np.repeat(self._amplitudes, max(1, len(wavelengths)), axis=0)
        from fpscan.physics import spectra

        mu_a = spectra.absorption(np.asarray(wavelengths, dtype=np.float64), self._so2,
                                  self._thb)
        return self.gruneisen * self.fluence * mu_a

    @property
    def peak(self) -> float:
        """Reference amplitude for the SNR, Pa: the largest ball amplitude (of the plan
        last prepared, at any of its wavelengths)."""
        return float(np.abs(self._amplitudes).max())

    def prepare(self, plan: DevicePlan) -> PressureFn:
        import dataclasses

        from fpscan.physics import ball_alines

        pos = plan.positions()
        dt, n_t, c = plan.dt, plan.n_t, self.c
        try:
            self._amplitudes = self.amplitudes(plan.wavelengths)
        except ValueError as exc:
            raise ValueError(f"spectral phantom: {exc}") from None
        balls_at = [[dataclasses.replace(b, amplitude=float(a)) for b, a in zip(self.balls, row)]
                    for row in self._amplitudes]

        def pressure(ks: np.ndarray, ws: np.ndarray | None = None) -> np.ndarray:
            ks = np.asarray(ks)
            ws = np.zeros(len(ks), np.int64) if ws is None else np.asarray(ws)
            out = np.zeros((len(ks), n_t))
            for w in np.unique(ws):
                m = ws == w
                out[m] = _ball_pressure(pos[ks[m]], balls_at[int(w)], dt, n_t, c, ball_alines)
            return out

        return pressure

    def describe(self) -> str:
        kind = "" if self.so2 is None else ", HbO2/Hb at sO2 " + ", ".join(
            f"{x:g}" for x in np.unique(self._so2))
        return f"balls ({len(self.balls)}{kind})"


def _ball_pressure(p: np.ndarray, balls: list, dt: float, n_t: int, c: float,
                   ball_alines: Callable[..., np.ndarray]) -> np.ndarray:
    """Sum of the balls' waves at positions ``p`` ``(n, 2)``: ``(n, n_t)`` Pa; each ball
    only where its wave is (samples of (r - R)/c … (r + R)/c)."""
    out = np.zeros((len(p), n_t))
    if not len(p):
        return out
    for b in balls:
        r = np.sqrt((p[:, 0] - b.x) ** 2 + (p[:, 1] - b.y) ** 2 + b.z ** 2)
        lo = max(0, int(np.floor((r.min() - b.radius) / c / dt)) - 2)
        hi = min(n_t, int(np.ceil((r.max() + b.radius) / c / dt)) + 3)
        if hi > lo:
            out[:, lo:hi] += ball_alines(p, [b], dt, hi - lo, c, t0=lo * dt)
    return out


@dataclass
class VolumeSource:
    """A p0 volume through the exact planar forward model.

    The HDF5 file holds ``p0`` ``(n_z, n_y, n_x)`` in Pa (row 0 at the sensor plane) with
    attributes ``dx_m`` (lateral voxel, m) and optionally ``dz_m`` (depth voxel, default
    ``dx_m``); the lateral grid is centred on the optical axis.
    Raises ``ValueError`` if the file lacks them, or is refused as hostile
    (``fpscan.driver.scanfile.open_checked``: external links or storage, declared sizes beyond what it stores).

    Attributes
    ----------
    path : Path
        The HDF5 file.
    c : float
        Sound speed, m/s (default ``fpscan.constants.C_DEFAULT``).
    """

    path: Path
    c: float = C_DEFAULT

    def __post_init__(self) -> None:
        from fpscan.driver.scanfile import open_checked

        self.path = Path(self.path)
        with open_checked(self.path, max_bytes=SOURCE_MAX_BYTES) as f:
            if "p0" not in f:
                raise ValueError(f"{self.path}: no 'p0' dataset")
            self.p0 = np.asarray(f["p0"], dtype=np.float64)
            attrs = dict(f.attrs) | dict(f["p0"].attrs)
        if self.p0.ndim != 3:
            raise ValueError(f"{self.path}: p0 must be (n_z, n_y, n_x), got {self.p0.shape}")
        if "dx_m" not in attrs:
            raise ValueError(f"{self.path}: attribute dx_m (lateral voxel size, m) missing")
        self.dx = float(attrs["dx_m"])
        self.dz = float(attrs.get("dz_m", self.dx))

    @property
    def peak(self) -> float:
        return float(np.abs(self.p0).max()) or 1.0

    def prepare(self, plan: DevicePlan) -> PressureFn:
        from fpscan.physics.forward import forward_points

        pos = plan.positions()
        chunk = 4096
        cache: dict[int, np.ndarray] = {}

        def pressure(ks: np.ndarray, ws: np.ndarray | None = None) -> np.ndarray:
            # the same A-line at every wavelength; one forward model evaluation per 4096 plan points (it costs a k-space
            # transform of the volume each time), cached
            out = np.empty((len(ks), plan.n_t))
            for c in np.unique(ks // chunk):
                if c not in cache:
                    cache.clear()
                    sel = slice(c * chunk, min((c + 1) * chunk, plan.n_points))
                    cache[c] = forward_points(self.p0, self.dx, self.dz, pos[sel], plan.dt,
                                              plan.n_t, self.c)
                m = ks // chunk == c
                out[m] = cache[c][ks[m] - c * chunk]
            return out

        return pressure

    def describe(self) -> str:
        return f"volume {self.path.name} {self.p0.shape}"


@dataclass
class ReplaySource:
    """Replay of a dense dataset in k-Wave layout.

    ``dataset`` ``(n_t, n_y, n_x)`` (k-Wave ``'tyz'``) with file attribute ``dt_s``; an
    optional ``sensor_yz_index`` ``(n_y, n_x, 2)`` must map (i_y, i_x) to itself (the
    dataset is a regular grid). A plan replays if its dt equals ``dt_s`` (relative 1e-6),
    its n_t ≤ the stored n_t, its pitch equals the stored lateral x spacing (if given:
    ``dz_m`` in a k-Wave-named file, else ``dx_m``; :mod:`fpscan.driver.kwave_layout`) and its lattice sits
    centred on the stored grid (both centred on the optical axis, so plan point (i_x, i_y)
    replays grid point (i_x + (N_x − n_x)/2, i_y + (N_y − n_y)/2)); otherwise ``prepare``
    raises ``ValueError`` with the reason; a file refused as hostile
    (``fpscan.driver.scanfile.open_checked``) raises ``ValueError`` at construction.

    Attributes
    ----------
    path : Path
        The HDF5 file.
    dataset : str
        The dataset's path in the file (default ``"sensor_data/clean"``).
    """

    path: Path
    dataset: str = "sensor_data/clean"

    def __post_init__(self) -> None:
        from fpscan.driver.scanfile import open_checked

        self.path = Path(self.path)
        with open_checked(self.path, max_bytes=SOURCE_MAX_BYTES) as f:
            if self.dataset not in f:
                raise ValueError(f"{self.path}: no dataset {self.dataset!r}")
            data = np.asarray(f[self.dataset])
            if data.dtype.kind != "f":
                data = data.astype(np.float64)
            if "dt_s" not in f.attrs:
                raise ValueError(f"{self.path}: file attribute dt_s missing")
            self.dt = float(f.attrs["dt_s"])
            # the lattice pitch is the lateral x spacing (k-Wave files call it dz_m)
            dx = lateral_spacings(dict(f[self.dataset].attrs), dict(f.attrs), 3)[0] if data.ndim == 3 else None
            self.dx = None if dx is None else float(dx)
            if "sensor_yz_index" in f:
                idx = np.asarray(f["sensor_yz_index"])
                if idx.shape != data.shape[1:] + (2,):
                    raise ValueError(f"{self.path}: sensor_yz_index shape {idx.shape} does "
                                     f"not match the data {data.shape}")
                grid = np.stack(np.meshgrid(np.arange(data.shape[1]), np.arange(data.shape[2]),
                                            indexing="ij"), axis=-1)
                if not np.array_equal(idx, grid):
                    raise ValueError(f"{self.path}: sensor_yz_index is not a regular grid")
        if data.ndim != 3:
            raise ValueError(f"{self.path}: {self.dataset} must be (t, y, x), got {data.shape}")
        # (n_y, n_x, n_t): one contiguous A-line per lattice point, stored in the file's
        # own float precision
        self.alines = np.ascontiguousarray(np.moveaxis(data, 0, -1))

    @property
    def peak(self) -> float:
        return float(np.abs(self.alines).max()) or 1.0

    def prepare(self, plan: DevicePlan) -> PressureFn:
        n_y, n_x, n_t = self.alines.shape
        if abs(plan.dt - self.dt) > 1e-6 * self.dt:
            raise ValueError(f"plan dt {plan.dt:g} s differs from the replay's {self.dt:g} s")
        if plan.n_t > n_t:
            raise ValueError(f"plan n_t {plan.n_t} exceeds the replay's {n_t} samples")
        if self.dx is not None and abs(plan.pitch - self.dx) > 1e-6 * self.dx:
            raise ValueError(f"plan pitch {plan.pitch:g} m differs from the replay's "
                             f"{self.dx:g} m")
        off_x, off_y = (n_x - plan.n_x) / 2, (n_y - plan.n_y) / 2
        if off_x < 0 or off_y < 0 or off_x % 1 or off_y % 1:
            raise ValueError(f"plan lattice {plan.n_x}x{plan.n_y} does not sit centred on the "
                             f"replay grid {n_x}x{n_y}")
        idx = plan.indices.astype(np.intp) + np.array([int(off_x), int(off_y)])

        def pressure(ks: np.ndarray, ws: np.ndarray | None = None) -> np.ndarray:  # the same A-line at every wavelength
            return self.alines[idx[ks, 1], idx[ks, 0], :plan.n_t].astype(np.float64)

        return pressure

    def describe(self) -> str:
        return f"replay {self.path.name}:{self.dataset}"
