"""Scan plans on the scanner side: read the plan JSON and build the device plan image.

The plan JSON (``fpscan-plan/1``, docs/architecture.md) is read with plain :mod:`json`;
``driver`` never imports ``service``. Point index k is the k-th entry of ``points``.

The *plan image* is what the host uploads to the device (docs/protocol.md §4), little-endian:

====== ================ ====== =================================================
offset field            type   meaning
====== ================ ====== =================================================
0      magic            4 B    ``b"FPPL"``
4      image_version    u16    1
6      reserved         u16    0
8      plan_id          32 B   SHA-256 digest of the plan (its JSON ``id``), raw
40     n_x, n_y         2×u32  lattice size
48     pitch_m          f64    lattice pitch, m
56     n_t              u32    samples per A-line
60     averages         u32    pulses averaged per point
64     dt_s             f64    sample interval, s
72     prf_hz           f64    requested pulse repetition frequency, Hz (0 = device's)
80     wavelength_m     f64    excitation wavelength, m
88     sound_speed      f64    m/s (for the record)
96     n_points         u32    number of points
100    indices          n_points × (u16 i_x, u16 i_y), in scan order
====== ================ ====== =================================================

Lattice point (i_x, i_y) lies at ``x = (i_x - (n_x - 1)/2)·pitch``, ``y`` likewise.
"""
from __future__ import annotations

import hashlib
import json
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

IMAGE_HEADER = struct.Struct("<4sHH32sIIdIIddddI")
MAGIC = b"FPPL"


def canonical_json(obj) -> bytes:
    """Canonical JSON of docs/architecture.md (sorted keys, no spaces, floats as repr)."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()


def load_plan(source) -> dict:
    """Read and check a plan: a path to plan JSON, a JSON string, or an already-parsed dict.

    Returns the plan dict. Raises ``ValueError`` naming the first problem (wrong format,
    missing keys, inconsistent point arrays, indices outside the lattice, bad settings).
    """
    if isinstance(source, dict):
        plan = source
    else:
        text = Path(source).read_text() if not str(source).lstrip().startswith("{") else source
        try:
            plan = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"plan is not valid JSON: {exc}") from None
    if not isinstance(plan, dict) or plan.get("format") != "fpscan-plan/1":
        raise ValueError("not an fpscan-plan/1 plan (missing or wrong 'format')")
    for key in ("id", "lattice", "points", "acquisition"):
        if key not in plan:
            raise ValueError(f"plan has no '{key}'")
    lat, acq, pts = plan["lattice"], plan["acquisition"], plan["points"]
    try:
        n_x, n_y, pitch = int(lat["n_x"]), int(lat["n_y"]), float(lat["pitch"])
        n_t, dt = int(acq["n_t"]), float(acq["dt"])
        idx = np.asarray(pts["indices"], dtype=np.int64)
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"plan field missing or malformed: {exc}") from None
    if n_x < 1 or n_y < 1 or not pitch > 0:
        raise ValueError(f"bad lattice {n_x}×{n_y} at pitch {pitch}")
    if n_t < 1 or not dt > 0:
        raise ValueError(f"bad acquisition settings n_t={n_t}, dt={dt}")
    if idx.ndim != 2 or idx.shape[1] != 2 or idx.shape[0] < 1:
        raise ValueError(f"points.indices must be (n_points, 2), got shape {idx.shape}")
    if (idx < 0).any() or (idx[:, 0] >= n_x).any() or (idx[:, 1] >= n_y).any():
        raise ValueError("points.indices has points outside the lattice")
    if len(np.unique(idx[:, 0] * n_y + idx[:, 1])) != len(idx):
        raise ValueError("points.indices has duplicate points")
    for key in ("positions", "weights"):
        if key in pts and len(pts[key]) != len(idx):
            raise ValueError(f"points.{key} has {len(pts[key])} entries, indices {len(idx)}")
    pid = str(plan["id"])
    if len(pid) != 64 or any(ch not in "0123456789abcdef" for ch in pid):
        raise ValueError("plan id must be a lowercase sha256 hex digest")
    return plan


def plan_id_of(plan: dict) -> str:
    """SHA-256 hex of the canonical JSON of everything but ``id`` (the plan's content hash)."""
    return hashlib.sha256(canonical_json({k: v for k, v in plan.items() if k != "id"})).hexdigest()


@dataclass(frozen=True)
class DevicePlan:
    """A parsed plan image. ``indices`` is uint16 ``(n_points, 2)`` as (i_x, i_y)."""

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

    @property
    def n_points(self) -> int:
        return len(self.indices)

    def positions(self) -> np.ndarray:
        """Sensor positions ``(n_points, 2)`` as (x, y) in m, lattice centred on the axis."""
        i = self.indices.astype(np.float64)
        return np.stack([(i[:, 0] - (self.n_x - 1) / 2) * self.pitch,
                         (i[:, 1] - (self.n_y - 1) / 2) * self.pitch], axis=1)


def plan_image(plan: dict) -> bytes:
    """Build the binary plan image the host uploads (layout in the module docstring).

    Raises ``ValueError`` if the plan does not fit the image (indices ≥ 65536, …).
    """
    plan = load_plan(plan)
    lat, acq = plan["lattice"], plan["acquisition"]
    idx = np.asarray(plan["points"]["indices"], dtype=np.int64)
    if idx.max() > 0xFFFF:
        raise ValueError("lattice indices above 65535 do not fit the plan image")
    waves = acq.get("wavelengths") or [0.0]
    head = IMAGE_HEADER.pack(MAGIC, 1, 0, bytes.fromhex(plan["id"]), int(lat["n_x"]),
                             int(lat["n_y"]), float(lat["pitch"]), int(acq["n_t"]),
                             int(acq.get("averages", 1)), float(acq["dt"]),
                             float(acq.get("prf", 0.0) or 0.0), float(waves[0]),
                             float(acq.get("sound_speed", 1500.0)), len(idx))
    return head + idx.astype("<u2").tobytes()


def parse_plan_image(image: bytes) -> DevicePlan:
    """Parse a plan image (device side). Raises ``ValueError`` with the reason."""
    if len(image) < IMAGE_HEADER.size:
        raise ValueError(f"plan image of {len(image)} bytes is shorter than its header")
    (magic, version, _, pid, n_x, n_y, pitch, n_t, averages, dt, prf, wavelength, c,
     n_points) = IMAGE_HEADER.unpack_from(image)
    if magic != MAGIC or version != 1:
        raise ValueError("not a version-1 plan image")
    if len(image) != IMAGE_HEADER.size + 4 * n_points:
        raise ValueError(f"plan image length {len(image)} disagrees with {n_points} points")
    idx = np.frombuffer(image, dtype="<u2", offset=IMAGE_HEADER.size).reshape(n_points, 2)
    if n_points < 1 or n_t < 1 or not dt > 0 or not pitch > 0 or averages < 1:
        raise ValueError("plan image has empty or non-positive settings")
    if n_points and ((idx[:, 0] >= n_x).any() or (idx[:, 1] >= n_y).any()):
        raise ValueError("plan image has points outside its lattice")
    return DevicePlan(pid.hex(), n_x, n_y, pitch, n_t, averages, dt, prf, wavelength, c,
                      idx.astype(np.uint16))
