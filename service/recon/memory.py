"""The peak-memory models of the reconstructions (admission control): bytes a method needs at
its peak, counted phase by phase from the arrays its kernels hold alive.

Each method declares its model (``fpscan.service.recon.methods``: ``Method.peak_memory``) from the
models here, named for what the kernels do, not for the methods: :func:`planar_peak` (the
planar inversions of ``fpscan.service.recon.planar``: the temporal step on a NUFFT grid, on the
regular grid or by pchip, a type-1 NUFFT over the sensor points or not),
:func:`kwave_peak` (``fpscan.service.recon.kwave``'s k-Wave modes) and :func:`model_based_peak`
(the model-based solve of ``fpscan.service.recon.tv`` on the free-space operator,
:func:`tv_memory`). ``fpscan.service.recon.methods.estimate_peak_memory`` asks the registry for a
method's model by name. The kernels check their own inputs against the same models before they allocate.
Measured against fresh processes' peaks in tests/service/test_memory_admission.py.
"""
from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from fpscan.physics import fft_engine
from fpscan.physics.fast_lengths import fast_dct1_rows, fast_lateral, fast_real_shape

__all__ = ["KWAVE_STEP_BYTES", "TEMPORAL_STEPS", "planar_peak", "kwave_peak", "band_columns",
           "model_based_peak", "padded_lateral", "OPERATOR_BATCH", "OPERATOR_CHUNK", "tv_memory"]

#: the bound of k-Wave's time-depth step buffers and other work arrays beside
#: the input and the spectrum: the prime-factor stages' per-thread work arrays, the chunks' spectra,
#: the pchip mapping's arrays (`fpscan.service.recon.kwave._CUBIC_BYTES` each). Measured as a fresh
#: process's resident peak (VmHWM) beyond input + spectrum: 122-127 MiB at 1024 x 100 x 226,
#: 1024 x 226² and 2048 x 60 x 226 in float64, any interpolation; lower elsewhere
KWAVE_STEP_BYTES = 160 << 20

#: the temporal steps :func:`planar_peak` counts: ``"nufft"`` (the NER/NEDNER NUFFT's fine grid),
#: ``"regular"`` (k-Wave-style interpolation on the regular frequency grid: linear, nearest),
#: ``"pchip"`` (Octave's 'cubic' along ω, per column group in complex128)
TEMPORAL_STEPS = ("nufft", "regular", "pchip")


def _planar_count(n_t: int, n_x: int, n_y: int, *, n_z: int | None, upsample: int, dtype: npt.DTypeLike,
                  temporal: str, points: bool, n_points: int | None, square: bool | None, pad: bool) -> int:
    """:func:`planar_peak`'s count before its margin (the input included)."""
    if temporal not in TEMPORAL_STEPS:
        raise ValueError(f"temporal must be one of {TEMPORAL_STEPS}, got {temporal!r}")
    b = np.dtype(dtype).itemsize
    cb = 2 * b
    n_z = n_t if n_z is None else n_z
    n_in = n_t * n_y * n_x  # the input, as given
    n_y0, n_x0 = n_y, n_x
    if pad:  # the transform sizes the planar methods use
        n_y, n_x = padded_lateral(n_y, n_x, square)
        n_z = fast_dct1_rows(max(int(n_z), 2))  # the depth rows the transform works on
    cols = n_y * (n_x // 2 + 1)
    spectrum = n_t * cols * cb
    if temporal == "nufft":
        from fpscan.physics.grid_sizes import grid_length

        fine = cols * grid_length(n_t, "nufft", 1e-6) * cb  # make_grid's L, without loading the kernels
    else:
        fine = cols * (2 * n_t - 1) * cb
    kimage = n_z * cols * cb
    # the lateral spectrum's memory, which the evaluated spectrum F and the image reuse
    # (`fpscan.service.recon.planar._workspace`); K is transposed into the fine grid's memory
    space = max(spectrum, kimage)
    u_y = upsample if n_y > 1 else 1
    padded = n_z * n_y * u_y * (n_x * upsample // 2 + 1) * cb if upsample > 1 else kimage
    out = n_z * n_y0 * u_y * n_x0 * upsample * b  # the grid asked for only (irfft_lateral's keep)
    alive = space  # held throughout: A (NEDNER's type-1 plane apart), then F, then the image
    front = 0
    if points:  # type-1 NUFFT: the full plane, A a view of it; weighted A-lines (float64 + complex)
        plane = n_t * n_y * n_x * cb
        alive += plane
        front = plane + (n_points or 0) * n_t * (8 + cb)
        # the Voronoi raster of weights not given (fpscan.physics.weights: ~1024 samples per cell within
        # 2^20, ~80 bytes each; measured 82 MiB (tracemalloc) from 500 to 3000 sensors since its
        # steps free their arrays as they end, 98 MiB before)
        front = max(front, 80 * min(1024 * max(n_points or 0, 768), 1 << 20) if n_points else 0)
    pchip = temporal == "pchip"
    if pchip:  # pchip per column group: the mirrored series and its spectra in complex128
        fine = 5 * cols * (2 * n_t - 1) * 16
    # K in the fine grid's memory, or an array of its own (pchip: no fine grid; more depth rows than
    # the fine grid has); pchip's F is an array of its own too
    kmem = kimage if pchip or kimage > fine else fine
    f_apart = kimage if pchip else 0
    up = upsample > 1
    peak = max(front + space,
               alive + fine,                                 # temporal step: U, F in the space
               alive + kmem + f_apart,                       # F transposed into K
               alive + kmem + padded if up else 0,           # K zero-padded
               alive + padded + out if up else 0)            # inverse lateral FFT (in place, then out)
    return peak + n_in * b  # the input


def planar_peak(n_t: int, n_x: int, n_y: int = 1, *, n_z: int | None = None, upsample: int = 1,
                dtype: npt.DTypeLike = np.float64, temporal: str = "nufft", points: bool = False,
                n_points: int | None = None, square: bool | None = None, **_: Any) -> int:
    """Estimated peak memory in bytes of a planar inversion (``fpscan.service.recon.planar``).

    Counted phase by phase, the arrays alive in each (b: the real itemsize, complex 2b): the
    lateral spectrum A (n_t x n_y x (n_x/2+1); with ``points``, the type-1 output is the full
    plane n_t x n_y x n_x, of which A is a view), alive to the end; the temporal fine grid U
    (columns x L), the evaluated spectrum F and its transposed k-space image K (depth rows x
    columns), F and the image in A's memory and K in U's (``fpscan.service.recon.planar._workspace``);
    K zero-padded for ``upsample`` u (u² times larger); the inverse lateral FFT, in place on
    the padded K (``fpscan.physics.lateral.irfft_lateral``), beside its output (depth rows x
    n_y u x n_x u of the grid asked for: the padding is not written). The peak is the largest
    phase, plus the input (measured within ±25 % for NER/NEDNER at upsample 1-8,
    tests/service/test_memory_admission.py).

    Parameters
    ----------
    n_t : int
        Samples per A-line.
    n_x, n_y : int
        Lateral grid (``n_y = 1`` in 2-D), zero-padded to the fast transform lengths of
        ``fpscan.physics.fast_lengths.fast_lateral`` (e.g. 226 -> 240), which are counted.
    n_z : int, optional
        Output depth samples (default n_t).
    upsample : int, optional
        Lateral upsampling factor.
    dtype : float32 or float64, optional
        Working precision.
    temporal : {"nufft", "regular", "pchip"}, optional
        The temporal step (:data:`TEMPORAL_STEPS`).
    points : bool, optional
        A type-1 NUFFT over ``n_points`` sensor points (NEDNER's lateral step) instead of an FFT
        of a full lattice.
    n_points : int, optional
        Sensors, with ``points`` (their weighted A-lines and, for weights not given, the
        Voronoi raster of ``fpscan.physics.weights``).
    square : bool or None, optional
        dy = dx, which may give both axes one transform length; None: unknown, the larger of
        the two.

    Returns
    -------
    int
        Bytes at the peak (4 % above the count for allocator and FFT-plan overheads).

    Raises
    ------
    ValueError
        An unknown ``temporal``.

    Examples
    --------
    >>> from fpscan.service.recon.memory import planar_peak
    >>> grid = planar_peak(256, 64, 64, dtype="float32")
    >>> planar_peak(256, 64, 64, dtype="float32", points=True, n_points=500) > grid  # the type-1 plane
    True
    """
    return int(1.04 * _planar_count(n_t, n_x, n_y, n_z=n_z, upsample=upsample, dtype=dtype, temporal=temporal,
                                    points=points, n_points=n_points, square=square, pad=True))


def kwave_peak(n_t: int, n_x: int, n_y: int = 1, *, dtype: npt.DTypeLike = np.float64, **_: Any) -> int:
    """Estimated peak memory in bytes of k-Wave's modes (``fpscan.service.recon.kwave``): their lateral
    half spectrum (n_t x n_y x (n_x/2+1), unpadded), over which the image is written, and the
    time-depth step's per-chunk buffers (:data:`KWAVE_STEP_BYTES`, or a fifth of the spectrum
    where that step runs as FFTs of the mirrored series), plus the input.

    Parameters
    ----------
    n_t : int
        Samples per A-line (and depth rows of the image).
    n_x, n_y : int
        Lateral grid (``n_y = 1`` in 2-D).
    dtype : float32 or float64, optional
        Working precision.

    Returns
    -------
    int
        Bytes at the peak (4 % above the count).

    Examples
    --------
    >>> from fpscan.service.recon.memory import KWAVE_STEP_BYTES, kwave_peak
    >>> kwave_peak(256, 64, 64) > KWAVE_STEP_BYTES
    True
    """
    cb = 2 * np.dtype(dtype).itemsize
    spectrum = n_t * n_y * (n_x // 2 + 1) * cb
    peak = spectrum + max(KWAVE_STEP_BYTES, spectrum // 5) + n_t * n_y * n_x * np.dtype(dtype).itemsize
    return int(1.04 * peak)


def model_based_peak(n_t: int, n_x: int, n_y: int = 1, *, n_z: int | None = None, dtype: npt.DTypeLike = np.float64,
                     n_points: int | None = None, dx: float | None = None, dt: float | None = None,
                     c: float | None = None, dz: float | None = None, warm_rows: int | None = None,
                     band: float | None = None, **_: Any) -> int:
    """Estimated peak memory in bytes of the model-based solve (``fpscan.service.recon.tv``): the larger
    of its warm start (a planar inversion on the unpadded grid with regular-grid steps, 10 %
    above the count) and the solve itself (:func:`tv_memory`) on the operator's padded grid.

    Parameters
    ----------
    n_t : int
        Samples per A-line.
    n_x, n_y : int
        Lateral grid (``n_y = 1`` in 2-D).
    n_z : int, optional
        Image depth samples (default n_t).
    dtype : float32 or float64, optional
        Working precision.
    n_points : int, optional
        Sensors (default every lattice point).
    dx, dt, c, dz : float, optional
        Pitch (m), sample interval (s), sound speed (m/s), depth spacing (m; default c·dt): the
        operator's own padding rule (``fpscan.physics.grid_sizes.pad_sizes``); without them the
        worst usual case dx = c·dt (the record reaches n_t pitches laterally).
    warm_rows : int, optional
        The depth rows the warm start works on (default ``n_z``; more where the kept record
        reaches deeper than the image: no sample may fold back through its depth period).
    band : float, optional
        The operator's band limit, Hz (with ``dx`` and ``c``; `band_columns`).

    Returns
    -------
    int
        Bytes at the peak.

    Examples
    --------
    >>> from fpscan.service.recon.memory import model_based_peak, planar_peak
    >>> model_based_peak(256, 64, 64, dtype="float32") > planar_peak(256, 64, 64, dtype="float32")
    True
    """
    n_z = n_t if n_z is None else n_z
    warm = _planar_count(n_t, n_x, n_y, n_z=max(n_z, warm_rows or 0), upsample=1, dtype=dtype, temporal="regular", points=False,
                         n_points=None, square=None, pad=False)
    n_data = n_t * (n_points or n_x * n_y)
    if dx and dt and c:  # the operator's own padding rule
        from fpscan.physics.grid_sizes import pad_sizes

        pad = pad_sizes((n_z, n_y, n_x), dx, dz or c * dt, dt, n_t, c, 0.0)
    else:  # the worst usual case dx = c dt (lateral reach of the record = n_t pitches)
        pad = (max(n_z, n_t), n_y + n_t if n_y > 1 else 1, n_x + n_t)
    kept = band_columns(pad, dx, c, band) if dx and c and band else None
    return max(int(warm * 1.1), tv_memory((n_z, n_y, n_x), pad, n_data, n_t, dtype, kept_columns=kept))


def band_columns(padded_shape: tuple[int, ...], dx: float, c: float, band: float) -> int:
    """The half-spectrum columns of a padded grid ``(N_z, N_y, N_x)`` at pitch ``dx`` (m) whose
    lateral wavenumber lies within a band (Hz) at sound speed ``c`` (m/s): |k_lat| <= 2π band / c,
    the columns a band-limited `fpscan.service.recon.operator.PlanarOperator` works on.

    Parameters
    ----------
    padded_shape : tuple of int
        The operator's working grid ``(N_z, N_y, N_x)`` (``N_y = 1`` in 2-D).
    dx : float
        Lateral pitch, m.
    c : float
        Sound speed, m/s.
    band : float
        The band limit, Hz.

    Returns
    -------
    int
        Columns of the ``N_y × (N_x // 2 + 1)`` half spectrum within the band.

    Examples
    --------
    >>> from fpscan.service.recon.memory import band_columns
    >>> band_columns((80, 64, 64), 60e-6, 1500.0, 12.5e6), 64 * 33  # the disc within the square
    (1634, 2112)
    """
    _, ny2, nx2 = padded_shape
    kx = 2 * np.pi * np.fft.rfftfreq(nx2, dx)
    ky = 2 * np.pi * np.fft.fftfreq(ny2, dx)
    return int(np.count_nonzero(ky[:, None] ** 2 + kx[None, :] ** 2 <= (2 * np.pi * band / c) ** 2))


def padded_lateral(n_y: int, n_x: int, square: bool | None = None) -> tuple[int, int]:
    """The lateral transform sizes the planar methods use for an ``n_y x n_x`` grid.

    Parameters
    ----------
    n_y, n_x : int
        The lateral grid (``n_y = 1`` in 2-D).
    square : bool or None, optional
        dy = dx (``fpscan.physics.fast_lengths.fast_lateral``); None (pitches unknown): the
        larger of the square and non-square choices, axis by axis.

    Returns
    -------
    tuple of int
        ``(n_y', n_x')``.

    Examples
    --------
    >>> from fpscan.service.recon.memory import padded_lateral
    >>> padded_lateral(226, 226)
    (240, 240)
    >>> padded_lateral(1, 226)
    (1, 240)
    """
    if square is not None:
        return fast_lateral(n_y, n_x, square)
    (ay, ax), (by, bx) = fast_lateral(n_y, n_x, False), fast_lateral(n_y, n_x, True)
    return max(ay, by), max(ax, bx)


#: the planar operator's working sizes (`fpscan.service.recon.operator`), here beside the memory
#: model that counts them: time samples per batch of the lateral NUFFTs of point data, and
#: elements (complex) of a chunk's working arrays per row (its k-space columns run in
#: chunks of about this many elements, whole |k_lat| groups)
OPERATOR_BATCH = 16
OPERATOR_CHUNK = 1 << 22


def tv_memory(image_shape: tuple[int, ...], padded_shape: tuple[int, ...], n_data: int, n_t: int,
              dtype: npt.DTypeLike = np.float64, kept_columns: int | None = None) -> int:
    """Estimated peak bytes of the model-based reconstruction (`fpscan.service.recon.tv`).

    The larger of two phases (`fpscan.service.recon.tv.fista.run_fista`). While the operator works: the
    solver's image-sized vector in ``dtype`` (y or the new iterate) and the adjoint's output, an
    image of its own (so that the k-space is free for the next application however long the
    solver keeps it: the operator's arrays are kept between applications,
    `fpscan.physics.workspace`), the last preconditioned
    gradient, the last move and, in the solver's exact phase, the last proximal step's s in int16
    (`fpscan.service.recon.tv.stores.store_gradient`, ``store_move``; `fpscan.service.recon.tv.fista`)
    and the TV proximal map's dual (d vectors) at half those bytes
    (`fpscan.service.recon.tv.stores.store_dual`), beside the operator's working arrays in its working
    precision (complex64 for float32, complex128 for float64;
    `fpscan.service.recon.operator.PlanarOperator`): the image's and the data's k-space in one array,
    max(n_z, n_t) per padded half-spectrum column (every column: the lateral transforms write them all,
    and a band limit skips columns in the depth and temporal steps only), beside one chunk of columns
    in the depth and temporal steps (about `OPERATOR_CHUNK` elements per row; the temporal fine grid L,
    `fpscan.physics.grid_sizes.grid_length`, beside the depth N_z or the time n_t, whichever is
    longer: the steps hold two of them at a time), one batch of full lateral spectra of
    the point NUFFTs and one slab of the lateral transforms (`fpscan.physics.fft_engine.SLAB_BYTES`).
    While the proximal map works: 2 + d + d/2 vectors (the gradient step,
    the preconditioned gradient, the dual at full precision beside the stored one,
    `fpscan.service.recon.tv.prox.tv_prox_stored`), the move and, in the exact phase, the gradient
    kept for the next gain test in int16, beside the operator's arrays that the work-array pool keeps
    for its next application (those of at least `fpscan.physics.workspace.MIN_BYTES`). The
    preconditioner P is computed where it is applied, on the image padded to fast lengths. The pool
    keeps every array it has lent, so each phase also holds the other's pooled arrays, free: the
    operator's phase the dual at full precision and P's padded image, the proximal map's P's padded
    image. Both phases add the data-sized vectors (the data
    in float64, A x, A y and a residual in ``dtype``), and the estimate 10 % (allocator, FFT
    buffers and plans). With the method's ``memory_calibration`` the estimate was 1.06-1.14 of the
    peak measured on five full-size scans (the paper's, cut and whole record; the three full-size
    members of tv's phantom family, `benchmarks/tv_family.py`) and 1.09-1.38 on the three smaller
    cases of tests/service/test_memory_admission.py (the most where the sensors sit on the lattice's
    nodes, which need no batch of full spectra).

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
    kept_columns : int, optional
        The half-spectrum columns a band-limited operator works on (`band_columns`; default
        all of them): the depth and temporal steps skip the columns above the band.

    Returns
    -------
    int
        Bytes.

    Examples
    --------
    >>> from fpscan.service.recon.memory import tv_memory
    >>> small = tv_memory((32, 64, 64), (128, 128, 128), 256 * 4096, 256)
    >>> tv_memory((64, 64, 64), (128, 128, 128), 256 * 4096, 256) > small  # deeper image
    True
    >>> tv_memory((32, 64, 64), (128, 128, 128), 256 * 4096, 256, "float32") < small
    True
    """
    from fpscan.physics import workspace
    from fpscan.physics.grid_sizes import grid_length

    b = np.dtype(dtype).itemsize
    n_img = int(np.prod(image_shape))
    d = sum(1 for n in image_shape if n > 1)
    nz2, ny2, nx2 = padded_shape
    every = ny2 * (nx2 // 2 + 1)  # the k-space's columns: the lateral transforms write every one
    cols = every if kept_columns is None else max(1, int(kept_columns))  # those the depth and temporal steps work on
    fine = grid_length(n_t)
    chunk = min(cols, max(1, OPERATOR_CHUNK // max(nz2, fine)))
    # the k-space, a chunk's fine-grid and depth arrays, a batch of full lateral spectra (complex), and one
    # slab of the lateral transforms' padded rows (`fpscan.physics.fft_engine.SLAB_BYTES`, real)
    plane = image_shape[1] * nx2 * b  # one padded row of the lateral transforms
    parts = (2 * b * every * max(image_shape[0], n_t), 2 * b * chunk * fine, 2 * b * chunk * max(nz2, n_t),
             2 * b * 2 * min(OPERATOR_BATCH, n_t) * ny2 * nx2,
             min(max(image_shape[0], n_t) * plane, max(fft_engine.SLAB_BYTES, plane)))
    operator = sum(parts)

    def pooled(nbytes: int) -> int:  # kept by the work-array pool once lent (`fpscan.physics.workspace.MIN_BYTES`)
        return nbytes if nbytes >= workspace.MIN_BYTES else 0

    kept = sum(pooled(p) for p in parts)
    # the preconditioner's image padded to fast lengths, and the proximal map's dual at full precision:
    # lent by the pool in their own phase and kept, free, through the other
    padded = fast_real_shape(tuple(int(n) for n in image_shape))
    preconditioner = pooled(int(np.prod(padded)) * b) if tuple(padded) != tuple(image_shape) else 0
    dual = d * n_img * b
    # y (or the new iterate), the adjoint's image, the stored dual, the last gradient, the last move and
    # (in the exact phase) the last proximal step's s as int16 (`tv.stores.store_gradient`, `tv.stores.store_move`)
    with_operator = (2 * n_img * b + d * n_img * b // 2 + 3 * 2 * n_img + operator + preconditioner
                     + pooled(dual))
    # the gradient step, G(A y − g), the move and (in the exact phase) the gradient kept for the next gain
    # test as int16, the dual at full precision beside the stored one, beside the operator's arrays,
    # which the work-array pool keeps for the next application
    proximal = 2 * n_img * b + 2 * 2 * n_img + dual + d * n_img * b // 2 + kept + preconditioner
    return int(1.10 * (max(with_operator, proximal) + n_data * (8 + 3 * b)))
