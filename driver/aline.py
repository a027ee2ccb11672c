"""The A-line frame payload (docs/protocol.md §5): a fixed 88-byte header and int16 samples.

Layout (protocol version 2), little-endian, ``struct`` format ``<IIIIQdddddffIId``:

=========  ====================  ====  ==============================================
offset     field                 type  meaning
=========  ====================  ====  ==============================================
0          run_id                u32   run the A-line belongs to (SCAN:STAR reply)
4          boot_id               u32   device boot id (changes on every reset)
8          point_index           u32   k: the k-th point of the uploaded plan
12         n_t                   u32   number of samples that follow
16         pulse_number          u64   excitation pulses fired since boot (last one used)
24         timestamp_s           f64   s since boot at the (last) excitation pulse
32         bias_wavelength_m     f64   interrogation (bias) wavelength, m
40         dt_s                  f64   sample interval, s
48         scale                 f64   signal per count: value = sample·scale + offset
56         offset                f64   signal offset (same unit as scale)
64         dc_level              f32   photodiode DC level at the bias point, V
68         pulse_energy_j        f32   excitation pulse energy, J
72         wavelength_index      u32   w: index into the plan's excitation wavelengths
76         reserved              u32   0
80         excitation_wavelength f64   excitation wavelength of this A-line, m
88         samples               i16[n_t]
=========  ====================  ====  ==============================================

"signal" is the FP sensor's AC output, pressure × sensitivity × DC level in Pa·V; the
DC-normalised pressure is ``(sample·scale + offset) / dc_level`` in Pa.

Each field has a documented range (docs/protocol.md §5, :data:`FIELD_RANGES`): every float
finite; ``dc_level``, ``scale`` and ``dt`` > 0; ``timestamp``, the wavelengths and the pulse
energy ≥ 0; samples in −32 767 … 32 767. :func:`check_aline` checks them: an A-line outside
them is the device's fault, whatever its CRC says.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

__all__ = ["ALINE_HEADER", "META_KEYS", "FIELD_RANGES", "SAMPLE_MIN", "ALine", "pack_aline", "unpack_aline",
           "check_aline", "quantise"]

ALINE_HEADER = struct.Struct("<IIIIQdddddffIId")
META_KEYS = ("run_id", "boot_id", "point_index", "pulse_number", "timestamp_s",
             "bias_wavelength_m", "dc_level", "pulse_energy_j", "dt_s", "scale", "offset",
             "wavelength_index", "excitation_wavelength_m")
#: the float fields' documented ranges (docs/protocol.md §5): attribute -> (wire name, lowest
#: value, whether the lowest is allowed, unit); every one must be finite as well
FIELD_RANGES = {
    "timestamp_s": ("timestamp", 0.0, True, "s"),
    "bias_wavelength_m": ("bias_wavelength", 0.0, True, "m"),
    "dt_s": ("dt", 0.0, False, "s"),
    "scale": ("scale", 0.0, False, "signal per count"),
    "offset": ("offset", -math.inf, False, "signal"),
    "dc_level": ("dc_level", 0.0, False, "V"),
    "pulse_energy_j": ("pulse_energy", 0.0, True, "J"),
    "excitation_wavelength_m": ("excitation_wavelength", 0.0, True, "m"),
}
#: the lowest sample value a device sends (−32 768 is not used: the int16 range is symmetric)
SAMPLE_MIN = -32767


@dataclass(slots=True)
class ALine:
    """One received or generated A-line; ``samples`` is int16 of shape ``(n_t,)``.

    Attributes
    ----------
    run_id : int
        The run the A-line belongs to (``SCAN:STAR`` reply).
    boot_id : int
        The device's boot id (changes on every reset).
    point_index : int
        k, the plan point.
    pulse_number : int
        Excitation pulses fired since boot, counting this point's (last) pulse.
    timestamp_s : float
        Time of that pulse, s since boot.
    bias_wavelength_m : float
        Interrogation (bias) wavelength, m.
    dt_s : float
        Sample interval, s.
    scale : float
        Signal per count: signal = sample·scale + offset.
    offset : float
        Signal offset (same unit as ``scale``).
    dc_level : float
        Photodiode DC level at the bias point, V.
    pulse_energy_j : float
        Excitation pulse energy, J.
    samples : ndarray ``(n_t,)`` int16
        The samples, sample n at t = n·dt after the excitation pulse.
    wavelength_index : int
        w, index into the plan's excitation wavelengths (default 0).
    excitation_wavelength_m : float
        Excitation wavelength of this A-line, m (0 = not reported).
    """

    run_id: int
    boot_id: int
    point_index: int
    pulse_number: int
    timestamp_s: float
    bias_wavelength_m: float
    dt_s: float
    scale: float
    offset: float
    dc_level: float
    pulse_energy_j: float
    samples: np.ndarray
    wavelength_index: int = 0
    excitation_wavelength_m: float = 0.0

    def meta(self) -> dict:
        """The metadata dict of the scan file API (docs/architecture.md)."""
        return {k: getattr(self, k) for k in META_KEYS}


def pack_aline(run_id: int, boot_id: int, point_index: int, pulse_number: int,
               timestamp_s: float, bias_wavelength_m: float, dt_s: float, scale: float,
               offset: float, dc_level: float, pulse_energy_j: float,
               samples: np.ndarray, wavelength_index: int = 0,
               excitation_wavelength_m: float = 0.0) -> bytes:
    """Serialise one A-line payload; ``samples`` is converted to little-endian int16.

    Parameters
    ----------
    run_id, boot_id, point_index, pulse_number : int
        As :class:`ALine`.
    timestamp_s, bias_wavelength_m, dt_s, scale, offset, dc_level, pulse_energy_j : float
        As :class:`ALine` (s, m, s, signal per count, signal, V, J).
    samples : ndarray ``(n_t,)``
        The samples (converted to int16).
    wavelength_index : int, optional
        w (default 0).
    excitation_wavelength_m : float, optional
        m (default 0: not reported).

    Returns
    -------
    bytes
        The payload: the 88-byte header (:data:`ALINE_HEADER`) and ``2·n_t`` sample bytes.
    """
    s = np.ascontiguousarray(samples, dtype="<i2")
    return ALINE_HEADER.pack(run_id, boot_id, point_index, s.size, pulse_number, timestamp_s,
                             bias_wavelength_m, dt_s, scale, offset, dc_level,
                             pulse_energy_j, wavelength_index, 0,
                             excitation_wavelength_m) + s.tobytes()


def unpack_aline(payload: bytes) -> ALine:
    """Parse an A-line payload. Raises ``ValueError`` if its length disagrees with n_t.

    Parameters
    ----------
    payload : bytes
        An A-line frame's payload (module docstring).

    Returns
    -------
    ALine
        The A-line, its samples an int16 copy.

    Raises
    ------
    ValueError
        The payload is shorter than its header, or its sample bytes are not ``2·n_t``.
    """
    if len(payload) < ALINE_HEADER.size:
        raise ValueError(f"A-line payload of {len(payload)} bytes is shorter than its header")
    (run_id, boot_id, k, n_t, pulse, ts, bias, dt, scale, offset, dc,
     energy, w, _, wavelength) = ALINE_HEADER.unpack_from(payload)
    if len(payload) != ALINE_HEADER.size + 2 * n_t:
        raise ValueError(f"A-line payload holds {len(payload) - ALINE_HEADER.size} sample "
                         f"bytes, header says n_t = {n_t}")
    samples = np.frombuffer(payload, dtype="<i2", offset=ALINE_HEADER.size).astype(np.int16)
    return ALine(run_id, boot_id, k, pulse, ts, bias, dt, scale, offset, dc, energy, samples,
                 w, wavelength)


def check_aline(a: ALine) -> None:
    """Check that every field of a received A-line lies in its documented range
    (docs/protocol.md §5; :data:`FIELD_RANGES`, :data:`SAMPLE_MIN`).

    The plan-dependent fields (run, boot, point, wavelength, ``n_t``) are the host's to
    check against its run and plan; this checks what holds for every A-line.

    Parameters
    ----------
    a : ALine
        The A-line as :func:`unpack_aline` returned it.

    Raises
    ------
    ValueError
        The first field out of its range, named as on the wire, with its value and range.
    """
    for attr, (name, low, closed, unit) in FIELD_RANGES.items():
        v = getattr(a, attr)
        if not (math.isfinite(v) and (v >= low if closed else v > low)):
            want = "finite" if low == -math.inf else f"finite and {'>=' if closed else '>'} {low:g}"
            raise ValueError(f"{name} = {v!r} {unit} is out of its range ({want})")
    if a.samples.size and int(a.samples.min()) < SAMPLE_MIN:
        raise ValueError(f"a sample of {int(a.samples.min())} is out of the range "
                         f"{SAMPLE_MIN} … {-SAMPLE_MIN}")


def quantise(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The scanner's int16 digitisation of A-lines (docs/protocol.md §5): per A-line
    ``scale = max|v|/32767`` (1 for an all-zero A-line), ``offset = 0``,
    ``sample = round(v/scale)``; the simulated scanner sends exactly these.

    Parameters
    ----------
    values : ndarray, shape ``(n, n_t)``
        The signal (Pa·V, or Pa), float64.

    Returns
    -------
    samples : ndarray of int16, shape ``(n, n_t)``
    scale : ndarray of float64, shape ``(n,)``
        Signal per count: ``value = sample·scale``.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.driver.aline import quantise
    >>> samples, scale = quantise(np.array([[0.0, 0.5, -1.0], [0.0, 0.0, 0.0]]))
    >>> samples.tolist(), scale.tolist()
    ([[0, 16384, -32767], [0, 0, 0]], [3.051850947599719e-05, 1.0])
    """
    v = np.asarray(values, dtype=np.float64)
    peak = np.abs(v).max(axis=1)
    scale = np.where(peak > 0, peak / 32767.0, 1.0)
    samples = np.clip(np.rint(v / scale[:, None]), -32767, 32767).astype(np.int16)
    return samples, scale
