"""Scan plans on the scanner side: read and check the plan JSON, the plan contract.

The plan JSON (``fpscan-plan/1``, docs/architecture.md) is read with plain :mod:`json`;
``driver`` never imports ``service``. Point index k is the k-th entry of ``points``. The
binary plan image the host uploads to the device (docs/protocol.md §4) is built and parsed
by :mod:`fpscan.driver.plan_image`.

Acquisition order (docs/protocol.md §4.1): the device acquires ``n_points·n_wavelengths``
A-lines; A-line index s is point k at wavelength w with ``s = k·n_wavelengths + w``
(``per_point``: the laser is tuned through all wavelengths at each point) or
``s = w·n_points + k`` (``per_pass``: a full pass over the points at each wavelength).

Lattice point (i_x, i_y) lies at ``x = (i_x - (n_x - 1)/2)·pitch``, ``y`` likewise.
"""
from __future__ import annotations

import hashlib
import json
import math
import numbers
from pathlib import Path
from typing import Any, Final

import numpy as np

from fpscan.constants import C_LIMITS
from fpscan.physics.axes import centred_positions

__all__ = [
    "MAX_WAVELENGTHS", "WAVELENGTH_ORDERS",
    "PLAN_FORMAT", "WAVELENGTH_RANGE", "MAX_LATTICE_POINTS", "N_T_RANGE", "MIN_N_T", "MAX_N_T", "MAX_DT",
    "MAX_AVERAGES", "MAX_PRF", "canonical_json", "plan_id_of", "check_wavelengths", "check_acquisition",
    "wavelength_order", "aline_order", "aline_index", "MAX_WEIGHT_AREAS", "check_plan", "lattice_positions",
    "load_plan",
]

#: most excitation wavelengths one plan may hold (the plan image's table holds as many)
MAX_WAVELENGTHS = 16
#: values of ``acquisition.wavelength_order`` (index = the plan image's ``order`` byte)
WAVELENGTH_ORDERS = ("per_point", "per_pass")

#: The plan JSON format this module reads and checks.
PLAN_FORMAT: Final = "fpscan-plan/1"
#: Excitation wavelengths a plan may ask for, m (inclusive): 400 nm to 2000 nm.
WAVELENGTH_RANGE = (400e-9, 2000e-9)
#: Largest lattice (points) a plan may declare: bounds what a plan (or a scan file's copy
#: of one) can make a reader allocate (a 4096² lattice).
MAX_LATTICE_POINTS = 1 << 24
#: The acquisition limits of the plan contract (``check_acquisition``), the one set: the
#: scanner side, the scan file, ``fpscan.service.plans.Acquisition`` and ``POST /api/plans`` (its
#: OpenAPI schema states these numbers) all apply them. Samples per A-line (inclusive):
N_T_RANGE = (8, 65536)
MIN_N_T, MAX_N_T = N_T_RANGE
#: longest sample interval, s (inclusive; > 0)
MAX_DT = 1e-3
#: most pulses averaged per point and wavelength (>= 1)
MAX_AVERAGES = 4096
#: highest pulse repetition frequency, Hz (inclusive; 0 = as fast as the scanner can)
MAX_PRF = 1e5


def canonical_json(obj: Any) -> str:
    """Canonical JSON text of docs/architecture.md.

    ``json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False)``; floats as
    Python's ``repr``. The one implementation of the plan contract's canonical form (the
    service, the scan file and the HTTP layer all call this).

    Parameters
    ----------
    obj : JSON-serialisable object
        Usually a plan as a dict.

    Returns
    -------
    str
        Keys sorted, no whitespace.

    Raises
    ------
    ValueError
        NaN or infinities (not JSON) and values JSON cannot hold (``TypeError`` turned into
        ``ValueError``).

    Examples
    --------
    >>> from fpscan.driver.plan import canonical_json
    >>> canonical_json({"b": 1, "a": [1.0, 2]})
    '{"a":[1.0,2],"b":1}'
    >>> canonical_json({"dt": float("nan")})
    Traceback (most recent call last):
    ...
    ValueError: ...
    """
    try:
        return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False)
    except TypeError as exc:
        raise ValueError(f"not JSON-serialisable: {exc}") from None
    except ValueError as exc:
        raise ValueError(f"not JSON-serialisable (NaN or infinity?): {exc}") from None


def plan_id_of(plan: dict) -> str:
    """The plan's id: SHA-256 hex digest (FIPS 180-4) of the UTF-8 canonical JSON
    (``canonical_json``) of everything but ``id``. Raises ``ValueError`` if the plan
    holds values JSON cannot represent (NaN, infinity, objects).

    Parameters
    ----------
    plan : dict
        The plan (its ``id``, if any, is left out of the hash).

    Returns
    -------
    str
        64 lowercase hex digits.

    Raises
    ------
    ValueError
        ``plan`` is not a dict, or holds values JSON cannot represent.
    """
    if not isinstance(plan, dict):
        raise ValueError(f"a plan must be a JSON object, got {type(plan).__name__}")
    body = {k: v for k, v in plan.items() if k != "id"}
    return hashlib.sha256(canonical_json(body).encode("utf-8")).hexdigest()


def _integer(name: str, value: Any, minimum: int, maximum: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(f"plan {name} must be an integer, got {value!r}")
    value = int(value)
    if value < minimum:
        raise ValueError(f"plan {name} must be >= {minimum}, got {value!r}")
    if maximum is not None and value > maximum:
        raise ValueError(f"plan {name} must be <= {maximum}, got {value!r}")
    return int(value)


def _number(name: str, value: Any, *, positive: bool = True, unit: str = "",
            maximum: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"plan {name} must be a number{(' in ' + unit) if unit else ''}, got {value!r}")
    v = float(value)
    if not math.isfinite(v) or (v <= 0 if positive else v < 0):
        raise ValueError(f"plan {name} must be finite and {'>' if positive else '>='} 0"
                         f"{(' ' + unit) if unit else ''}, got {value!r}")
    if maximum is not None and v > maximum:
        raise ValueError(f"plan {name} must be <= {maximum:g}{(' ' + unit) if unit else ''}, got {value!r}")
    return v


def check_wavelengths(wavelengths: Any) -> list[float]:
    """Excitation wavelengths (m) as a list of floats: non-empty, each within
    ``WAVELENGTH_RANGE`` (400 nm to 2000 nm, the tunable OPO range a FP scanner's
    excitation laser covers), no duplicates. Raises ``ValueError`` naming the fault.

    Parameters
    ----------
    wavelengths : list or tuple of float
        Excitation wavelengths, m.

    Returns
    -------
    list of float
        The wavelengths, m, in the given order.

    Raises
    ------
    ValueError
        Not a list or tuple, empty, a value that is not a finite number > 0, or a repeat.
    ImplausibleValue
        A wavelength outside ``WAVELENGTH_RANGE``, with the likely unit mistake
        (:class:`fpscan.driver.units.ImplausibleValue`, a ``ValueError``).
    """
    if isinstance(wavelengths, (str, bytes)) or not isinstance(wavelengths, (list, tuple)):
        raise ValueError(f"wavelengths must be a list of wavelengths in m, got {wavelengths!r}")
    if len(wavelengths) == 0:
        raise ValueError("wavelengths must hold at least one wavelength")
    lo, hi = WAVELENGTH_RANGE
    out = []
    for w in wavelengths:
        v = _number("wavelength", w, unit="m")
        if not lo <= v <= hi:
            from fpscan.driver.units import ImplausibleValue, suggest_unit

            raise ImplausibleValue(f"wavelengths must lie within {lo * 1e9:g} nm to {hi * 1e9:g} nm, "
                                   f"got {v:g} m ({v * 1e9:g} nm){suggest_unit(v, lo, hi, 'm')} "
                                   "Numbers without a unit are m; write the unit, e.g. 750nm.")
        out.append(v)
    if len(set(out)) != len(out):
        raise ValueError(f"wavelengths must not repeat, got {out!r}")
    return out


def check_acquisition(acq: Any) -> dict:
    """Check a plan's ``acquisition`` object (docs/architecture.md "Plan JSON") against the
    contract's limits (the module constants): ``n_t`` (int, ``N_T_RANGE``: 8 to 65536),
    ``dt`` (s, > 0, at most ``MAX_DT`` = 1 ms), optional ``averages`` (int, 1 to
    ``MAX_AVERAGES`` = 4096), ``wavelengths`` (m, see ``check_wavelengths``; at most
    ``MAX_WAVELENGTHS`` = 16), ``prf`` (Hz, 0 to ``MAX_PRF`` = 100 kHz; 0 = as fast as
    possible), ``sound_speed`` (m/s, ``fpscan.constants.C_LIMITS``: above 100, at most 10 000),
    ``wavelength_order`` (``wavelength_order``). The service's ``Acquisition`` model calls
    this, so the library, the API and the scanner side accept the same plans.

    Returns it; raises ``ValueError`` naming the first fault.

    Parameters
    ----------
    acq : dict
        The plan's ``acquisition`` object.

    Returns
    -------
    dict
        ``acq`` itself, unchanged.

    Raises
    ------
    ValueError
        Naming the first fault: not an object, ``n_t`` or ``dt`` missing, a value of the
        wrong type or outside its limits, too many wavelengths, an unknown
        ``wavelength_order``.
    """
    if not isinstance(acq, dict):
        raise ValueError("plan 'acquisition' must be an object")
    if "n_t" not in acq or "dt" not in acq:
        raise ValueError("plan acquisition needs 'n_t' and 'dt'")
    _integer("acquisition.n_t", acq["n_t"], MIN_N_T, MAX_N_T)
    _number("acquisition.dt", acq["dt"], unit="s", maximum=MAX_DT)
    if "averages" in acq:
        _integer("acquisition.averages", acq["averages"], 1, MAX_AVERAGES)
    if "prf" in acq and acq["prf"] is not None:
        _number("acquisition.prf", acq["prf"], positive=False, unit="Hz", maximum=MAX_PRF)
    if "sound_speed" in acq:
        lo, hi = C_LIMITS
        c = _number("acquisition.sound_speed", acq["sound_speed"], unit="m/s", maximum=hi)
        if c <= lo:
            raise ValueError(f"plan acquisition.sound_speed must be > {lo:g} m/s, got {acq['sound_speed']!r}")
    if len(check_wavelengths(acq.get("wavelengths"))) > MAX_WAVELENGTHS:
        raise ValueError(f"a plan holds at most {MAX_WAVELENGTHS} wavelengths")
    wavelength_order(acq)
    return acq


def wavelength_order(acq: dict) -> str:
    """The acquisition's ``wavelength_order``: ``"per_point"`` (default: at every point the
    laser is tuned through all wavelengths before the galvos move on) or ``"per_pass"``
    (one full pass over the points per wavelength). Trade-off: docs/protocol.md §4.1.
    Raises ``ValueError`` for another value.

    Parameters
    ----------
    acq : dict
        The plan's ``acquisition`` object.

    Returns
    -------
    str
        ``"per_point"`` or ``"per_pass"``.

    Raises
    ------
    ValueError
        Another value than those of ``WAVELENGTH_ORDERS`` (or None).
    """
    order = acq.get("wavelength_order")
    if order is None:
        return WAVELENGTH_ORDERS[0]
    if order not in WAVELENGTH_ORDERS:
        raise ValueError(f"acquisition.wavelength_order must be one of {WAVELENGTH_ORDERS}, "
                         f"got {order!r}")
    return order


def aline_order(n_points: int, n_wavelengths: int, order: str,
                s: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Point and wavelength index of A-lines in acquisition order.

    Parameters
    ----------
    n_points : int
        Points of the plan.
    n_wavelengths : int
        Excitation wavelengths of the plan.
    order : str
        ``"per_point"`` (every wavelength at a point, then the next point) or ``"per_pass"``
        (every point at a wavelength, then the next wavelength).
    s : ndarray of int, optional
        A-line indices, any shape (default all, ``0 … n_points·n_wavelengths - 1``).

    Returns
    -------
    k, w : ndarray of int64
        Shaped like ``s``: A-line index s is point ``k`` at wavelength ``w`` (module docstring).

    Raises
    ------
    ValueError
        An unknown ``order``.
    """
    if s is None:
        s = np.arange(n_points * n_wavelengths, dtype=np.int64)
    s = np.asarray(s, dtype=np.int64)
    if order == "per_point":
        return s // n_wavelengths, s % n_wavelengths
    if order == "per_pass":
        return s % n_points, s // n_points
    raise ValueError(f"wavelength order must be one of {WAVELENGTH_ORDERS}, got {order!r}")


def aline_index(k: int | np.ndarray, w: int | np.ndarray, n_points: int, n_wavelengths: int,
                order: str) -> int | np.ndarray:
    """Inverse of :func:`aline_order`: the acquisition index of point ``k`` at wavelength
    ``w`` (ints or int arrays). Raises ``ValueError`` for an unknown ``order``.

    Parameters
    ----------
    k : int or ndarray of int
        Point indices.
    w : int or ndarray of int
        Wavelength indices (broadcast against ``k``).
    n_points, n_wavelengths : int
        Points and wavelengths of the plan.
    order : str
        ``"per_point"`` or ``"per_pass"`` (:func:`aline_order`).

    Returns
    -------
    int or ndarray of int
        The acquisition (A-line) index of each (k, w).

    Raises
    ------
    ValueError
        An unknown ``order``.
    """
    if order == "per_point":
        return k * n_wavelengths + w
    if order == "per_pass":
        return w * n_points + k
    raise ValueError(f"wavelength order must be one of {WAVELENGTH_ORDERS}, got {order!r}")


#: Largest weight a plan point may have, in lattice areas (``check_plan``).
MAX_WEIGHT_AREAS = 4


def check_plan(plan: Any) -> dict:
    """Check a parsed plan (docs/architecture.md "Plan JSON", ``fpscan-plan/1``): the one
    validation of the plan contract, used by the host driver, the scan file and the service.

    Checks: the format; ``id`` is the content hash (``plan_id_of``); the lattice
    (``n_x``, ``n_y`` >= 1, ``pitch`` > 0 m); the acquisition (``check_acquisition``);
    ``points.indices`` ``(n_points, 2)`` integers inside the lattice without duplicates;
    ``points.positions`` ``(n_points, 2)`` (or ``(n_points, 1)`` on a line lattice) equal
    to the lattice positions of the indices (x = (i_x - (n_x - 1)/2)·pitch, y likewise);
    ``points.weights`` ``(n_points,)`` finite, > 0 and at most ``MAX_WEIGHT_AREAS`` times
    the lattice's area (m², m on a line lattice). ``mask`` and ``order`` are the
    planner's record and not checked here.

    Returns the plan (unchanged). Raises ``ValueError`` naming the first problem.

    Parameters
    ----------
    plan : dict
        The parsed plan JSON.

    Returns
    -------
    dict
        ``plan`` itself, unchanged.

    Raises
    ------
    ValueError
        Naming the first problem (a wrong format, a missing section, a malformed id or one
        that is not the content hash, a bad lattice, acquisition or points).
    """
    pid = _check_plan_header(plan)
    n_x, n_y, pitch = _check_plan_lattice(plan["lattice"], plan["points"])
    check_acquisition(plan["acquisition"])
    _check_plan_points(plan["points"], n_x, n_y, pitch)
    expected = plan_id_of(plan)
    if pid != expected:
        raise ValueError(f"plan id {pid[:16]}... does not match its content hash (sha256 {expected})")
    return plan


def _check_plan_header(plan: Any) -> str:
    """``check_plan``: a JSON object of ``PLAN_FORMAT`` with every section and a
    well-formed id; returns the id."""
    if not isinstance(plan, dict):
        raise ValueError(f"a plan must be a JSON object, got {type(plan).__name__}")
    if plan.get("format") != PLAN_FORMAT:
        raise ValueError(f"not an {PLAN_FORMAT} plan (missing or wrong 'format': {plan.get('format')!r})")
    for key in ("id", "lattice", "points", "acquisition"):
        if key not in plan:
            raise ValueError(f"plan has no '{key}'")
    pid = plan["id"]
    if not isinstance(pid, str) or len(pid) != 64 or any(ch not in "0123456789abcdef" for ch in pid):
        raise ValueError("plan id must be a lowercase sha256 hex digest")
    return pid


def _check_plan_lattice(lat: Any, pts: Any) -> tuple[int, int, float]:
    """``check_plan``: the lattice ``(n_x, n_y, pitch)`` (pitch in m), both sections objects."""
    if not isinstance(lat, dict) or not isinstance(pts, dict):
        raise ValueError("plan 'lattice' and 'points' must be objects")
    try:
        n_x = _integer("lattice.n_x", lat["n_x"], 1)
        n_y = _integer("lattice.n_y", lat["n_y"], 1)
        pitch = _number("lattice.pitch", lat["pitch"], unit="m")
    except KeyError as exc:
        raise ValueError(f"plan lattice has no {exc}") from None
    if n_x * n_y > MAX_LATTICE_POINTS:
        raise ValueError(f"plan lattice {n_x}x{n_y} has more than {MAX_LATTICE_POINTS} points")
    return n_x, n_y, pitch


def _plan_point_arrays(pts: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``check_plan``: ``points`` as arrays ``(indices, positions, weights)``, unchecked."""
    try:
        raw = np.asarray(pts["indices"])
        pos = np.asarray(pts["positions"], dtype=np.float64)
        w = np.asarray(pts["weights"], dtype=np.float64)
    except KeyError as exc:
        raise ValueError(f"plan points has no {exc}") from None
    except (TypeError, ValueError) as exc:
        raise ValueError(f"plan points are malformed: {exc}") from None
    return raw, pos, w


def _check_plan_indices(raw: np.ndarray, n_x: int, n_y: int) -> np.ndarray:
    """``check_plan``: ``points.indices`` ``(n_points, 2)`` distinct integers inside the
    lattice; returns them as int64."""
    if raw.ndim != 2 or raw.shape[1:] != (2,) or raw.shape[0] < 1:
        raise ValueError(f"plan points.indices must be (n_points, 2) with n_points >= 1, got shape {raw.shape}")
    if raw.dtype.kind not in "iu":
        raise ValueError("plan points.indices must be integers")
    idx = raw.astype(np.int64)
    if (idx < 0).any() or (idx[:, 0] >= n_x).any() or (idx[:, 1] >= n_y).any():
        raise ValueError(f"plan points.indices has points outside the lattice {n_x}x{n_y}")
    if len(np.unique(idx[:, 0] * n_y + idx[:, 1])) != idx.shape[0]:
        raise ValueError("plan points.indices has duplicate points")
    return idx


def _check_plan_points(pts: dict, n_x: int, n_y: int, pitch: float) -> None:
    """``check_plan``: indices, positions (the lattice positions of the indices, m) and
    weights (finite, > 0, at most ``MAX_WEIGHT_AREAS`` lattice areas)."""
    raw, pos, w = _plan_point_arrays(pts)
    idx = _check_plan_indices(raw, n_x, n_y)
    n = idx.shape[0]
    if pos.ndim != 2 or pos.shape[0] != n or pos.shape[1] not in (1, 2) or (pos.shape[1] == 1 and n_y != 1):
        raise ValueError(f"plan points.positions must be ({n}, 2) (or ({n}, 1) on a line lattice), "
                         f"got shape {pos.shape}")
    if w.shape != (n,):
        raise ValueError(f"plan points.weights must be ({n},), got shape {w.shape}")
    if not (np.isfinite(pos).all() and np.isfinite(w).all()) or (w <= 0).any():
        raise ValueError("plan positions must be finite and weights finite and > 0")
    # a weight is the area (m² or m) one sensor stands for: never more than a few times the
    # lattice's own (the masks give at most ~1x; 1e300 would overflow a reconstruction)
    area = n_x * pitch * (n_y * pitch if n_y > 1 else 1.0)
    if w.max() > MAX_WEIGHT_AREAS * area:
        raise ValueError(f"plan points.weights has a weight of {w.max():g}, more than {MAX_WEIGHT_AREAS} times "
                         f"the lattice's area ({n_x} x {n_y} points at pitch {pitch:g} m: {area:g} "
                         f"m{'²' if n_y > 1 else ''})")
    want = lattice_positions(idx, n_x, n_y, pitch)[:, :pos.shape[1]]
    if np.max(np.abs(pos - want)) > 1e-9 * pitch:
        raise ValueError("plan points.positions are not the lattice positions of points.indices")


def lattice_positions(indices: np.ndarray, n_x: int, n_y: int, pitch: float) -> np.ndarray:
    """Positions ``(n, 2)`` as (x, y) in m of lattice indices ``(n, 2)`` (i_x, i_y) on an
    ``n_x × n_y`` lattice at ``pitch`` (m) centred on the optical axis:
    ``x = (i_x - (n_x - 1)/2)·pitch``, ``y = (i_y - (n_y - 1)/2)·pitch``.

    Parameters
    ----------
    indices : ndarray ``(n, 2)``
        Lattice indices (i_x, i_y).
    n_x, n_y : int
        Lattice points along x and y.
    pitch : float
        Lattice pitch, m.

    Returns
    -------
    ndarray ``(n, 2)`` float64
        Positions (x, y), m.
    """
    i = np.asarray(indices, dtype=np.float64).reshape(-1, 2)
    return np.stack([centred_positions(i[:, 0], n_x, pitch), centred_positions(i[:, 1], n_y, pitch)], axis=1)


def load_plan(source: Any) -> dict:
    """Read and check a plan: a path to plan JSON, a JSON string, or an already-parsed dict.

    Returns the plan dict. Raises ``ValueError`` naming the first problem (a file that is
    not UTF-8 JSON text: "not a plan: ..."; invalid JSON; everything ``check_plan``
    rejects); ``OSError`` if the file cannot be read. What another kind of file is (a scan
    file, a result ...) is named by the registry of formats above the driver
    (``fpscan.service.formats.describe``: the CLI's "this is a scan file, not a plan").

    Parameters
    ----------
    source : dict, str or Path
        A parsed plan, plan JSON text (starting with ``{``), or the path of a plan JSON file.

    Returns
    -------
    dict
        The checked plan (:func:`check_plan`).

    Raises
    ------
    ValueError
        A file that is not UTF-8 JSON text, invalid JSON, or a plan :func:`check_plan` rejects.
    OSError
        The file cannot be read.
    """
    if isinstance(source, dict):
        plan = source
    else:
        if str(source).lstrip().startswith("{"):
            text = str(source)
        else:
            raw = Path(source).read_bytes()
            try:
                text = raw.decode("utf-8")
            except UnicodeDecodeError:
                raise ValueError(f"{source}: not a plan: the file is not UTF-8 JSON text") from None
        try:
            plan = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"plan is not valid JSON: {exc}") from None
    return check_plan(plan)
