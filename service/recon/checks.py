"""The option and input rules shared by the reconstructions: each option's range and its
refusal in words (``check_eps``, ``check_dz``, ...), the inputs' checks (``positive``,
``finite_array``) and the memory check against a limit (``check_memory``; the peak-memory
models themselves are ``fpscan.service.recon.memory``'s)."""
from __future__ import annotations

import math
import os
import reprlib
from typing import Any

import numpy as np

from fpscan.constants import C_AUTOFOCUS_LIMITS
from fpscan.driver.units import RefusedInput
from fpscan.physics.fft_engine import is_small

__all__ = [
    "positive", "finite_array", "EPS_RANGE", "UPSAMPLE_RANGE", "N_Z_RANGE", "DZ_RANGE", "LAM_RANGE",
    "ITERATIONS_RANGE", "TIME_LIMIT_MAX", "OptionError", "check_eps", "check_upsample", "check_n_z",
    "check_sound_speed_range", "check_dz", "check_lam", "check_bandwidth", "check_tol", "check_max_iter", "check_time_limit", "check_dtype", "available_memory",
    "check_memory",
]


def positive(name: str, value: Any) -> float:
    """``value`` as a float, refused unless finite and > 0.

    Parameters
    ----------
    name : str
        The quantity's name, used in the error message.
    value : float or anything ``float()`` takes
        The value (in the quantity's SI unit).

    Returns
    -------
    float

    Raises
    ------
    ValueError
        Not a number, non-finite or <= 0; the message names ``name``.

    Examples
    --------
    >>> from fpscan.service.recon.checks import positive
    >>> positive("dx", "1e-4")  # m
    0.0001
    >>> positive("dt", -1)
    Traceback (most recent call last):
    ...
    ValueError: dt must be a finite number > 0, got -1
    """
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {_said(value)}") from None
    if not np.isfinite(v) or v <= 0:
        raise ValueError(f"{name} must be a finite number > 0, got {_said(value)}")
    return v


def finite_array(name: str, a: Any, ndims: tuple[int, ...]) -> np.ndarray:
    """``a`` as an ndarray of real numbers with a number of dimensions in ``ndims``.

    Parameters
    ----------
    name : str
        The array's name, used in the error message.
    a : array_like
        The array (int, uint or float).
    ndims : tuple of int
        Allowed numbers of dimensions, e.g. ``(2, 3)`` for ``(n_t, n_x)`` / ``(n_t, n_y, n_x)``.

    Returns
    -------
    ndarray
        ``np.asarray(a)``, not copied.

    Raises
    ------
    ValueError
        NaN/inf, a wrong number of dimensions, empty or non-numeric input.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.checks import finite_array
    >>> finite_array("data", [[1, 2], [3, 4]], (2,)).shape
    (2, 2)
    >>> finite_array("data", [[1, np.nan]], (2,))
    Traceback (most recent call last):
    ...
    ValueError: data contains NaN or inf
    """
    arr = np.asarray(a)
    if arr.dtype.kind not in "fiu":
        raise ValueError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    if arr.ndim not in ndims:
        raise ValueError(f"{name} must have {' or '.join(map(str, ndims))} dimensions, got shape {arr.shape}")
    if arr.size == 0 or 0 in arr.shape:
        raise ValueError(f"{name} is empty (shape {arr.shape})")
    if arr.dtype.kind != "f":  # integers are finite
        return arr
    if arr.dtype in (np.float32, np.float64) and arr.flags.c_contiguous and not is_small(arr.size):
        from fpscan.physics.array_kernels import nonfinite  # numba: on use, for a large array

        single = arr.dtype == np.float32
        bits = arr.reshape(-1).view(np.uint32 if single else np.uint64)
        if nonfinite(bits, 0x7F800000 if single else 0x7FF0000000000000):  # one pass on every core
            raise ValueError(f"{name} contains NaN or inf")
        return arr
    # one summing pass in the array's own precision, without a temporary (NaN/inf propagate
    # into the sum; float32 summed as float64 took twice as long: 24 against 12 ms at
    # 1024 x 226²); only a sum that overflowed from finite values needs the element-wise check
    with np.errstate(all="ignore"):
        total = arr.sum()
    if not np.isfinite(total) and not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf")
    return arr


# -- the reconstruction options' rules: one owner each ----------------------------------
# The kernels (``planar``, ``tv``) apply these; the methods' options models
# (``fpscan.service.recon.methods.options``) apply the same functions at every door (library, CLI,
# HTTP) before a job is queued, and their JSON schemas state the same bounds.

# the ranges: fpscan.service.recon.limits (import-free, read by the methods' option models too)
from fpscan.service.recon.limits import (
    BANDWIDTH_RANGE,
    DZ_RANGE,
    EPS_RANGE,
    ITERATIONS_RANGE,
    LAM_RANGE,
    N_Z_RANGE,
    TIME_LIMIT_MAX,
    TOL_RANGE,
    UPSAMPLE_RANGE,
)


class OptionError(RefusedInput):
    """A reconstruction option refused by its rule.

    A value outside its range, or an option the chosen method does not take: the caller's
    input, a usage error (CLI exit 2, HTTP 422). A ``fpscan.driver.units.RefusedInput``, hence a
    ``ValueError``.

    Attributes
    ----------
    args : tuple of str
        The message: the option, its rule and the value given.

    Examples
    --------
    >>> from fpscan.service.recon.checks import OptionError, check_eps
    >>> issubclass(OptionError, ValueError)
    True
    >>> try:
    ...     check_eps(5e-15)
    ... except OptionError as exc:
    ...     print(exc)
    eps must be in [1e-14, 1e-1], got 5e-15
    """


#: how a refused value is shown in its message: a few elements of a list, the ends of a long text (reprlib), so
#: that a body of 64 KiB refused for one option neither builds nor sends a message of its size
_SHOWN = reprlib.Repr()
_SHOWN.maxstring = _SHOWN.maxother = 66
_SHOWN.maxlist = _SHOWN.maxtuple = _SHOWN.maxdict = _SHOWN.maxset = 4
_SHOWN.maxlevel = 2


def _said(value: Any) -> str:
    """``repr(value)``, bounded (:data:`_SHOWN`): ``[[1, 2], [1, 2], ...]`` for a list of thousands."""
    return _SHOWN.repr(value)


def _number(name: str, value: Any, what: str) -> float:
    if isinstance(value, bool):
        raise OptionError(f"{name} must be {what}, got {_said(value)}")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise OptionError(f"{name} must be {what}, got {_said(value)}") from None


def _integer(name: str, value: Any, lo: int, hi: int) -> int:
    what = f"an integer in {lo}..{hi}"
    v = _number(name, value, what)
    if not np.isfinite(v) or int(v) != v or not lo <= v <= hi:
        raise OptionError(f"{name} must be {what}, got {_said(value)}")
    return int(v)


def check_eps(eps: Any) -> float:
    """The NUFFT tolerance, within ``EPS_RANGE`` ([1e-14, 1e-1], inclusive).

    Parameters
    ----------
    eps : float
        Relative tolerance of the NUFFTs (dimensionless).

    Returns
    -------
    float

    Raises
    ------
    OptionError
        (a ValueError) not a number, or outside the range.

    Examples
    --------
    >>> from fpscan.service.recon.checks import check_eps
    >>> check_eps(1e-6)
    1e-06
    >>> check_eps(5e-15)
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: eps must be in [1e-14, 1e-1], got 5e-15
    """
    e = _number("eps", eps, "a number")
    if not (EPS_RANGE[0] <= e <= EPS_RANGE[1]):
        raise OptionError(f"eps must be in [1e-14, 1e-1], got {_said(eps)}")
    return e


def check_upsample(upsample: Any) -> int:
    """The lateral upsampling factor: an integer in ``UPSAMPLE_RANGE`` (1..8).

    Parameters
    ----------
    upsample : int or integral float
        Output points per sensor pitch along each lateral axis.

    Returns
    -------
    int

    Raises
    ------
    OptionError
        (a ValueError) not an integer (booleans included), or outside the range.

    Examples
    --------
    >>> from fpscan.service.recon.checks import check_upsample
    >>> check_upsample(2.0)
    2
    >>> check_upsample(9)
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: upsample must be an integer in 1..8, got 9
    """
    return _integer("upsample", upsample, *UPSAMPLE_RANGE)


def check_n_z(n_z: Any) -> int:
    """The number of output depth samples: an integer in ``N_Z_RANGE`` (2..65536).

    Parameters
    ----------
    n_z : int, integral float or its decimal text
        Depth samples (rows) of p0.

    Returns
    -------
    int

    Raises
    ------
    OptionError
        (a ValueError) not an integer, or outside the range.

    Examples
    --------
    >>> from fpscan.service.recon.checks import check_n_z
    >>> check_n_z("128")
    128
    >>> check_n_z(1)
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: n_z must be an integer in 2..65536, got 1
    """
    return _integer("n_z", n_z, *N_Z_RANGE)


def check_dz(dz: Any) -> float:
    """The output depth spacing, within ``DZ_RANGE`` ([1 nm, 0.1 m]).

    Parameters
    ----------
    dz : float
        Depth spacing, m.

    Returns
    -------
    float
        m.

    Raises
    ------
    OptionError
        (a ValueError) not a finite number, or outside the range.

    Examples
    --------
    >>> from fpscan.service.recon.checks import check_dz
    >>> check_dz(5e-5)
    5e-05
    >>> check_dz(1.0)
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: dz must be in [1e-09, 0.1] m, got 1.0
    """
    v = _number("dz", dz, "a depth spacing in m")
    if not np.isfinite(v) or not DZ_RANGE[0] <= v <= DZ_RANGE[1]:
        raise OptionError(f"dz must be in [1e-09, 0.1] m, got {_said(dz)}")
    return v


def check_lam(lam: Any) -> float:
    """The TV weight λ: a finite number in ``LAM_RANGE`` ([0, 1e30]).

    Parameters
    ----------
    lam : float
        Weight of the total-variation term of ½‖A p0 − g‖² + λ TV(p0) (`fpscan.service.recon.tv`:
        TV with forward differences in voxel units, J in Pa², so λ is in Pa).

    Returns
    -------
    float

    Raises
    ------
    OptionError
        (a ValueError) not a finite number, or outside the range.

    Examples
    --------
    >>> from fpscan.service.recon.checks import check_lam
    >>> check_lam(0)
    0.0
    >>> check_lam(-1)
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: lam (the TV weight λ) must be in [0, 1e+30], got -1
    """
    v = _number("lam (the TV weight λ)", lam, "a number >= 0")
    if not np.isfinite(v) or not LAM_RANGE[0] <= v <= LAM_RANGE[1]:
        raise OptionError(f"lam (the TV weight λ) must be in [0, 1e+30], got {_said(lam)}")
    return v


def check_bandwidth(bandwidth: Any) -> float:
    """A sensor bandwidth the caller declares, Hz: a finite number in ``BANDWIDTH_RANGE``
    ([1e3, 1e12]); tv works at that band instead of the one it reads off the data
    (`fpscan.service.recon.tv.grid`).

    Parameters
    ----------
    bandwidth : float
        The highest frequency the sensor passes, Hz.

    Returns
    -------
    float

    Raises
    ------
    OptionError
        (a ValueError) not a finite number, or outside the range.

    Examples
    --------
    >>> from fpscan.service.recon.checks import check_bandwidth
    >>> check_bandwidth("2e7")  # Hz
    20000000.0
    >>> check_bandwidth(0)
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: bandwidth (the sensor's band, Hz) must be in [1e+03, 1e+12], got 0
    """
    v = _number("bandwidth (the sensor's band, Hz)", bandwidth, "a number > 0")
    if not np.isfinite(v) or not BANDWIDTH_RANGE[0] <= v <= BANDWIDTH_RANGE[1]:
        raise OptionError(f"bandwidth (the sensor's band, Hz) must be in [{BANDWIDTH_RANGE[0]:.0e}, "
                          f"{BANDWIDTH_RANGE[1]:.0e}], got {_said(bandwidth)}")
    return v


def check_tol(tol: Any) -> float:
    """The model-based solver's stopping threshold: a number in ``TOL_RANGE`` ([0, 0.5]).

    Parameters
    ----------
    tol : float
        Stop when the image's relative change per iteration, ‖x_k − x_{k−1}‖ / ‖x_k‖, has
        stayed below ``tol`` for the last 3 iterations (`fpscan.service.recon.tv`); 0: run every
        iteration.

    Returns
    -------
    float

    Raises
    ------
    OptionError
        (a ValueError) not a finite number, or outside the range.

    Examples
    --------
    >>> from fpscan.service.recon.checks import check_tol
    >>> check_tol(0.01)
    0.01
    >>> check_tol(1)
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: tol (the stopping threshold) must be in [0, 0.5], got 1
    """
    v = _number("tol (the stopping threshold)", tol, "a number in [0, 0.5]")
    if not np.isfinite(v) or not TOL_RANGE[0] <= v <= TOL_RANGE[1]:
        raise OptionError(f"tol (the stopping threshold) must be in [0, 0.5], got {_said(tol)}")
    return v


def check_max_iter(max_iter: Any) -> int:
    """The iteration cap of the model-based solver: an integer in ``ITERATIONS_RANGE`` (1..100000).

    Parameters
    ----------
    max_iter : int or integral float

    Returns
    -------
    int

    Raises
    ------
    OptionError
        (a ValueError) not an integer, or outside the range.

    Examples
    --------
    >>> from fpscan.service.recon.checks import check_max_iter
    >>> check_max_iter(200)
    200
    >>> check_max_iter(0)
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: max_iter must be an integer in 1..100000, got 0
    """
    return _integer("max_iter", max_iter, *ITERATIONS_RANGE)


def check_time_limit(seconds: Any) -> float:
    """The wall-time limit of the model-based solver, in (0, ``TIME_LIMIT_MAX``] (a week).

    Parameters
    ----------
    seconds : float
        s.

    Returns
    -------
    float
        s.

    Raises
    ------
    OptionError
        (a ValueError) not a finite number, or outside the range.

    Examples
    --------
    >>> from fpscan.service.recon.checks import check_time_limit
    >>> check_time_limit(60)
    60.0
    >>> check_time_limit(0)
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: time_limit must be in (0, 604800] s, got 0
    """
    v = _number("time_limit", seconds, "a number of seconds")
    if not np.isfinite(v) or not 0 < v <= TIME_LIMIT_MAX:
        raise OptionError(f"time_limit must be in (0, {TIME_LIMIT_MAX:g}] s, got {_said(seconds)}")
    return v


def check_dtype(dtype: Any) -> np.dtype:
    """The working precision: float32 or float64.

    Parameters
    ----------
    dtype : str, type or numpy.dtype
        Anything ``numpy.dtype`` takes.

    Returns
    -------
    numpy.dtype

    Raises
    ------
    OptionError
        (a ValueError) any other dtype.

    Examples
    --------
    >>> from fpscan.service.recon.checks import check_dtype
    >>> check_dtype("float32")
    dtype('float32')
    >>> check_dtype("int16")
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: dtype must be float32 or float64, got int16
    """
    if isinstance(dtype, str) and len(dtype) > 32:  # no dtype name is longer; NumPy's parser is not fed text
        raise OptionError(f"dtype must be float32 or float64, got {dtype[:32]!r}...")
    try:
        dt = np.dtype(dtype)
    except (TypeError, ValueError, SyntaxError):  # NumPy's parser raises SyntaxError for "(1,2"
        raise OptionError(f"dtype must be float32 or float64, got {_said(dtype)}") from None
    if dt not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise OptionError(f"dtype must be float32 or float64, got {dt}")
    return dt


def available_memory() -> int:
    """Bytes of memory available now.

    Linux's ``MemAvailable`` (``/proc/meminfo``); elsewhere the physical pages free.

    Returns
    -------
    int
        Bytes.

    Examples
    --------
    >>> from fpscan.service.recon.checks import available_memory
    >>> available_memory() > 0
    True
    """
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def check_memory(needed: int, memory_limit: int | None) -> None:
    """Refuse a reconstruction that needs more memory than the limit.

    Parameters
    ----------
    needed : int
        Bytes at the peak (`estimate_peak_memory`).
    memory_limit : int or None
        Bytes; None: the memory available now (`available_memory`).

    Raises
    ------
    ValueError
        ``needed`` above the limit, naming both in GiB and what to reduce.

    Examples
    --------
    >>> from fpscan.service.recon.checks import check_memory
    >>> check_memory(2**20, 2**30)
    >>> check_memory(2**31, 2**30)
    Traceback (most recent call last):
    ...
    ValueError: reconstruction needs about 2.00 GiB at its peak, more than the limit of 1.00 GiB; ...
    """
    limit = available_memory() if memory_limit is None else int(memory_limit)
    if needed > limit and memory_limit is None:
        from fpscan.physics import workspace

        if workspace.release():  # the work-array pool's free buffers give way first
            limit = available_memory()
    if needed > limit:
        raise ValueError(
            f"reconstruction needs about {needed / 2**30:.2f} GiB at its peak, more than the "
            f"limit of {limit / 2**30:.2f} GiB; reduce n_t, n_z, the grid or upsample, or use float32"
        )


def check_sound_speed_range(sound_speed_range: Any) -> tuple[float, float]:
    """Check an autofocus search interval (``fpscan.service.autofocus``'s, and the options models').

    Parameters
    ----------
    sound_speed_range : sequence of two numbers
        ``(c_min, c_max)`` in m/s.

    Returns
    -------
    tuple of float
        ``(c_min, c_max)`` in m/s as floats.

    Raises
    ------
    ValueError
        Not two numbers; not finite; not c_min < c_max; not both within
        ``fpscan.constants.C_AUTOFOCUS_LIMITS``.

    Examples
    --------
    >>> from fpscan.service.recon.checks import check_sound_speed_range
    >>> check_sound_speed_range([1450, "1600"])
    (1450.0, 1600.0)
    >>> check_sound_speed_range((1600, 1450))
    Traceback (most recent call last):
    ...
    ValueError: sound_speed_range must satisfy 300 <= c_min < c_max <= 6000 m/s, got (1600.0, 1450.0)
    """
    try:
        lo, hi = (float(v) for v in sound_speed_range)
    except (TypeError, ValueError):
        raise ValueError(f"sound_speed_range must be two speeds (c_min, c_max) in m/s, got {_said(sound_speed_range)}") \
            from None
    if not (math.isfinite(lo) and math.isfinite(hi) and C_AUTOFOCUS_LIMITS[0] <= lo < hi <= C_AUTOFOCUS_LIMITS[1]):
        raise ValueError(f"sound_speed_range must satisfy {C_AUTOFOCUS_LIMITS[0]:g} <= c_min < c_max <= "
                         f"{C_AUTOFOCUS_LIMITS[1]:g} m/s, got ({lo}, {hi})")
    return lo, hi
