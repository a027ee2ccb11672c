"""Input validation and the peak-memory estimate shared by the reconstructions."""
from __future__ import annotations

import os

import numpy as np

from driver.physics.fast_lengths import fast_dct1_rows, fast_lateral
from driver.units import RefusedInput

__all__ = [
    "positive", "finite_array", "EPS_RANGE", "UPSAMPLE_RANGE", "N_Z_RANGE", "DZ_RANGE", "LAM_RANGE",
    "ITERATIONS_RANGE", "TIME_LIMIT_MAX", "OptionError", "check_eps", "check_upsample", "check_n_z",
    "check_dz", "check_lam", "check_bandwidth", "check_tol", "check_iterations", "check_time_limit", "check_dtype", "available_memory",
    "estimate_peak_memory", "padded_lateral", "OPERATOR_BATCH", "OPERATOR_CHUNK", "tv_memory", "check_memory",
]


def positive(name: str, value) -> float:
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
    >>> from service.recon.checks import positive
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
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not np.isfinite(v) or v <= 0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return v


def finite_array(name: str, a, ndims: tuple[int, ...]) -> np.ndarray:
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
    >>> from service.recon.checks import finite_array
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
    # one summing pass in the array's own precision, without a temporary (NaN/inf propagate
    # into the sum; float32 summed as float64 took twice as long: 24 against 12 ms at
    # 1024 x 226²); only a sum that overflowed from finite values needs the element-wise check
    with np.errstate(all="ignore"):
        total = arr.sum()
    if not np.isfinite(total) and not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf")
    return arr


# -- the reconstruction options' rules: one owner each ----------------------------------
# The kernels (``planar``, ``tv``) apply these; ``service.pipeline.check_options`` applies
# the same functions at every door (library, CLI, HTTP) before a job is queued, and the
# HTTP schema states the same bounds (``service.api.models.ReconParams``).

# the ranges: service.recon.limits (import-free, read by the methods' option models too)
from service.recon.limits import (  # noqa: E402
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
    input, a usage error (CLI exit 2, HTTP 422). A ``driver.units.RefusedInput``, hence a
    ``ValueError``.

    Attributes
    ----------
    args : tuple of str
        The message: the option, its rule and the value given.

    Examples
    --------
    >>> from service.recon.checks import OptionError, check_eps
    >>> issubclass(OptionError, ValueError)
    True
    >>> try:
    ...     check_eps(5e-15)
    ... except OptionError as exc:
    ...     print(exc)
    eps must be in [1e-14, 1e-1], got 5e-15
    """


def _number(name: str, value, what: str) -> float:
    if isinstance(value, bool):
        raise OptionError(f"{name} must be {what}, got {value!r}")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise OptionError(f"{name} must be {what}, got {value!r}") from None


def _integer(name: str, value, lo: int, hi: int) -> int:
    what = f"an integer in {lo}..{hi}"
    v = _number(name, value, what)
    if not np.isfinite(v) or int(v) != v or not lo <= v <= hi:
        raise OptionError(f"{name} must be {what}, got {value!r}")
    return int(v)


def check_eps(eps) -> float:
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
    >>> from service.recon.checks import check_eps
    >>> check_eps(1e-6)
    1e-06
    >>> check_eps(5e-15)
    Traceback (most recent call last):
    ...
    service.recon.checks.OptionError: eps must be in [1e-14, 1e-1], got 5e-15
    """
    e = _number("eps", eps, "a number")
    if not (EPS_RANGE[0] <= e <= EPS_RANGE[1]):
        raise OptionError(f"eps must be in [1e-14, 1e-1], got {eps!r}")
    return e


def check_upsample(upsample) -> int:
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
    >>> from service.recon.checks import check_upsample
    >>> check_upsample(2.0)
    2
    >>> check_upsample(9)
    Traceback (most recent call last):
    ...
    service.recon.checks.OptionError: upsample must be an integer in 1..8, got 9
    """
    return _integer("upsample", upsample, *UPSAMPLE_RANGE)


def check_n_z(n_z) -> int:
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
    >>> from service.recon.checks import check_n_z
    >>> check_n_z("128")
    128
    >>> check_n_z(1)
    Traceback (most recent call last):
    ...
    service.recon.checks.OptionError: n_z must be an integer in 2..65536, got 1
    """
    return _integer("n_z", n_z, *N_Z_RANGE)


def check_dz(dz) -> float:
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
    >>> from service.recon.checks import check_dz
    >>> check_dz(5e-5)
    5e-05
    >>> check_dz(1.0)
    Traceback (most recent call last):
    ...
    service.recon.checks.OptionError: dz must be in [1e-09, 0.1] m, got 1.0
    """
    v = _number("dz", dz, "a depth spacing in m")
    if not np.isfinite(v) or not DZ_RANGE[0] <= v <= DZ_RANGE[1]:
        raise OptionError(f"dz must be in [1e-09, 0.1] m, got {dz!r}")
    return v


def check_lam(lam) -> float:
    """The TV weight λ: a finite number in ``LAM_RANGE`` ([0, 1e30]).

    Parameters
    ----------
    lam : float
        Weight of the total-variation term of ½‖A p0 − g‖² + λ TV(p0) (`service.recon.tv`:
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
    >>> from service.recon.checks import check_lam
    >>> check_lam(0)
    0.0
    >>> check_lam(-1)
    Traceback (most recent call last):
    ...
    service.recon.checks.OptionError: lam (the TV weight λ) must be in [0, 1e+30], got -1
    """
    v = _number("lam (the TV weight λ)", lam, "a number >= 0")
    if not np.isfinite(v) or not LAM_RANGE[0] <= v <= LAM_RANGE[1]:
        raise OptionError(f"lam (the TV weight λ) must be in [0, 1e+30], got {lam!r}")
    return v


def check_bandwidth(bandwidth) -> float:
    """A sensor bandwidth the caller declares, Hz: a finite number in ``BANDWIDTH_RANGE``
    ([1e3, 1e12]); tv works at that band instead of the one it reads off the data
    (`service.recon.tv_grid`).

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
    >>> from service.recon.checks import check_bandwidth
    >>> check_bandwidth("2e7")  # Hz
    20000000.0
    >>> check_bandwidth(0)
    Traceback (most recent call last):
    ...
    service.recon.checks.OptionError: bandwidth (the sensor's band, Hz) must be in [1e+03, 1e+12], got 0
    """
    v = _number("bandwidth (the sensor's band, Hz)", bandwidth, "a number > 0")
    if not np.isfinite(v) or not BANDWIDTH_RANGE[0] <= v <= BANDWIDTH_RANGE[1]:
        raise OptionError(f"bandwidth (the sensor's band, Hz) must be in [{BANDWIDTH_RANGE[0]:.0e}, "
                          f"{BANDWIDTH_RANGE[1]:.0e}], got {bandwidth!r}")
    return v


def check_tol(tol) -> float:
    """The model-based solver's stopping threshold: a number in ``TOL_RANGE`` ([0, 0.5]).

    Parameters
    ----------
    tol : float
        Stop when the image's relative change per iteration, ‖x_k − x_{k−1}‖ / ‖x_k‖, has
        stayed below ``tol`` for the last 3 iterations (`service.recon.tv`); 0: run every
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
    >>> from service.recon.checks import check_tol
    >>> check_tol(0.01)
    0.01
    >>> check_tol(1)
    Traceback (most recent call last):
    ...
    service.recon.checks.OptionError: tol (the stopping threshold) must be in [0, 0.5], got 1
    """
    v = _number("tol (the stopping threshold)", tol, "a number in [0, 0.5]")
    if not np.isfinite(v) or not TOL_RANGE[0] <= v <= TOL_RANGE[1]:
        raise OptionError(f"tol (the stopping threshold) must be in [0, 0.5], got {tol!r}")
    return v


def check_iterations(iterations) -> int:
    """The most iterations of the model-based solver: an integer in ``ITERATIONS_RANGE`` (1..100000).

    Parameters
    ----------
    iterations : int or integral float

    Returns
    -------
    int

    Raises
    ------
    OptionError
        (a ValueError) not an integer, or outside the range.

    Examples
    --------
    >>> from service.recon.checks import check_iterations
    >>> check_iterations(200)
    200
    >>> check_iterations(0)
    Traceback (most recent call last):
    ...
    service.recon.checks.OptionError: iterations must be an integer in 1..100000, got 0
    """
    return _integer("iterations", iterations, *ITERATIONS_RANGE)


def check_time_limit(seconds) -> float:
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
    >>> from service.recon.checks import check_time_limit
    >>> check_time_limit(60)
    60.0
    >>> check_time_limit(0)
    Traceback (most recent call last):
    ...
    service.recon.checks.OptionError: time_limit must be in (0, 604800] s, got 0
    """
    v = _number("time_limit", seconds, "a number of seconds")
    if not np.isfinite(v) or not 0 < v <= TIME_LIMIT_MAX:
        raise OptionError(f"time_limit must be in (0, {TIME_LIMIT_MAX:g}] s, got {seconds!r}")
    return v


def check_dtype(dtype) -> np.dtype:
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
    >>> from service.recon.checks import check_dtype
    >>> check_dtype("float32")
    dtype('float32')
    >>> check_dtype("int16")
    Traceback (most recent call last):
    ...
    service.recon.checks.OptionError: dtype must be float32 or float64, got int16
    """
    if isinstance(dtype, str) and len(dtype) > 32:  # no dtype name is longer; NumPy's parser is not fed text
        raise OptionError(f"dtype must be float32 or float64, got {dtype[:32]!r}...")
    try:
        dt = np.dtype(dtype)
    except (TypeError, ValueError, SyntaxError):  # NumPy's parser raises SyntaxError for "(1,2"
        raise OptionError(f"dtype must be float32 or float64, got {dtype!r}") from None
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
    >>> from service.recon.checks import available_memory
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


#: `estimate_peak_memory`'s bound of k-Wave's time-depth step buffers and other work arrays beside
#: the input and the spectrum: the prime-factor stages' per-thread work arrays, the chunks' spectra,
#: the pchip mapping's arrays (`service.recon.kwave._CUBIC_BYTES` each). Measured as a fresh
#: process's resident peak (VmHWM) beyond input + spectrum: 122-127 MiB at 1024 x 100 x 226,
#: 1024 x 226² and 2048 x 60 x 226 in float64, any interpolation; lower elsewhere
KWAVE_STEP_BYTES = 160 << 20


def estimate_peak_memory(
    n_t: int,
    n_x: int,
    n_y: int = 1,
    *,
    n_z: int | None = None,
    upsample: int = 1,
    dtype=np.float64,
    method: str = "ner",
    n_points: int | None = None,
    dx: float | None = None,
    dt: float | None = None,
    c: float | None = None,
    dz: float | None = None,
    square: bool | None = None,
) -> int:
    """Estimated peak memory in bytes of a planar reconstruction (admission control).

    The planar methods (`service.recon.planar`) are counted phase by phase, the arrays
    alive in each (b: the real itemsize, complex 2b): the lateral spectrum A (n_t x
    n_y x (n_x/2+1); NEDNER's type-1 output is the full plane n_t x n_y x n_x, of which A is
    a view), alive to the end; the temporal fine grid U (columns x L), the evaluated
    spectrum F and its transposed k-space image K (depth rows x columns), F and the image in
    A's memory and K in U's (`service.recon.planar._workspace`); K zero-padded
    for ``upsample`` u (u² times larger); the inverse lateral FFT, in place on the padded K
    (`driver.physics.lateral.irfft_lateral`), beside its output (depth rows x n_y u x n_x u
    of the grid asked for: the padding is not written). The peak is the largest phase,
    plus the input (measured within ±25 % for ner/nedner at upsample 1-8,
    tests/service/test_memory_admission.py). k-Wave's modes (``"kwave"``,
    `service.recon.kwave`): their lateral half spectrum (n_t x n_y x (n_x/2+1), unpadded),
    over which the image is written, and the time-depth step's buffers
    (`KWAVE_STEP_BYTES`, or a fifth of the spectrum where that step runs as FFTs), plus the
    input.

    Parameters
    ----------
    n_t : int
        Samples per A-line.
    n_x, n_y : int
        Lateral grid (``n_y = 1`` in 2-D). The planar methods zero-pad it to the fast
        transform lengths of ``driver.physics.fast_lengths.fast_lateral`` (e.g. 226 -> 240),
        and the estimate counts those.
    n_z : int, optional
        Output depth samples (default n_t).
    upsample : int, optional
        Lateral upsampling factor.
    dtype : float32 or float64, optional
        Working precision.
    method : str, optional
        ``"ner"``, ``"linear"``, ``"nearest"``, ``"cubic"``, ``"nedner"``, ``"kwave"`` or
        ``"tv"``.
    n_points : int, optional
        Sensors, for NEDNER (its weighted A-lines, the full-plane type-1 spectrum and, for
        weights not given, the Voronoi raster of ``driver.physics.weights``) and tv.
    dx, dt, c, dz : float, optional
        Pitch (m), sample interval (s), sound speed (m/s), depth spacing (m; default c·dt):
        with ``method="tv"`` the estimate is `tv_memory` on the free-space operator's padded
        grid (`driver.physics.forward`'s padding rule); without them on a conservative one
        (dx = c·dt).
    square : bool or None, optional
        dy = dx, which may give both axes one transform length; None: unknown, the larger of
        the two.

    Returns
    -------
    int
        Bytes at the peak (4 % above the count for allocator and FFT-plan overheads).

    Examples
    --------
    >>> import numpy as np
    >>> from service.recon import estimate_peak_memory
    >>> est = estimate_peak_memory(256, 64, 64)  # (n_t, n_y, n_x) = (256, 64, 64), float64 NER
    >>> est > 256 * 64 * 64 * 8  # more than the input
    True
    >>> estimate_peak_memory(256, 64, 64, dtype=np.float32) < est
    True
    """
    b = np.dtype(dtype).itemsize
    cb = 2 * b
    n_z = n_t if n_z is None else n_z
    n_in = n_t * n_y * n_x  # the input, as given
    n_y0, n_x0 = n_y, n_x
    if method not in ("tv", "kwave"):  # the transform sizes the planar methods use
        n_y, n_x = padded_lateral(n_y, n_x, square)
        n_z = fast_dct1_rows(max(int(n_z), 2))  # the depth rows the transform works on
    cols = n_y * (n_x // 2 + 1)
    spectrum = n_t * cols * cb
    if method in ("ner", "nedner"):
        from driver.physics.grid_sizes import grid_length

        fine = cols * grid_length(n_t, "nufft", 1e-6) * cb  # make_grid's L, without loading the kernels
    else:
        fine = cols * (2 * n_t - 1) * cb
    kimage = n_z * cols * cb
    # the lateral spectrum's memory, which the evaluated spectrum F and the image reuse
    # (`service.recon.planar._workspace`); K is transposed into the fine grid's memory
    space = max(spectrum, kimage)
    u_y = upsample if n_y > 1 else 1
    padded = n_z * n_y * u_y * (n_x * upsample // 2 + 1) * cb if upsample > 1 else kimage
    out = n_z * n_y0 * u_y * n_x0 * upsample * b  # the grid asked for only (irfft_lateral's keep)
    alive = space  # held throughout: A (NEDNER's type-1 plane apart), then F, then the image
    front = 0
    if method == "nedner":  # type-1 NUFFT: the full plane, A a view of it; weighted A-lines (float64 + complex)
        plane = n_t * n_y * n_x * cb
        alive += plane
        front = plane + (n_points or 0) * n_t * (8 + cb)
        # the Voronoi raster of weights not given (driver.physics.weights: ~1024 samples per cell within
        # 2^20, ~80 bytes each; measured 82 MiB (tracemalloc) from 500 to 3000 sensors since its
        # steps free their arrays as they end, 98 MiB before)
        front = max(front, 80 * min(1024 * max(n_points or 0, 768), 1 << 20) if n_points else 0)
    if method == "cubic":  # pchip per column group: the mirrored series and its spectra in complex128
        fine = 5 * cols * (2 * n_t - 1) * 16
    # K in the fine grid's memory, or an array of its own (cubic: no fine grid; more depth rows than
    # the fine grid has); cubic's F is an array of its own too
    kmem = kimage if method == "cubic" or kimage > fine else fine
    f_apart = kimage if method == "cubic" else 0
    up = upsample > 1
    peak = max(front + space,
               alive + fine,                                 # temporal step: U, F in the space
               alive + kmem + f_apart,                       # F transposed into K
               alive + kmem + padded if up else 0,           # K zero-padded
               alive + padded + out if up else 0)            # inverse lateral FFT (in place, then out)
    if method == "kwave":  # `service.recon.kwave`: its lateral half spectrum, which takes the image too,
        # and the time-depth step's per-chunk buffers (matrix products: 16 MiB of spectra and the
        # prime-factor stages' work; FFTs of the mirrored series: ~32 chunks of 3 mirrored copies)
        peak = spectrum + max(KWAVE_STEP_BYTES, spectrum // 5)
    peak += n_in * b  # the input
    if method == "tv":  # model-based: its own count (the warm start needs less)
        n_data = n_t * (n_points or n_x * n_y)
        if dx and dt and c:  # the operator's own padding rule
            from driver.physics.grid_sizes import pad_sizes

            pad = pad_sizes((n_z, n_y, n_x), dx, dz or c * dt, dt, n_t, c, 0.0)
        else:  # the worst usual case dx = c dt (lateral reach of the record = n_t pitches)
            pad = (max(n_z, n_t), n_y + n_t if n_y > 1 else 1, n_x + n_t)
        return max(int(peak * 1.1), tv_memory((n_z, n_y, n_x), pad, n_data, n_t, dtype))
    return int(1.04 * peak)  # 4 % above the count: allocator and FFT-plan overheads


def padded_lateral(n_y: int, n_x: int, square: bool | None = None) -> tuple[int, int]:
    """The lateral transform sizes the planar methods use for an ``n_y x n_x`` grid.

    Parameters
    ----------
    n_y, n_x : int
        The lateral grid (``n_y = 1`` in 2-D).
    square : bool or None, optional
        dy = dx (``driver.physics.fast_lengths.fast_lateral``); None (pitches unknown): the
        larger of the square and non-square choices, axis by axis.

    Returns
    -------
    tuple of int
        ``(n_y', n_x')``.

    Examples
    --------
    >>> from service.recon.checks import padded_lateral
    >>> padded_lateral(226, 226)
    (240, 240)
    >>> padded_lateral(1, 226)
    (1, 240)
    """
    if square is not None:
        return fast_lateral(n_y, n_x, square)
    (ay, ax), (by, bx) = fast_lateral(n_y, n_x, False), fast_lateral(n_y, n_x, True)
    return max(ay, by), max(ax, bx)


#: the planar operator's working sizes (`service.recon.operator`), here beside the memory
#: model that counts them: time samples per batch of the lateral NUFFTs of point data, and
#: elements (complex) of a chunk's working arrays per row (its k-space columns run in
#: chunks of about this many elements, whole |k_lat| groups)
OPERATOR_BATCH = 16
OPERATOR_CHUNK = 1 << 22


def tv_memory(image_shape, padded_shape, n_data: int, n_t: int, dtype=np.float64) -> int:
    """Estimated peak bytes of the model-based reconstruction (`service.recon.tv`).

    The larger of two phases (`service.recon.tv._fista`). While the operator works: the
    solver's 3 image-sized vectors in ``dtype`` (the iterate x, y or the new iterate, the
    last preconditioned gradient; the adjoint writes its output over its k-space, where the
    system can release the rest) and the TV proximal map's dual (d vectors) at half those
    bytes (`service.recon.tv._store_dual`), beside the operator's working arrays in its working
    precision (complex64 for float32, complex128 for float64;
    `service.recon.operator.PlanarOperator`): the image's and the data's k-space in one array,
    max(n_z, n_t) per padded half-spectrum column, beside one chunk of columns in the depth and temporal
    steps (about `OPERATOR_CHUNK` elements per row; the temporal fine grid L,
    `driver.physics.grid_sizes.grid_length`, beside the depth N_z or the time n_t, whichever is
    longer: the steps hold two of them at a time) and one batch of full lateral spectra of
    the point NUFFTs. While the proximal map works: 4 + d vectors (x, the gradient step, the
    preconditioned gradient, the new iterate and the dual at full precision). The
    preconditioner P is computed where it is applied, on the image padded to fast lengths
    after the operator's arrays are freed. Both phases add the data-sized vectors (the data
    in float64, A x, A y and a residual in ``dtype``), and the estimate 15 % (allocator, FFT
    buffers and plans;
    tests/service/test_memory_admission.py measures it within 25 %).

    Parameters
    ----------
    image_shape : tuple of int
        p0's shape ``(n_z, n_y, n_x)`` (``n_y = 1`` in 2-D).
    padded_shape : tuple of int
        The operator's working grid ``(N_z, N_y, N_x)``.
    n_data : int
        Data samples (n_t times the number of sensors).
    n_t : int
        Samples per A-line.
    dtype : float32 or float64, optional

    Returns
    -------
    int
        Bytes.

    Examples
    --------
    >>> from service.recon.checks import tv_memory
    >>> small = tv_memory((32, 64, 64), (128, 128, 128), 256 * 4096, 256)
    >>> tv_memory((64, 64, 64), (128, 128, 128), 256 * 4096, 256) > small  # deeper image
    True
    >>> tv_memory((32, 64, 64), (128, 128, 128), 256 * 4096, 256, "float32") < small
    True
    """
    from driver.physics.grid_sizes import grid_length

    b = np.dtype(dtype).itemsize
    n_img = int(np.prod(image_shape))
    d = sum(1 for n in image_shape if n > 1)
    nz2, ny2, nx2 = padded_shape
    cols = ny2 * (nx2 // 2 + 1)
    fine = grid_length(n_t)
    chunk = min(cols, max(1, OPERATOR_CHUNK // max(nz2, fine)))
    operator = 2 * b * (cols * max(image_shape[0], n_t) + chunk * (fine + max(nz2, n_t))
                        + 2 * min(OPERATOR_BATCH, n_t) * ny2 * nx2)
    with_operator = 3 * n_img * b + d * n_img * b // 2 + operator
    proximal = (4 + d) * n_img * b
    return int(1.15 * (max(with_operator, proximal) + n_data * (8 + 3 * b)))


def check_memory(needed: int, memory_limit) -> None:
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
    >>> from service.recon.checks import check_memory
    >>> check_memory(2**20, 2**30)
    >>> check_memory(2**31, 2**30)
    Traceback (most recent call last):
    ...
    ValueError: reconstruction needs about 2.00 GiB at its peak, more than the limit of 1.00 GiB; ...
    """
    limit = available_memory() if memory_limit is None else int(memory_limit)
    if needed > limit:
        raise ValueError(
            f"reconstruction needs about {needed / 2**30:.2f} GiB at its peak, more than the "
            f"limit of {limit / 2**30:.2f} GiB; reduce n_t, n_z, the grid or upsample, or use float32"
        )
