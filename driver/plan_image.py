"""The plan image: the binary form of a plan that the host uploads to the device (docs/protocol.md
§4), built from the plan JSON (:mod:`fpscan.driver.plan`, the contract) and parsed on the device side.

Little-endian:

====== ================ ====== =================================================
offset field            type   meaning
====== ================ ====== =================================================
0      magic            4 B    ``b"FPPL"``
4      image_version    u16    2 (1: the single-wavelength image, which ends at 100)
6      reserved         u16    0
8      plan_id          32 B   SHA-256 digest of the plan (its JSON ``id``), raw
40     n_x, n_y         2×u32  lattice size
48     pitch_m          f64    lattice pitch, m
56     n_t              u32    samples per A-line
60     averages         u32    pulses averaged per point
64     dt_s             f64    sample interval, s
72     prf_hz           f64    requested pulse repetition frequency, Hz (0 = device's)
80     wavelength_m     f64    first excitation wavelength, m
88     sound_speed      f64    m/s (for the record)
96     n_points         u32    number of points
100    n_wavelengths    u16    excitation wavelengths, 1 … ``MAX_WAVELENGTHS``
102    order            u8     0 = per point, 1 = per pass (``WAVELENGTH_ORDERS``)
103    reserved         u8     0
104    wavelengths_m    n_wavelengths × f64, in acquisition order
…      indices          n_points × (u16 i_x, u16 i_y), in scan order
====== ================ ====== =================================================

A-line index s of the acquisition is point k at wavelength w in the image's ``order``
(:func:`fpscan.driver.plan.aline_order`, docs/protocol.md §4.1).
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from fpscan.constants import C_DEFAULT
from fpscan.driver.plan import (
    MAX_WAVELENGTHS,
    WAVELENGTH_ORDERS,
    aline_order,
    lattice_positions,
    load_plan,
    wavelength_order,
)

__all__ = ["IMAGE_HEADER", "IMAGE_SPECTRAL", "MAGIC", "IMAGE_VERSION", "DevicePlan", "plan_image",
           "image_size_limit", "parse_plan_image"]

IMAGE_HEADER = struct.Struct("<4sHH32sIIdIIddddI")
#: what image version 2 adds after IMAGE_HEADER: n_wavelengths, order, reserved
IMAGE_SPECTRAL = struct.Struct("<HBB")
MAGIC = b"FPPL"
IMAGE_VERSION = 2


@dataclass(frozen=True)
class DevicePlan:
    """A parsed plan image. ``indices`` is uint16 ``(n_points, 2)`` as (i_x, i_y);
    ``wavelengths`` (m) in plan order; ``order`` one of ``WAVELENGTH_ORDERS``.

    Attributes
    ----------
    plan_id : str
        The plan's id, 64 hex digits.
    n_x, n_y : int
        Lattice points along x and y.
    pitch : float
        Lattice pitch, m.
    n_t : int
        Samples per A-line.
    averages : int
        Pulses averaged per A-line.
    dt : float
        Sample interval, s.
    prf : float
        Pulse repetition frequency, Hz (0: as fast as possible).
    wavelength : float
        The first excitation wavelength, m.
    sound_speed : float
        m/s.
    indices : ndarray ``(n_points, 2)`` uint16
        Lattice indices (i_x, i_y) in acquisition order.
    wavelengths : tuple of float
        Excitation wavelengths, m, in plan order.
    order : str
        The wavelength order, ``"per_point"`` or ``"per_pass"``.
    """

    plan_id: str
    n_x: int
    n_y: int
    pitch: float
    n_t: int
    averages: int
    dt: float
    prf: float
    wavelength: float
    sound_speed: float
    indices: np.ndarray
    wavelengths: tuple[float, ...] = ()
    order: str = "per_point"

    @property
    def n_points(self) -> int:
        return len(self.indices)

    @property
    def n_wavelengths(self) -> int:
        return max(1, len(self.wavelengths))

    @property
    def n_alines(self) -> int:
        """A-lines of one complete acquisition: points × wavelengths."""
        return self.n_points * self.n_wavelengths

    def aline_order(self, s: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(k, w)`` of A-line indices ``s`` (default all; see :func:`aline_order`)."""
        return aline_order(self.n_points, self.n_wavelengths, self.order, s)

    def positions(self) -> np.ndarray:
        """Sensor positions ``(n_points, 2)`` as (x, y) in m, lattice centred on the axis."""
        return lattice_positions(self.indices, self.n_x, self.n_y, self.pitch)


def plan_image(plan: dict) -> bytes:
    """Build the binary plan image (version 2) the host uploads (layout in the module
    docstring).

    Raises ``ValueError`` if the plan is invalid or does not fit the image (indices ≥ 65536).

    Parameters
    ----------
    plan : dict or str or Path
        The plan (anything :func:`load_plan` reads).

    Returns
    -------
    bytes
        The image: header, wavelength table, then the indices as little-endian uint16 pairs.

    Raises
    ------
    ValueError
        An invalid plan, or lattice indices above 65535.
    """
    plan = load_plan(plan)
    lat, acq = plan["lattice"], plan["acquisition"]
    idx = np.asarray(plan["points"]["indices"], dtype=np.int64)
    if idx.max() > 0xFFFF:
        raise ValueError("lattice indices above 65535 do not fit the plan image")
    waves = [float(w) for w in acq["wavelengths"]]
    head = IMAGE_HEADER.pack(MAGIC, IMAGE_VERSION, 0, bytes.fromhex(plan["id"]),
                             int(lat["n_x"]), int(lat["n_y"]), float(lat["pitch"]),
                             int(acq["n_t"]), int(acq.get("averages", 1)), float(acq["dt"]),
                             float(acq.get("prf", 0.0) or 0.0), waves[0],
                             float(acq.get("sound_speed", C_DEFAULT)), len(idx))
    spectral = IMAGE_SPECTRAL.pack(len(waves), WAVELENGTH_ORDERS.index(wavelength_order(acq)), 0)
    return (head + spectral + np.asarray(waves, dtype="<f8").tobytes()
            + idx.astype("<u2").tobytes())


def image_size_limit(max_points: int) -> int:
    """Largest plan image a device with ``max_points`` accepts, bytes.

    Parameters
    ----------
    max_points : int
        The most points the device takes.

    Returns
    -------
    int
        The image size with ``MAX_WAVELENGTHS`` wavelengths and ``max_points`` points, bytes.
    """
    return IMAGE_HEADER.size + IMAGE_SPECTRAL.size + 8 * MAX_WAVELENGTHS + 4 * max_points


def parse_plan_image(image: bytes) -> DevicePlan:
    """Parse a plan image, version 2 or 1 (device side). Raises ``ValueError`` with the
    reason.

    Parameters
    ----------
    image : bytes
        The uploaded image (:func:`plan_image`).

    Returns
    -------
    DevicePlan
        Its settings, indices and wavelengths.

    Raises
    ------
    ValueError
        A short or truncated image, a wrong magic or version, a bad wavelength table, a length
        that disagrees with the point count, empty or non-positive settings, or points
        outside the lattice.
    """
    if len(image) < IMAGE_HEADER.size:
        raise ValueError(f"plan image of {len(image)} bytes is shorter than its header")
    (magic, version, _, pid, n_x, n_y, pitch, n_t, averages, dt, prf, wavelength, c,
     n_points) = IMAGE_HEADER.unpack_from(image)
    if magic != MAGIC or version not in (1, 2):
        raise ValueError("not a version-1 or version-2 plan image")
    start, order = IMAGE_HEADER.size, WAVELENGTH_ORDERS[0]
    waves: tuple[float, ...] = (wavelength,)
    if version == 2:
        if len(image) < start + IMAGE_SPECTRAL.size:
            raise ValueError("plan image ends inside its wavelength table")
        n_w, order_byte, _ = IMAGE_SPECTRAL.unpack_from(image, start)
        start += IMAGE_SPECTRAL.size
        if not 1 <= n_w <= MAX_WAVELENGTHS or order_byte >= len(WAVELENGTH_ORDERS):
            raise ValueError(f"plan image has {n_w} wavelengths (1..{MAX_WAVELENGTHS}) or "
                             f"an unknown order {order_byte}")
        if len(image) < start + 8 * n_w:
            raise ValueError("plan image ends inside its wavelength table")
        waves = tuple(float(w) for w in np.frombuffer(image, "<f8", n_w, start))
        order = WAVELENGTH_ORDERS[order_byte]
        start += 8 * n_w
        if not all(np.isfinite(waves)) or min(waves) <= 0 or len(set(waves)) != n_w:
            raise ValueError("plan image wavelengths must be finite, > 0 and distinct")
    if len(image) != start + 4 * n_points:
        raise ValueError(f"plan image length {len(image)} disagrees with {n_points} points")
    idx = np.frombuffer(image, dtype="<u2", offset=start).reshape(n_points, 2)
    if n_points < 1 or n_t < 1 or not dt > 0 or not pitch > 0 or averages < 1:
        raise ValueError("plan image has empty or non-positive settings")
    if n_points and ((idx[:, 0] >= n_x).any() or (idx[:, 1] >= n_y).any()):
        raise ValueError("plan image has points outside its lattice")
    return DevicePlan(pid.hex(), n_x, n_y, pitch, n_t, averages, dt, prf, wavelength, c,
                      idx.astype(np.uint16), waves, order)
