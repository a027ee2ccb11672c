"""Numbers a person types: explicit units, and the plausibility rules that catch a unit
mistake (a pitch of 60 m where 60 µm was meant).

:func:`parse_quantity` reads ``"60um"``, ``"60 µm"``, ``"3.6 mm"``, ``"8ns"``, ``"500 Hz"``,
``"1.5 km/s"`` with ``pint`` (its registry with decimal arithmetic, so ``"60um"`` gives
exactly the float ``6e-05`` that ``"6e-5"`` gives: the same plan id); a bare number is SI
(m, s, Hz, m/s). Only ``<number> <unit>`` is accepted -- no expressions -- so hostile text
ends at once; each unit's factor is pint's, looked up once per unit text (cached), so a long
list typed with units (a point list) reads in microseconds per value.

:func:`check_plausible` holds the ranges a planar FP scanner works in, one place for the
library (``ValueError``), the API (422) and the CLI (exit 2):

=============================  ==============================  ============================
quantity                       plausible                       likely mistake named
=============================  ==============================  ============================
lattice pitch, spacing dx/dy   1 µm – 10 mm                    µm or mm typed as m
sample interval dt             0.1 ns – 1 µs                   ns or µs typed as s
point-of-interest depth        > 0, within the recording's     mm or µm typed as m
                               reach c·(n_t − 1)·dt
PRF                            period 1/PRF ≥ the recording    Hz vs kHz
                               n_t·dt (0 = unthrottled)
speed of sound c               1000 – 2000 m/s unless forced   km/s or mm/µs typed as m/s
=============================  ==============================  ============================
"""
from __future__ import annotations

import functools
import math
import re

from fpscan.constants import C_DEFAULT, C_LIMITS, C_PLAUSIBLE

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (`fpscan --help` imports this module)
if TYPE_CHECKING:
    from typing import Any

    import pint

__all__ = [
    "KINDS", "PITCH_RANGE", "DT_RANGE", "MAGNITUDE_MAX", "RefusedInput", "ImplausibleValue", "parse_quantity",
    "suggest_unit", "check_speeds", "check_plausible",
]

#: what each kind of quantity is measured in: (pint dimensionality, SI unit name)
KINDS = {
    "length": ("[length]", "m"),
    "time": ("[time]", "s"),
    "frequency": ("1 / [time]", "Hz"),
    "speed": ("[length] / [time]", "m/s"),
}

PITCH_RANGE = (1e-6, 10e-3)       # m
#: largest magnitude a typed number may have, checked on the text's number before any
#: arithmetic: no quantity of the field is larger, and decimal arithmetic on "1e999999999"
#: overflows (``decimal.Overflow``); tiny numbers only underflow to 0 (then refused by range)
MAGNITUDE_MAX = 1e30
DT_RANGE = (0.1e-9, 1e-6)         # s

_QUANTITY = re.compile(r"^\s*([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)\s*([A-Za-zµμ/ ]*?)\s*$")


class RefusedInput(ValueError):
    """Input refused by a rule the caller can fix (a value out of range, a unit mistake, an
    option the method does not take): a usage error -- the CLI exits 2, the API answers
    422. Subclasses: :class:`ImplausibleValue`, ``fpscan.service.recon.checks.OptionError``.

    Parameters
    ----------
    *args : str
        The message (as ``ValueError``): what was refused and how to fix it.
    """


class ImplausibleValue(RefusedInput):
    """A value outside what a planar FP scanner works with, most likely a unit mistake;
    the message names the quantity, its plausible range and the likely intended unit.

    Parameters
    ----------
    *args : str
        The message (as ``ValueError``).
    """


@functools.cache
def _registry() -> pint.UnitRegistry:
    from decimal import Decimal

    import pint

    return pint.UnitRegistry(non_int_type=Decimal)


def parse_quantity(value: Any, kind: str, *, name: str = "value") -> float:
    """``value`` in SI units as a float.

    Parameters
    ----------
    value : int, float or str
        A number (SI already) or text ``"<number>"`` (SI) or ``"<number> <unit>"``
        (``"60um"``, ``"3.6 mm"``, ``"8ns"``, ``"500 Hz"``, ``"1.5 km/s"``); text longer
        than 40 characters is refused.
    kind : str
        One of :data:`KINDS` (``"length"``, ``"time"``, ``"frequency"``, ``"speed"``).
    name : str, optional
        The quantity's name in error messages (default ``"value"``).

    Returns
    -------
    float
        The value in the kind's SI unit (m, s, Hz or m/s).

    Raises
    ------
    ValueError
        Naming ``name``: an unknown ``kind``; a bool; text that is not a number with a unit
        of that kind (an unknown unit, a unit of another dimension); a typed number above
        :data:`MAGNITUDE_MAX` (checked before any arithmetic) or out of range after the
        conversion; a value that is not finite.
    """
    if kind not in KINDS:
        raise ValueError(f"unknown kind of quantity {kind!r}; one of {', '.join(KINDS)}")
    si = KINDS[kind][1]
    if isinstance(value, bool):
        raise ValueError(f"{name} must be a {kind}, got {value!r}")
    if isinstance(value, (int, float)):
        out = float(value)
    else:
        text = str(value)
        m = _QUANTITY.match(text) if len(text) <= 40 else None
        if m is None:
            raise ValueError(f"{name} must be a number with an optional {kind} unit "
                             f"(e.g. {', '.join(_EXAMPLES[kind])}; bare numbers are {si}), got {text!r}")
        number, unit = m.group(1), m.group(2).strip().replace("μ", "µ")
        if not abs(float(number)) <= MAGNITUDE_MAX:  # a float first: "1e999999999" is inf here, not decimal's
            raise ValueError(f"{name}: the number {number!r} is out of range (magnitude at most "  # Overflow later
                             f"{MAGNITUDE_MAX:g})")
        from decimal import Decimal, InvalidOperation  # imported here: ``fpscan --help`` imports this module

        try:
            magnitude = Decimal(number)
        except InvalidOperation:
            raise ValueError(f"{name}: {number!r} is not a number") from None
        if not unit:
            out = float(magnitude)
        else:
            factor = _unit_factor(unit, kind)
            if factor == "unknown":
                raise ValueError(f"{name}: unknown unit {unit!r} (a {kind}: e.g. "
                                 f"{', '.join(_EXAMPLES[kind])})")
            if factor == "other":
                raise ValueError(f"{name}: {text.strip()!r} is not a {kind} (expected {si} or e.g. "
                                 f"{', '.join(_EXAMPLES[kind])})")
            try:  # decimal's own bounds (Overflow, an ArithmeticError) stay a refusal, never a crash
                if not isinstance(factor, Decimal):
                    raise ArithmeticError(factor)
                out = float(magnitude * factor)
            except ArithmeticError:
                raise ValueError(f"{name}: {text.strip()!r} is out of range") from None
    if not math.isfinite(out):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return out


@functools.lru_cache(maxsize=256)
def _unit_factor(unit: str, kind: str) -> Any:
    """The factor (a ``Decimal``) that takes a magnitude in ``unit`` to the SI unit of ``kind``,
    as pint's conversion multiplies by it (every unit of :data:`KINDS` is multiplicative, no
    offset); or why not: ``"unknown"`` (pint knows no such unit), ``"other"`` (a unit of
    another dimension), ``"range"`` (the factor is beyond decimal's bounds). Cached per unit
    text (at most 256, each at most 40 characters): a list of values typed with units (a
    point list) reads at the speed of decimal arithmetic, not of pint's unit parser."""
    from decimal import Decimal

    import pint

    dim, si = KINDS[kind]
    try:
        one = _registry().Quantity(Decimal(1), _registry().Unit(unit))
    except (pint.errors.PintError, AttributeError, ValueError, TypeError, ArithmeticError):
        return "unknown"
    if not one.check(dim):
        return "other"
    try:
        return Decimal(one.to(si).magnitude)
    except ArithmeticError:
        return "range"


_EXAMPLES = {"length": ("60um", "3.6 mm"), "time": ("8ns", "2 us"), "frequency": ("500 Hz", "2 kHz"),
             "speed": ("1500 m/s", "1.54 km/s")}


def _fmt(x: float, unit: str) -> str:
    """``x`` SI in a readable unit (µm/mm, ns/µs, Hz/kHz)."""
    if unit == "m":
        for scale, u in ((1.0, "m"), (1e-3, "mm"), (1e-6, "µm"), (1e-9, "nm")):
            if abs(x) >= scale or scale == 1e-9:
                return f"{x / scale:g} {u}"
    if unit == "s":
        for scale, u in ((1.0, "s"), (1e-3, "ms"), (1e-6, "µs"), (1e-9, "ns"), (1e-12, "ps")):
            if abs(x) >= scale or scale == 1e-12:
                return f"{x / scale:g} {u}"
    if unit == "Hz":
        for scale, u in ((1e6, "MHz"), (1e3, "kHz"), (1.0, "Hz")):
            if abs(x) >= scale or scale == 1.0:
                return f"{x / scale:g} {u}"
    return f"{x:g} {unit}"


def _guess(value: float, lo: float, hi: float, units: tuple) -> str:
    """``" -- did you mean 60 µm (60um)?"`` for the first ``(factor, name, suffix)`` that
    brings ``value`` into ``[lo, hi]``, else "". The suggestion is the quantity the number
    most likely meant, written in its readable unit: 60 (m) and 60 mm both suggest 60 µm --
    the number typed, in a unit 10³ or 10⁶ smaller (not "0.06 mm", the same mistaken
    quantity renamed)."""
    si = _SI_OF_UNITS.get(units, "m")
    for factor, _unit_name, _suffix in units:
        if lo <= value * factor <= hi:
            return _did_you_mean(value * factor, si)
    for factor in (1e3, 1e6):  # too small: typed in a unit 10³ or 10⁶ too small (60 nm for 60 µm)
        if lo <= value * factor <= hi:
            return _did_you_mean(value * factor, si)
    for factor in (1e-3, 1e-6):  # too large: typed in a unit 10³ or 10⁶ too large (8 µs for 8 ns)
        if lo <= value * factor <= hi:
            return _did_you_mean(value * factor, si)
    return ""


def _did_you_mean(x: float, unit: str) -> str:
    shown = _fmt(x, unit)
    return f" -- did you mean {shown} ({shown.replace(' ', '').replace('µ', 'u')})?"


def suggest_unit(value: float, lo: float, hi: float, unit: str) -> str:
    """The likely-unit hint of a value (SI ``unit``: ``"m"`` or ``"s"``) outside
    ``[lo, hi]``: the number typed in a unit 10³, 10⁶ or 10⁹ smaller that lands in range
    (``750`` m for a wavelength: " -- did you mean 750 nm (750nm)?"), else "".

    Parameters
    ----------
    value : float
        The value as given, read in SI units.
    lo, hi : float
        The plausible range, SI units.
    unit : str
        The SI unit, ``"m"`` or ``"s"``.

    Returns
    -------
    str
        The hint to append to an error message, or ``""`` when no smaller unit fits.
    """
    for factor in (1e-9, 1e-6, 1e-3):
        if lo <= value * factor <= hi:
            return _did_you_mean(value * factor, unit)
    return ""


def _in_range(name: str, value: float, lo: float, hi: float, unit: str, units: tuple) -> None:
    if not lo <= value <= hi:
        raise ImplausibleValue(
            f"{name} {value:g} {unit} is implausible for a planar FP scanner (expected "
            f"{_fmt(lo, unit)} to {_fmt(hi, unit)}){_guess(value, lo, hi, units)} "
            f"Numbers without a unit are SI ({unit}); write the unit, e.g. {_EXAMPLES[_KIND_OF[unit]][0]}.")


_KIND_OF = {"m": "length", "s": "time", "Hz": "frequency", "m/s": "speed"}
_LENGTH_UNITS = ((1e-6, "µm", "um"), (1e-3, "mm", "mm"), (1e-9, "nm", "nm"))
_TIME_UNITS = ((1e-9, "ns", "ns"), (1e-6, "µs", "us"), (1e-12, "ps", "ps"))
_SI_OF_UNITS = {_LENGTH_UNITS: "m", _TIME_UNITS: "s"}


def check_speeds(*, sound_speed: Any = None, sound_speed_range: Any = None, force: bool = False) -> None:
    """The speed-of-sound rule for reconstruction options (every method's options model,
    ``fpscan.service.recon.methods.options.SpeedOptions``, which every door validates with): a
    numeric ``sound_speed`` (m/s) and each end of the autofocus search interval
    ``sound_speed_range`` within ``fpscan.constants.C_PLAUSIBLE`` (1000–2000 m/s) unless ``force``;
    forced, a numeric ``sound_speed`` stays within ``C_LIMITS`` (above 100, at most 10 000 m/s).
    ``"auto"``, None and non-numbers pass (their own checks name them).

    Parameters
    ----------
    sound_speed : Any, optional
        The speed of sound, m/s (a number is checked; ``"auto"``, None and other values pass).
    sound_speed_range : Any, optional
        The autofocus search interval ``(lo, hi)``, m/s (each numeric end of a list or tuple
        is checked).
    force : bool, optional
        Accept speeds outside ``C_PLAUSIBLE`` (other media); ``sound_speed`` must still lie
        within ``C_LIMITS``.

    Raises
    ------
    ImplausibleValue
        ``sound_speed`` or an end of ``sound_speed_range`` outside ``C_PLAUSIBLE`` (not forced);
        the message names the option and the likely unit mistake.
    RefusedInput
        A forced ``sound_speed`` outside ``C_LIMITS``.

    Examples
    --------
    >>> from fpscan.driver.units import check_speeds
    >>> check_speeds(sound_speed=1480.0, sound_speed_range=(1450.0, 1600.0))
    >>> check_speeds(sound_speed=3000.0, force=True)  # another medium
    >>> check_speeds(sound_speed=1.5)
    Traceback (most recent call last):
    ...
    fpscan.driver.units.ImplausibleValue: sound_speed: sound speed 1.5 m/s is implausible for tissue or water ...
    """
    def number(v: Any) -> bool:
        return isinstance(v, (int, float)) and not isinstance(v, bool)

    if force:
        if number(sound_speed) and not C_LIMITS[0] < float(sound_speed) <= C_LIMITS[1]:
            raise RefusedInput(f"sound_speed must be within {C_LIMITS[0]:g}-{C_LIMITS[1]:g} m/s even with force, "
                               f"got {float(sound_speed):g} m/s")
        return
    if number(sound_speed):
        try:
            check_plausible(sound_speed=float(sound_speed))
        except ImplausibleValue as exc:
            raise ImplausibleValue(f"sound_speed: {exc}") from None
    if isinstance(sound_speed_range, (list, tuple)):
        for end in sound_speed_range:
            if number(end):
                try:
                    check_plausible(sound_speed=float(end))
                except ImplausibleValue as exc:
                    raise ImplausibleValue(f"sound_speed_range: {exc}") from None


def check_plausible(*, pitch: float | None = None, dx: float | None = None, dy: float | None = None,
                    dt: float | None = None, n_t: int | None = None, prf: float | None = None,
                    sound_speed: float | None = None, depth: float | None = None,
                    force: bool = False) -> None:
    """Raise :class:`ImplausibleValue` (a ``ValueError``) for the first value outside the
    table of the module docstring, naming the likely unit mistake. All values SI; None =
    not given. ``force`` accepts a sound speed outside ``C_PLAUSIBLE`` (other media).

    Parameters
    ----------
    pitch, dx, dy : float, optional
        Lateral spacings, m (within ``PITCH_RANGE``).
    dt : float, optional
        Sample interval, s (within ``DT_RANGE``).
    n_t : int, optional
        Samples per A-line (with ``dt``: the recording's length for the depth and PRF checks).
    prf : float, optional
        Pulse repetition frequency, Hz: its period must not be shorter than one recording
        ``n_t·dt`` (checked when ``n_t`` and ``dt`` are given).
    sound_speed : float, optional
        m/s, within ``C_PLAUSIBLE`` unless ``force`` (also the speed of the depth check;
        default ``C_DEFAULT``).
    depth : float, optional
        Imaging depth below the sensor plane, m: > 0 and, with ``n_t`` and ``dt``, within the
        recording's reach ``c·(n_t − 1)·dt``.
    force : bool, optional
        Skip the sound-speed range check.

    Raises
    ------
    ImplausibleValue
        The first value out of its range, with the likely unit mistake in the message.
    """
    for name, v in (("pitch", pitch), ("dx", dx), ("dy", dy)):
        if v is not None:
            _in_range(name, float(v), *PITCH_RANGE, "m", _LENGTH_UNITS)
    if dt is not None:
        _in_range("dt", float(dt), *DT_RANGE, "s", _TIME_UNITS)
    if sound_speed is not None and not force:
        c = float(sound_speed)
        if not C_PLAUSIBLE[0] <= c <= C_PLAUSIBLE[1]:
            hint = ""
            if C_PLAUSIBLE[0] <= c * 1e3 <= C_PLAUSIBLE[1]:
                hint = f" -- did you mean {c:g} km/s (= {c * 1e3:g} m/s; mm/µs is the same)?"
            raise ImplausibleValue(
                f"sound speed {c:g} m/s is implausible for tissue or water (expected {C_PLAUSIBLE[0]:g} to "
                f"{C_PLAUSIBLE[1]:g} m/s){hint} Numbers without a unit are m/s; force a value outside the range if the "
                "medium really is that fast or slow.")
    recording = n_t * dt if (n_t is not None and dt is not None) else None
    if depth is not None and float(depth) <= 0:
        raise ImplausibleValue(f"depth must be > 0 m (below the sensor plane), got {float(depth):g} m")
    if depth is not None:
        d = float(depth)
        c = float(sound_speed) if sound_speed is not None else C_DEFAULT
        reach = c * (n_t - 1) * dt if (n_t is not None and dt is not None) else None
        if d <= 0 or (reach is not None and d > reach):
            def fits(x: float) -> bool:  # a unit guess must land within the recording and >= 10 µm
                return reach is not None and 1e-5 <= x <= reach

            hint = (f" -- did you mean {d:g} mm ({d:g}mm)?" if fits(d * 1e-3) else
                    f" -- did you mean {d:g} µm ({d:g}um)?" if fits(d * 1e-6) else
                    " -- record longer (more samples n_t or a larger dt) or choose a shallower depth.")
            where = f"the recording reaches c·(n_t − 1)·dt = {_fmt(reach, 'm')}" if reach is not None \
                else "it must be > 0"
            raise ImplausibleValue(
                f"depth {d:g} m is beyond the recording's reach ({where}){hint} Numbers without a unit "
                "are metres; write the unit, e.g. 3.6mm.")
    if prf is not None and float(prf) > 0 and recording is not None and dt is not None:
        period = 1.0 / float(prf)
        if period < recording:
            f = float(prf)
            hint = f" -- did you mean {f / 1e3:g} Hz?" if 1e3 / f >= recording else ""
            raise ImplausibleValue(
                f"PRF {_fmt(f, 'Hz')} fires every {_fmt(period, 's')}, shorter than one recording "
                f"(n_t·dt = {n_t} × {_fmt(dt, 's')} = {_fmt(recording, 's')}){hint} Numbers without a "
                "unit are Hz; write it, e.g. 500Hz or 2kHz.")
