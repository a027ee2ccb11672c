"""Exact planar Fourier inversion: NER-NUFFT, NEDNER-NUFFT and FFT + interpolation.

Implements the exact inversion formula (paper eqs. (1)-(5); Xu, Feng & Wang 2002;
Haltmeier, Scherzer & Zangerl 2009) in this discrete form, for data g on a lateral grid (or
at sensors x_m with area weights h_m) and samples t_n = t0 + n dt, n = 0..N_t-1::

    A(k_lat, n) = Σ_x g(x, t_n) e^{-i k_lat·x}          (grid: FFT)
               = Σ_m (h_m / ΔA) g_m(t_n) e^{-i k_lat·x_m} (sensors: type-1 NUFFT, ΔA = dx dy)
    E(k_lat, ω) = Σ_n A(k_lat, n) 2 cos(ω t_n)           (t_0 = 0 counted once)
    F(k_lat, k_z,l) = (c² dt Δk / π) (k_z,l / ω) E(k_lat, ω),   ω = c sqrt(|k_lat|² + k_z,l²)
                      (k_z/ω := 1/c at ω = 0; F := 0 where ω > π/dt)
    p0(x, z_j) = IDFT_lat [ DCT-I_z F ](x, z_j)

with k_z,l = l Δk, Δk = π / ((K - 1) dz), z_j = j dz, and DCT-I unnormalised
(y_j = x_0 + (-1)^j x_last + 2 Σ_{l=1}^{K-2} x_l cos(π l j/(K - 1))), computed on
K = max(n_z, ceil(c t_last / dz) + 1) depths (so that no recorded signal folds back
through the depth period 2 (K - 1) dz) and cropped to the n_z requested. The lateral
DFT/IDFT pair makes every dx, dy factor cancel; the constant makes a laterally uniform
layer come back exactly (g = p0(c t)/2).

Methods (the temporal step, `fpscan.physics.nufft`): ``ner`` evaluates E at the
non-equispaced ω with a type-2 NUFFT (error ~ eps); ``linear``, ``nearest`` interpolate E
from the regular DFT grid of the mirrored series (k-Wave style); ``cubic`` interpolates it
with pchip (Octave's interp2 'cubic'; its real and imaginary parts apart, and pchip's
monotone slopes depend on the values: the only method here that is not linear in the data,
nor exactly mirror-symmetric: 0.45 % of a point source's image, 3 % on white noise).
NEDNER (`reconstruct_points`) replaces the lateral FFT by a type-1 NUFFT (finufft) from the
sensor positions, batched over time samples.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from fpscan.constants import C_DEFAULT
from fpscan.physics import fft_engine, nufft, workspace
from fpscan.physics.axes import centred_axis, node_indices
from fpscan.physics.fast_lengths import fast_dct1_rows, fast_lateral, fast_length
from fpscan.physics.lateral import irfft_lateral, pad_spectrum
from fpscan.physics.nufft_plans import lateral_plan
from fpscan.physics.step_times import step
from fpscan.service.progress import Fraction, Rising, Span, rising
from fpscan.service.progress import span as span_of
from fpscan.service.recon import checks, memory
from fpscan.service.recon import device as devices
from fpscan.service.recon.depth import depth_grid
from fpscan.service.recon.reconstruction import Reconstruction

__all__ = ["GRID_METHODS", "transform_lengths", "reconstruct_grid", "reconstruct_points", "depth_axis", "default_grid", "check_grid"]

#: the methods `reconstruct_grid` runs (the method registry is `fpscan.service.recon.methods`)
GRID_METHODS = ("ner", "linear", "nearest", "cubic")
_KIND = {"ner": "nufft", "linear": "linear", "nearest": "nearest"}
#: the temporal step of each grid method in the memory model (`fpscan.service.recon.memory.planar_peak`)
_TEMPORAL_STEP = {"ner": "nufft", "linear": "regular", "nearest": "regular", "cubic": "pchip"}


def depth_axis(n_t: int, dt: float, c: float, dz: float | None, n_z: int | None,
               t0: float, pitch: float | None = None) -> tuple[float, int, int]:
    """The output depth grid and the working depth count of a record.

    The output grid is the one rule of every method (`fpscan.service.recon.depth.depth_grid`:
    the lateral ``pitch`` unless ``dz`` is given, c dt where the pitch is finer; the rows down
    to c t_last unless ``n_z`` is given). The working count also reaches the depth c t of the
    last sample, so that no recorded signal folds back into the image through the periodicity
    of the depth transform (period 2 (n_work - 1) dz), rounded up so that the depth transform
    runs at a fast FFT length (more rows than needed only lengthen the period; the rows asked
    for are cropped).

    Parameters
    ----------
    n_t : int
        Samples per A-line.
    dt : float
        Sample interval, s.
    c : float
        Sound speed, m/s.
    dz : float or None
        Depth spacing, m (None: the default spacing).
    n_z : int or None
        Output depth samples (None: down to c t_last).
    t0 : float
        Time of sample 0, s.
    pitch : float, optional
        The lateral pitch of the image's lattice, m (None: not known; the default spacing is
        then c dt).

    Returns
    -------
    tuple
        ``(dz, n_z, n_work)``: m, rows, rows.

    Raises
    ------
    ValueError
        ``dz`` or ``n_z`` out of range (``fpscan.service.recon.checks.OptionError``), or a ``dz``
        too fine to reach the last sample.

    Examples
    --------
    >>> from fpscan.service.recon.planar import depth_axis
    >>> depth_axis(256, 4e-8, 1500.0, None, None, 0.0, pitch=1e-4)  # the pitch, down to c t_last
    (0.0001, 154, 161)
    >>> depth_axis(256, 4e-8, 1500.0, None, None, 0.0)  # no pitch: c dt, n_t rows
    (6e-05, 256, 257)
    >>> depth_axis(256, 4e-8, 1500.0, 1.5e-4, 8, 0.0)[2]  # 8 rows asked, 109 worked on (a fast length)
    109
    """
    dz, n_z = depth_grid(n_t, dt, c, pitch, dz=dz, n_z=n_z, t0=t0)
    rows = c * (t0 + (n_t - 1) * dt) / dz * (1 - 1e-12)
    if not rows < 2**31:  # also inf (dz = 5e-324): refused before int() overflows
        raise ValueError(f"dz = {dz:g} m is too fine for this recording: the depth transform would need "
                         f"{rows:.3g} rows to reach c·t of the last sample; use a larger dz (c·dt is {c * dt:.3g} m)")
    reach = int(np.ceil(rows)) + 1
    return dz, int(n_z), fast_dct1_rows(max(int(n_z), reach))


def _temporal_length(n_t: int, method: str, eps: float) -> int:
    """Length of the temporal FFT ``method`` runs on series of n_t samples: the NUFFT's
    oversampled grid (ner) or the refined DFT grid of the mirrored series (linear,
    nearest: `fpscan.physics.nufft.make_grid`; cubic: `_cubic_columns`)."""
    if method == "cubic":
        return fast_length(2 * n_t - 1)
    return nufft.grid_length(n_t, _KIND[method], eps)


def transform_lengths(data_shape: Sequence[int], dt: float = 1.0, c: float = 1.0, *, method: str = "ner",
                      eps: float = 1e-6, dz: float | None = None, n_z: int | None = None, t0: float = 0.0,
                      upsample: int = 1, square: bool = True, pitch: float | None = None) -> dict[str, tuple[int, ...]]:
    """The FFT lengths `reconstruct_grid` runs for data of a given shape.

    Also those of `reconstruct_points` for a lattice of (n_y, n_x) grid nodes; the
    reconstruction chooses them with the same functions.

    Parameters
    ----------
    data_shape : tuple of int
        ``(n_t, n_x)`` or ``(n_t, n_y, n_x)``, time first.
    dt : float, optional
        Sample interval, s.
    c : float, optional
        Sound speed, m/s.
    method, eps, dz, n_z, t0, upsample
        As `reconstruct_grid` (dz in m, t0 in s).
    square : bool, optional
        dy = dx (default True).
    pitch : float, optional
        The lateral pitch dx, m: the default depth spacing (`depth_axis`; None: c dt).

    Returns
    -------
    dict of str to tuple of int
        ``"lateral"`` the forward lateral FFT lengths (``(n_x',)`` or ``(n_y', n_x')``),
        ``"temporal"`` ``(L,)`` the temporal FFT length, ``"depth"`` ``(2 (K - 1),)`` the FFT
        length of the depth DCT-I, ``"output"`` the inverse lateral FFT lengths (upsampled).

    Raises
    ------
    ValueError
        A bad shape or option (as `reconstruct_grid`).

    Examples
    --------
    >>> from fpscan.service.recon.planar import transform_lengths
    >>> transform_lengths((40, 32), dt=1e-4 / 1500, c=1500.0)
    {'lateral': (32,), 'temporal': (80,), 'depth': (80,), 'output': (32,)}
    >>> transform_lengths((256, 226, 226))["lateral"]  # padded to a fast length
    (240, 240)
    """
    shape = tuple(int(s) for s in data_shape)
    if len(shape) not in (2, 3) or shape[0] < 2 or min(shape) < 1:
        raise ValueError(f"data_shape must be (n_t, n_x) or (n_t, n_y, n_x) with n_t >= 2, got {data_shape!r}")
    dt, c, eps, _, upsample, t0 = _check_options(dt, c, method, eps, np.float64, upsample, t0)
    n_t = shape[0]
    n_y, n_x = (1, shape[1]) if len(shape) == 2 else shape[1:]
    _, _, n_work = depth_axis(n_t, dt, c, dz, n_z, t0, pitch)
    n_yp, n_xp = fast_lateral(n_y, n_x, square=square)
    lat = (n_xp,) if n_y == 1 else (n_yp, n_xp)
    return {"lateral": lat, "temporal": (_temporal_length(n_t, method, eps),), "depth": (2 * (n_work - 1),),
            "output": tuple(n * upsample for n in lat)}


def _check_options(dt: float, c: float, method: str, eps: float, dtype: npt.DTypeLike, upsample: int,
                   t0: float) -> tuple[float, float, float, np.dtype, int, float]:
    """Validate the options both reconstructions share; ValueError naming the problem."""
    dt = checks.positive("dt", dt)
    c = checks.positive("c", c)
    if method not in GRID_METHODS:
        raise ValueError(f"method must be one of {GRID_METHODS}, got {method!r}")
    upsample = checks.check_upsample(upsample)
    if not np.isfinite(t0) or t0 < 0:
        raise ValueError(f"t0 must be finite and >= 0 s, got {t0!r}")
    return dt, c, checks.check_eps(eps), checks.check_dtype(dtype), int(upsample), float(t0)


def _cubic_columns(A_cols: np.ndarray, n_t: int, klat2: np.ndarray, kz: np.ndarray, qw: np.ndarray, c: float,
                   dt: float, t0: float) -> np.ndarray:
    """Octave 'cubic' (pchip along ω) evaluation of the inversion, column by column
    group (columns sharing |k_lat|² share the query points)."""
    L = _temporal_length(n_t, "cubic", 0.0)
    a = A_cols.astype(np.complex128)
    if t0 == 0:
        a = a.copy()
        a[:, 0] *= 0.5
    import scipy.fft  # on use: this mode imports scipy.interpolate anyway

    S = scipy.fft.fft(a, n=L, axis=-1, workers=fft_engine.workers())
    # E on the DFT grid theta_j = 2 pi j / L of the mirrored series (L = 2 n_t - 1 rounded
    # up to a fast length: a finer grid), |j| <= (L - 1) // 2 (theta in (-pi, pi))
    j = np.arange(-((L - 1) // 2), (L - 1) // 2 + 1)
    theta = 2 * np.pi * j / L
    Ep = S[:, j % L]
    Em = S[:, (-j) % L]
    omega_grid = theta / dt
    ph = np.exp(-1j * omega_grid * t0)
    E = ph * Ep + np.conj(ph) * Em  # (n_cols, 2 n_t - 1)
    gvals, gptr, order = nufft.group_columns(klat2)
    from scipy.interpolate import PchipInterpolator  # on use: a slow import for one mode

    out = np.zeros((a.shape[0], len(kz)), np.complex128)
    for g, k2 in enumerate(gvals):
        cols = order[gptr[g] : gptr[g + 1]]
        om = c * np.sqrt(k2 + kz**2)
        ok = om * dt <= np.pi * (1 + 1e-12)
        q = np.minimum(om, omega_grid[-1])
        Ec = E[cols].T
        vals = (PchipInterpolator(omega_grid, Ec.real, axis=0, extrapolate=False)(q)
                + 1j * PchipInterpolator(omega_grid, Ec.imag, axis=0, extrapolate=False)(q))
        vals = np.nan_to_num(vals.real) + 1j * np.nan_to_num(vals.imag)
        w = np.where(om > 0, kz / np.where(om > 0, om, 1.0), 1.0 / c) * qw * ok
        out[cols] = (vals * w[:, None]).T
    return out


def _workspace(n_t: int, n_z: int, n_cols: int, rdtype: np.dtype) -> np.ndarray:
    """Memory for the lateral spectrum (n_t, n_cols) that `_invert` reuses for its depth
    spectrum (n_cols, n_z) and the image: max(n_t, n_z) n_cols complex values of the
    working precision (complex64 for float32), flat; from the work-array pool
    (`fpscan.physics.workspace`: an earlier call's, warm, once its image is dropped)."""
    return workspace.take(max(n_t, n_z) * n_cols, np.result_type(rdtype, np.complex64))


def _reuse(space: np.ndarray | None, shape: tuple[int, ...], dtype: npt.DTypeLike) -> np.ndarray | None:
    """``space``'s memory as a C-contiguous array of ``shape`` and ``dtype`` (its contents
    undefined), or None where ``space`` is None or too small (the step then makes its own).
    Every step of a reconstruction writes its result into memory an earlier step has
    already written, so that a call faults in fresh pages for two large arrays (this buffer
    and the fine temporal grid), not up to seven (docs/history/measurements.md, "NER's work arrays share
    memory")."""
    need = int(np.prod(shape)) * np.dtype(dtype).itemsize
    if space is None or space.nbytes < need or not space.flags.c_contiguous:
        return None
    return space.reshape(-1).view(np.uint8)[:need].view(dtype).reshape(shape)


def _invert(A: np.ndarray, n_x: int, dx: float, dy: float, dt: float, c: float, n_z: int,
            dz: float, t0: float, method: str, eps: float, rdtype: np.dtype, upsample: int,
            keep: tuple[int, int, int], progress: Span | None = None, space: np.ndarray | None = None) -> np.ndarray:
    """Lateral spectrum A (n_t, n_y, n_x//2+1) -> p0 (n_z, n_y*u, n_x*u) (see module doc),
    of which the leading ``keep`` (rows, y, x) are returned: the grid asked for inside the
    padded transform grid, C-contiguous (the inverse lateral FFT runs on the kept depth
    rows only and writes the kept samples only, `fpscan.physics.lateral.irfft_lateral`).
    (The forward model's true adjoint is `fpscan.service.recon.operator.PlanarOperator.adjoint`.)

    ``progress`` (optional: the caller's :func:`fpscan.service.progress.span` over this step) is
    called as the steps finish, with fractions in proportion to each step's typical share of
    the run time. ``space`` (optional: `_workspace`, whose memory may hold A) is reused for
    the depth spectrum and the image; A is then overwritten. The fine temporal grid's
    memory holds the transposed depth spectrum."""
    n_t, n_y, n_xr = A.shape
    kx = 2 * np.pi * np.fft.rfftfreq(n_x, dx)
    ky = 2 * np.pi * np.fft.fftfreq(n_y, dy)
    klat2 = (ky[:, None] ** 2 + kx[None, :] ** 2).ravel()
    a = A.reshape(n_t, n_y * n_xr)  # time first: column c is a[:, c]
    dk = np.pi / ((n_z - 1) * dz)
    kz = dk * np.arange(n_z)
    qw = np.full(n_z, c * c * dt * dk / np.pi)
    ctype = np.complex64 if rdtype == np.float32 else np.complex128
    U = None
    if method == "cubic":
        F = _cubic_columns(a.T, n_t, klat2, kz, qw, c, dt, t0)
    else:
        grid = nufft.make_grid(n_t, _KIND[method], eps)
        U = nufft.to_fine_grid(a, grid, t0_is_zero=(t0 == 0))
        del a, A  # read: its memory (space) takes the depth spectrum
        if progress is not None:
            progress(0.3)
        with step("interpolation"):
            F = nufft.evaluate(U, grid, klat2, kz, qw, c, dt, t0, inversion=True,
                               progress=span_of(progress, 0.3, 0.75),
                               out=_reuse(space, (U.shape[0], n_z), U.dtype))
    if progress is not None:
        progress(0.75)
    with step("depth DCT-I"):
        F = np.ascontiguousarray(F, dtype=ctype)
        # DCT-I along depth of the real and imaginary parts (in place, through an interleaved view)
        F = fft_engine.dct1(F, axis=1, overwrite_x=True)
    with step("transpose"):
        K = _reuse(U, (n_z, n_y * n_xr), ctype)  # the fine grid is read: its memory takes K
        del U
        if K is None:
            K = np.empty((n_z, n_y * n_xr), dtype=ctype)
        nufft.transpose(F, K)
        K = K.reshape(n_z, n_y, n_xr)
        del F
    if progress is not None:
        progress(0.85)
    with step("inverse lateral FFT"):
        ups_y = n_y > 1
        if upsample > 1:
            K = pad_spectrum(K, n_y, n_x, upsample, ups_y)
        shape = ((n_y * upsample) if ups_y else n_y, n_x * upsample)
        p0 = irfft_lateral(K[: keep[0]], shape, out=_reuse(space, keep, rdtype), keep=keep[1:])
        if upsample > 1:
            p0 *= upsample ** (2 if ups_y else 1)
    if progress is not None:
        progress(1.0)
    return p0.astype(rdtype, copy=False)


def _on_device(device: str, method: str, n_t: int, n_cols: int, n_work: int, n_out: int, eps: float,
               rdtype: np.dtype, data_elements: int, on_gpu: Callable[[], np.ndarray],
               on_cpu: Callable[[], np.ndarray]) -> tuple[np.ndarray, dict[str, Any]]:
    """Run an inversion where ``device`` says (`fpscan.service.recon.device.run`): the GPU path
    covers NER's temporal step only; its memory is `fpscan.service.recon.gpu.inversion_peak`. Returns
    the image and the params that say which device ran."""
    if device == "cpu":
        return on_cpu(), {"device": "cpu"}
    from fpscan.service.recon import gpu

    unsupported = None if method == "ner" else f"the temporal step {method!r} runs on the CPU only (the GPU's is NER's)"
    return devices.run(device, gpu.inversion_peak(n_t, n_cols, n_work, n_out, eps, rdtype, data_elements),
                       on_gpu, on_cpu, unsupported)


def reconstruct_grid(
    data: np.ndarray,
    dx: float,
    dt: float,
    c: float = C_DEFAULT,
    *,
    method: str = "ner",
    eps: float = 1e-6,
    dtype: npt.DTypeLike = np.float64,
    dz: float | None = None,
    n_z: int | None = None,
    upsample: int = 1,
    positivity: bool = False,
    t0: float = 0.0,
    dy: float | None = None,
    memory_limit: int | None = None,
    progress: Fraction | None = None,
    device: str = "auto",
) -> Reconstruction:
    """Reconstruct p0 from data on a regular sensor line or plane (NER-NUFFT by default).

    The exact planar Fourier inversion of the module docstring: lateral FFT, the temporal
    step (``method``), k_z/ω weighting, DCT-I in depth, inverse lateral FFT.

    Parameters
    ----------
    data : ndarray, shape ``(n_t, n_x)`` (line) or ``(n_t, n_y, n_x)`` (plane)
        Pressure in Pa, time first (k-Wave's 'ty' / 'tyz' order), samples at
        t_n = t0 + n dt.
    dx : float
        Lateral sensor spacing, m (also y unless ``dy`` is given).
    dt : float
        Sample interval, s.
    c : float, optional
        Sound speed, m/s (default 1500).
    method : {"ner", "linear", "nearest", "cubic"}, optional
        "ner" (default): NUFFT evaluation of the temporal transform at the non-equispaced
        frequencies (paper §3.1); the others: FFT on the regular frequency grid of the
        mirrored data + interpolation, as k-Wave.
    eps : float, optional
        NUFFT tolerance in [1e-14, 1e-1] (ner; default 1e-6).
    dtype : float32 or float64, optional
        Output dtype and working precision of the FFTs.
    dz : float, optional
        Output depth spacing, m (default the lateral pitch ``dx``, or c dt where that is
        finer: `fpscan.service.recon.depth.depth_grid`).
    n_z : int, optional
        Output depth samples, >= 2 (default: down to the depth c t_last the last sample reaches).
    upsample : int, optional
        Lateral upsampling factor 1..8 of the output grid (trigonometric interpolation; the
        paper uses 2).
    positivity : bool, optional
        Clip negative values of p0 to 0.
    t0 : float, optional
        Time of sample 0, s (>= 0).
    dy : float, optional
        Spacing along y, m (default dx).
    memory_limit : int, optional
        Bytes; default the memory available now.
    progress : callable, optional
        ``progress(fraction)`` called with increasing fractions in (0, 1] as the steps
        (lateral FFT, temporal step in chunks, depth transform, inverse lateral FFT) finish.
    device : {"auto", "cpu", "cuda"}, optional
        Where it runs (`fpscan.service.recon.device`): ``"auto"`` (default) the GPU where CuPy sees
        one and the request fits it (method ``"ner"`` only), else the CPU.

    Returns
    -------
    Reconstruction
        p0 of shape ``(n_z, n_x u)`` or ``(n_z, n_y u, n_x u)`` (u = upsample), row 0 at
        z = 0, lateral coordinates centred on the optical axis. ``params["depth_rows"]`` is K
        of the module docstring: at least the depth the last sample reaches, rounded up to a
        fast FFT length; ``params["device"]`` the device that ran (``"cpu"``/``"cuda"``).

    Raises
    ------
    ValueError
        Naming the problem: NaN/inf, wrong ndim/shape, non-positive dx/dt/c/dz, unknown
        method, eps outside [1e-14, 1e-1], bad dtype/upsample/n_z, t0 < 0, or an estimated
        peak memory above the limit; ``device="cuda"`` without a GPU, for another method
        than ``"ner"`` or beyond the GPU's free memory.
    fpscan.service.recon.device.GpuError
        The GPU failed during a ``device="cuda"`` run (``"auto"`` falls back to the CPU).

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", eqs. (1)-(5) and §3.1 (NER).
    .. [2] M. Xu, D. Feng, L. V. Wang, "Exact frequency-domain reconstruction for
       thermoacoustic tomography: I. Planar geometry", IEEE Trans. Med. Imaging 21 (2002).
    .. [3] M. Haltmeier, O. Scherzer, G. Zangerl, "A reconstruction algorithm for
       photoacoustic imaging based on the nonuniform FFT", IEEE Trans. Med. Imaging 28 (2009).

    Examples
    --------
    A laterally uniform layer comes back exactly: data g = p0(c t) / 2 at every sensor.

    >>> import numpy as np
    >>> from fpscan.service.recon.planar import reconstruct_grid
    >>> g = np.zeros((64, 8))  # (n_t, n_x)
    >>> g[10] = 0.5
    >>> r = reconstruct_grid(g, dx=1e-4, dt=1e-4 / 1500, c=1500.0)  # dz = c dt = 0.1 mm
    >>> r.p0.shape, r.p0.dtype, int(r.p0[:, 4].argmax()), round(float(r.p0[10, 4]), 4)
    ((64, 8), dtype('float64'), 10, 1.0)

    A point source (the exact forward model, `fpscan.physics.forward`) at depth row 8:

    >>> from fpscan.physics.forward import forward_grid
    >>> p0 = np.zeros((16, 32))
    >>> p0[8, 16] = 1.0
    >>> data = forward_grid(p0, dx=1e-4, dz=1e-4, dt=1e-4 / 1500, n_t=40, c=1500.0)
    >>> r = reconstruct_grid(data.astype(np.float32), 1e-4, 1e-4 / 1500, 1500.0, n_z=16,
    ...                      dtype=np.float32, upsample=2)
    >>> r.p0.shape, r.p0.dtype, np.unravel_index(r.p0.argmax(), r.p0.shape)  # x upsampled 2x
    ((16, 64), dtype('float32'), (np.int64(8), np.int64(32)))
    """
    with step("input check"):
        data = checks.finite_array("data", data, (2, 3))
    dx = checks.positive("dx", dx)
    dy = dx if dy is None else checks.positive("dy", dy)
    dt, c, eps, rdtype, upsample, t0 = _check_options(dt, c, method, eps, dtype, upsample, t0)
    n_t = data.shape[0]
    if n_t < 2:
        raise ValueError(f"data needs at least 2 time samples, got {n_t}")
    dz, n_z, n_work = depth_axis(n_t, dt, c, dz, n_z, t0, pitch=dx)  # the one depth rule (fpscan.service.recon.depth)
    is2d = data.ndim == 2
    n_y, n_x = (1, data.shape[1]) if is2d else data.shape[1:]
    n_yp, n_xp = fast_lateral(n_y, n_x, square=abs(dy - dx) <= 1e-9 * dx)
    checks.check_memory(
        memory.planar_peak(n_t, n_xp, n_yp, n_z=n_work, upsample=upsample, dtype=rdtype,
                           temporal=_TEMPORAL_STEP[method]),
        memory_limit,
    )
    vol = data.astype(rdtype, copy=False).reshape(n_t, n_y, n_x)
    kernel = rising(progress)  # strictly increasing fractions, each step through its span
    keep = (n_z, n_y * upsample if n_y > 1 else 1, n_x * upsample)

    def on_cpu() -> np.ndarray:
        with step("lateral FFT"):
            space = _workspace(n_t, n_work, n_yp * (n_xp // 2 + 1), rdtype)
            A = fft_engine.rfft2(vol, s=(n_yp, n_xp), axes=(1, 2),
                                 out=_reuse(space, (n_t, n_yp, n_xp // 2 + 1), space.dtype))
        if kernel is not None:
            kernel(0.1)
        return _invert(A, n_xp, dx, dy, dt, c, n_work, dz, float(t0), method, eps, rdtype, upsample, keep,
                       progress=span_of(kernel, 0.1, 1.0), space=space)

    def on_gpu() -> np.ndarray:
        from fpscan.service.recon import gpu

        xp = devices.gpu_module()
        A = xp.fft.rfft2(xp.asarray(vol), s=(n_yp, n_xp), axes=(1, 2))
        if kernel is not None:
            kernel(0.1)
        return xp.asnumpy(gpu.invert(xp, A, n_xp, dx, dy, dt, c, n_work, dz, float(t0), eps, rdtype, upsample, keep))

    p0, ran = _on_device(device, method, n_t, n_yp * (n_xp // 2 + 1), n_work, int(np.prod(keep)), eps, rdtype,
                         vol.size, on_gpu, on_cpu)
    if positivity:
        np.maximum(p0, 0, out=p0)
    x = centred_axis(n_x, dx)[0] + np.arange(n_x * upsample) * (dx / upsample)
    y = None if is2d else centred_axis(n_y, dy)[0] + np.arange(keep[1]) * (dy / upsample)  # one row stays one
    params = dict(method=method, dx=dx, dy=None if is2d else dy, dt=dt, sound_speed=c, eps=eps,
                  dtype=rdtype.name, dz=dz, n_z=n_z, upsample=upsample, positivity=bool(positivity),
                  t0=float(t0), n_t=n_t, data_shape=list(data.shape), depth_rows=n_work,
                  lateral_transform=[n_yp, n_xp], **ran)
    return Reconstruction(p0[:, 0, :] if is2d else p0, np.arange(n_z) * dz, x, y, params)


def _check_positions(positions: np.ndarray, n_points: int) -> np.ndarray:
    pos = checks.finite_array("positions", positions, (1, 2)).astype(np.float64)
    if pos.ndim == 1:
        pos = pos[:, None]
    if pos.shape[1] not in (1, 2):
        raise ValueError(f"positions must have shape (n_points, 1) or (n_points, 2), got {pos.shape}")
    if pos.shape[0] != n_points:
        raise ValueError(f"positions has {pos.shape[0]} rows but alines has {n_points} A-lines")
    if n_points > 1:
        if n_points <= 512:  # every pair (at most 131k distances): no scipy import for a small scan
            gap = np.sqrt(((pos[:, None, :] - pos[None, :, :]) ** 2).sum(axis=-1))
            np.fill_diagonal(gap, np.inf)
            nearest = gap.min(axis=1)
        else:
            from scipy.spatial import cKDTree  # on use: a slow import

            nearest = cKDTree(pos).query(pos, k=2)[0][:, 1]
        scale = max(float(np.abs(pos).max()), 1e-300)
        dup = nearest <= 1e-9 * scale
        if np.any(dup):
            i = int(np.flatnonzero(dup)[0])
            raise ValueError(f"positions contain duplicates (e.g. point {i} at {pos[i].tolist()})")
    return pos


def default_grid(pos: np.ndarray) -> tuple[tuple[np.ndarray, ...], float]:
    """The default output lattice of `reconstruct_points`: the smallest regular grid at the
    positions' lattice pitch (`fpscan.physics.weights.infer_pitch`; else the nearest
    neighbours' least distance) that covers them.

    Parameters
    ----------
    pos : ndarray
        Sensor positions ``(n_points, 1)`` x / ``(n_points, 2)`` (x, y), m.

    Returns
    -------
    tuple
        ``(axes, pitch)``: one coordinate vector per column of ``pos`` (x, then y; m) and the
        pitch (m).

    Raises
    ------
    ValueError
        A single position (it needs an explicit grid).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.planar import default_grid
    >>> axes, pitch = default_grid(np.array([[0.0], [2e-4], [6e-4]]))
    >>> np.round(axes[0] * 1e4, 6).tolist(), round(pitch * 1e4, 6)
    ([0.0, 2.0, 4.0, 6.0], 2.0)
    >>> default_grid(np.array([[0.0, 0.0]]))
    Traceback (most recent call last):
    ...
    ValueError: a single sensor position needs an explicit grid
    """
    from fpscan.physics.weights import infer_pitch  # on use: importing the plans package costs start-up time

    pitch = infer_pitch(pos) if len(pos) > 1 else None
    if pitch is None:
        if len(pos) < 2:
            raise ValueError("a single sensor position needs an explicit grid")
        from scipy.spatial import cKDTree  # on use: a slow import

        dist, _ = cKDTree(pos).query(pos, k=2)
        pitch = float(dist[:, 1].min())
    axes = []
    for a in range(pos.shape[1]):
        lo, hi = float(pos[:, a].min()), float(pos[:, a].max())
        n = int(round((hi - lo) / pitch)) + 1
        axes.append(lo + pitch * np.arange(n))
    return tuple(axes), pitch


def check_grid(grid: np.ndarray | Sequence[npt.ArrayLike], d: int) -> tuple[np.ndarray, ...]:
    """An output lattice given to `reconstruct_points`, checked: one finite, regular, increasing
    coordinate vector of at least 2 points per column of the positions.

    Parameters
    ----------
    grid : ndarray or sequence of array_like
        The x vector (1-D array) or ``(x, y)`` vectors, m.
    d : int
        The positions' columns (1: x; 2: x, y).

    Returns
    -------
    tuple of ndarray
        The vectors, float64.

    Raises
    ------
    ValueError
        Not ``d`` vectors, a non-finite vector, fewer than 2 points, or not regular and increasing.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.planar import check_grid
    >>> [g.tolist() for g in check_grid(np.array([0.0, 1e-4, 2e-4]), 1)]
    [[0.0, 0.0001, 0.0002]]
    >>> check_grid([np.array([0.0, 1e-4, 3e-4])], 1)
    Traceback (most recent call last):
    ...
    ValueError: grid x must be regular and increasing
    """
    if isinstance(grid, np.ndarray) and grid.ndim == 1:
        grid = (grid,)
    grid = tuple(grid)
    if len(grid) != d:
        raise ValueError(f"grid must hold {d} coordinate vector(s) for positions with {d} column(s)")
    out = []
    for name, g in zip("xy", grid):
        g = checks.finite_array(f"grid {name}", g, (1,)).astype(np.float64)
        if len(g) < 2:
            raise ValueError(f"grid {name} needs at least 2 points")
        step = np.diff(g)
        if step[0] <= 0 or np.max(np.abs(step - step[0])) > 1e-6 * step[0]:
            raise ValueError(f"grid {name} must be regular and increasing")
        out.append(g)
    return tuple(out)


def _type1(strengths: np.ndarray, pos: np.ndarray, axes: tuple[np.ndarray, ...], dx: float, dy: float, n_y: int,
           n_x: int, eps: float, rdtype: np.dtype, progress: Span | None) -> np.ndarray:
    """Lateral type-1 NUFFT (finufft) of the weighted A-lines ``strengths`` (n_t, n_points)
    onto the (n_y, n_x) transform grid's wavenumbers: (n_t, n_y, n_x) complex, with the
    y-Nyquist row split band-limited (see below). Paper eq. (5). ``progress`` (optional: the
    caller's :func:`fpscan.service.progress.span` over this step) is called as the chunks finish."""
    n_t = strengths.shape[0]
    d = pos.shape[1]
    ctype = strengths.dtype
    ftype = np.float32 if rdtype == np.float32 else np.float64
    tx = 2 * np.pi * (pos[:, 0] - axes[0][0]) / (n_x * dx)
    # single precision honours a type-1 tolerance of about 2e-5 at oversampling 1.25 (a
    # tighter one makes FINUFFT shrink its kernel and warn of catastrophic cancellation)
    eps_nu = max(eps, 2e-5) if rdtype == np.float32 else eps
    # one thread: batched type-1 transforms with 2 threads were ~40x slower on 2 busy cores;
    # oversampling 1.25 keeps the batched FFTs small (FINUFFT supports it down to ~1e-9)
    upsampfac = 1.25 if eps_nu >= 1e-9 else 2.0
    # the batched type-1 transforms in a few chunks of time samples (each transform is
    # independent of the others), so that progress is reported through this step too
    # planned once per mask and chunk size (fpscan.physics.nufft_plans): the live preview,
    # repeated jobs on one plan and the model-based iterations only execute
    A = np.empty((n_t, n_y, n_x), dtype=ctype)
    n_chunks = min(4, n_t)
    size = -(-n_t // n_chunks)
    coords = (tx.astype(ftype),) if d == 1 else \
        ((2 * np.pi * (pos[:, 1] - axes[1][0]) / (n_y * dy)).astype(ftype), tx.astype(ftype))
    modes = (n_x,) if d == 1 else (n_y, n_x)
    for i, a in enumerate(range(0, n_t, size)):
        b = min(a + size, n_t)
        plan = lateral_plan(1, coords, modes, b - a, eps=eps_nu, isign=-1, dtype=ctype, upsampfac=upsampfac)
        plan.execute(np.ascontiguousarray(strengths[a:b]), out=A[a:b].reshape((b - a, *modes)))
        if progress is not None:
            progress((i + 1) / n_chunks)
    if d == 2 and n_y % 2 == 0:
        # The y-Nyquist row holds the aliased pair ±π/dy; off-grid sensors make the two
        # differ, so take the band-limited (cosine) split: ½(A(-k_N, k_x) + A(+k_N, k_x)),
        # with A(+k_N, k_x) = conj(A(-k_N, -k_x)) for real data.
        r = n_y // 2
        if n_x % 2 == 0:
            # the corner also pairs with (-k_Ny, +k_Nx), which the FFT-ordered modes lack
            ph = np.exp(-1j * np.pi * (-(pos[:, 1] - axes[1][0]) / dy + (pos[:, 0] - axes[0][0]) / dx))
            corner = 0.5 * (A[:, r, n_x // 2] + strengths @ ph.astype(strengths.dtype))
        A[:, r, :] = 0.5 * (A[:, r, :] + np.conj(A[:, r, (-np.arange(n_x)) % n_x]))
        if n_x % 2 == 0:
            A[:, r, n_x // 2] = corner
    return A


def _output_grid(pos: np.ndarray, grid: np.ndarray | Sequence[npt.ArrayLike] | None,
                 ) -> tuple[tuple[np.ndarray, ...], list[float]]:
    """The output lateral grid of `reconstruct_points` and its steps (m): ``grid`` checked,
    or by default the smallest regular grid at the positions' lattice pitch covering them
    (`default_grid`). Raises ValueError when a position ``pos`` ``(n_points, d)`` m lies
    more than half a step outside the grid along an axis."""
    if grid is None:
        axes, pitch = default_grid(pos)
        steps = [float(g[1] - g[0]) if len(g) > 1 else pitch for g in axes]
    else:
        axes = check_grid(grid, pos.shape[1])
        steps = [float(g[1] - g[0]) for g in axes]
    for a, g in enumerate(axes):
        lo, hi = g[0] - steps[a] / 2, g[-1] + steps[a] / 2
        if np.any(pos[:, a] < lo - 1e-9 * abs(lo)) or np.any(pos[:, a] > hi + 1e-9 * abs(hi)):
            raise ValueError(f"positions lie outside the output grid along {'xy'[a]}")
    return axes, steps


def _area_weights(weights: np.ndarray | None, pos: np.ndarray) -> np.ndarray:
    """The area weights h_m ``(n_points,)`` (m in 2-D, m² in 3-D) of the positions ``pos``
    ``(n_points, d)`` m: ``weights`` checked (finite, that shape, >= 0: else ValueError), or
    by default the clipped Voronoi areas (`voronoi_weights`)."""
    if weights is None:
        from fpscan.physics.weights import voronoi_weights  # on use (start-up time)

        return voronoi_weights(pos)
    n_points = pos.shape[0]
    h = checks.finite_array("weights", weights, (1,)).astype(np.float64)
    if h.shape != (n_points,):
        raise ValueError(f"weights must have shape ({n_points},), got {h.shape}")
    if np.any(h < 0):
        raise ValueError("weights must be >= 0")
    return h


def _lateral_spectrum(al: np.ndarray, h: np.ndarray, pos: np.ndarray, axes: tuple[np.ndarray, ...],
                      steps: list[float], shape: tuple[int, int], eps: float, rdtype: np.dtype, space: np.ndarray,
                      kernel: Rising | None) -> np.ndarray:
    """The lateral step of `reconstruct_points` (paper eq. (5)): the A-lines ``al``
    ``(n_points, n_t)`` at ``pos``, weighted by ``h`` over the grid's cell area, to the half
    spectrum ``(n_t, n_y, n_x // 2 + 1)`` complex of the ``shape`` = ``(n_y, n_x)`` transform
    grid. When every position is a node of the grid (lattice masks) the type-1 sum is the FFT
    of the zero-filled grid, exactly and at FFT speed (written into ``space``); otherwise the
    type-1 NUFFT (`_type1`). ``kernel`` is told the first 30 % of the reconstruction's
    progress; the weighted copy of the A-lines is freed as soon as it is consumed."""
    d = pos.shape[1]
    n_t = al.shape[1]
    n_y, n_x = shape
    dx = steps[0]
    dy = steps[1] if d == 2 else 1.0
    cell = dx * (dy if d == 2 else 1.0)
    on_grid = node_indices(pos, axes, steps)
    if on_grid is not None:
        A = _reuse(space, (n_t, n_y, n_x // 2 + 1), space.dtype)
        assert A is not None
        if fft_engine.is_small(n_t * n_y * n_x):
            filled = np.zeros((n_t, n_y, n_x), dtype=rdtype)
            filled[:, on_grid[1], on_grid[0]] = (al * (h / cell)[:, None]).T
            A = fft_engine.rfft2(filled, axes=(1, 2), out=A)
        else:  # the weighted A-lines placed on their nodes slab by slab, on every core
            from fpscan.physics.array_kernels import place_points

            # the products in float64, rounded once to the working precision (as numpy's were)
            values = np.ascontiguousarray(al if al.dtype in (np.float32, np.float64) else al.astype(np.float64))
            scale = h / cell
            rows, cols = on_grid[1].astype(np.int64), on_grid[0].astype(np.int64)
            step = max(1, fft_engine.SLAB_BYTES // (n_y * n_x * rdtype.itemsize))
            buf = workspace.take((min(step, n_t), n_y, n_x), rdtype)

            def planes(a: int, b: int) -> np.ndarray:
                place_points(values, scale, rows, cols, a, buf[: b - a])
                return buf[: b - a]

            fft_engine.rfft2_planes(planes, n_t, n_y, n_x, out=A, step=step)
        if kernel is not None:
            kernel(0.3)
        return A
    weighted = (al * (h / cell)[:, None]).T  # (n_t, n_points)
    A = _type1(np.ascontiguousarray(weighted, dtype=space.dtype), pos, axes, dx, dy, n_y, n_x, eps, rdtype,
               span_of(kernel, 0.0, 0.3))
    del weighted
    return A[:, :, : n_x // 2 + 1]


def reconstruct_points(
    alines: np.ndarray,
    positions: np.ndarray,
    dt: float,
    c: float = C_DEFAULT,
    *,
    weights: np.ndarray | None = None,
    grid: np.ndarray | Sequence[npt.ArrayLike] | None = None,
    method: str = "ner",
    eps: float = 1e-6,
    dtype: npt.DTypeLike = np.float64,
    dz: float | None = None,
    n_z: int | None = None,
    upsample: int = 1,
    positivity: bool = False,
    t0: float = 0.0,
    memory_limit: int | None = None,
    progress: Fraction | None = None,
    device: str = "auto",
) -> Reconstruction:
    """NEDNER-NUFFT: reconstruct p0 from A-lines at arbitrary lateral positions.

    The lateral step is a type-1 NUFFT (finufft) from the positions to the grid's
    wavenumbers, batched over the time samples — or, when every position is a node of the
    grid (lattice masks), the FFT of the zero-filled grid, which is the same sum exactly; the
    rest is the pipeline of `reconstruct_grid`.

    Parameters
    ----------
    alines : ndarray, shape ``(n_points, n_t)``
        Pressure in Pa, samples at t_n = t0 + n dt.
    positions : ndarray, shape ``(n_points, 1)`` or ``(n_points, 2)``
        x (line sensor, 2-D image) or (x, y), m.
    dt : float
        Sample interval, s.
    c : float, optional
        Sound speed, m/s (default 1500).
    weights : ndarray, shape ``(n_points,)``, optional
        Area weights h_m (m in 2-D, m² in 3-D), >= 0 (paper eq. (5)); default the clipped
        Voronoi areas (`voronoi_weights`).
    grid : tuple of ndarray, optional
        Output lateral grid, ``(x,)`` or ``(x, y)`` regular coordinate vectors in m; default
        the smallest regular grid at the positions' lattice pitch covering them. Positions
        must lie within the grid (half a pitch of slack).
    method : {"ner", "linear", "nearest", "cubic"}, optional
        Temporal step, as `reconstruct_grid` ("ner", the default, is NEDNER-NUFFT).
    dtype : float32 or float64, optional
        As `reconstruct_grid`; in float32 the type-1 NUFFT runs at a tolerance of
        max(eps, 2e-5), the tightest single precision honours without FINUFFT shrinking its
        kernel (relative image error ~1e-5).
    eps, dz, n_z, upsample, positivity, t0, memory_limit
        As `reconstruct_grid` (the default depth spacing: the output grid's pitch along x).
    progress : callable, optional
        As `reconstruct_grid` (the type-1 NUFFT reports in chunks of time samples).
    device : {"auto", "cpu", "cuda"}, optional
        As `reconstruct_grid`; on the GPU the lateral step still runs here (finufft, or the
        zero-filled grid's FFT for lattice positions) and its spectrum is copied there.

    Returns
    -------
    Reconstruction
        p0 of shape ``(n_z, n_x u)`` or ``(n_z, n_y u, n_x u)`` on the grid (upsampled by u).

    Raises
    ------
    ValueError
        NaN/inf, wrong shapes, duplicated positions, positions outside the grid, negative or
        mis-sized weights, non-positive dt/c, bad eps/method/dtype, memory.

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", eq. (5) and §3.2 (NEDNER).

    Examples
    --------
    Every other sensor of a line, a point source at depth row 8 below x = 0.05 mm:

    >>> import numpy as np
    >>> from fpscan.physics.forward import forward_points
    >>> from fpscan.service.recon.planar import reconstruct_points
    >>> p0 = np.zeros((16, 32))  # (n_z, n_x), pitch 0.1 mm
    >>> p0[8, 16] = 1.0
    >>> x = (np.arange(32) - 15.5) * 1e-4  # the image's lateral axis, m
    >>> pos = x[::2, None]  # (16, 1) sensors, x in m
    >>> alines = forward_points(p0, positions=pos, dx=1e-4, dz=1e-4, dt=1e-4 / 1500, n_t=40, c=1500.0)
    >>> r = reconstruct_points(alines, pos, 1e-4 / 1500, 1500.0, n_z=16, grid=(x,))
    >>> r.p0.shape, np.unravel_index(r.p0.argmax(), r.p0.shape), r.params["method"]
    ((16, 32), (np.int64(8), np.int64(16)), 'nedner')
    """
    with step("input check"):
        al = checks.finite_array("alines", alines, (2,))
    n_points, n_t = al.shape
    if n_t < 2:
        raise ValueError(f"alines need at least 2 time samples, got {n_t}")
    with step("positions"):
        pos = _check_positions(positions, n_points)
    d = pos.shape[1]
    dt, c, eps, rdtype, upsample, t0 = _check_options(dt, c, method, eps, dtype, upsample, t0)
    with step("positions"):
        axes, steps = _output_grid(pos, grid)
    dz, n_z, n_work = depth_axis(n_t, dt, c, dz, n_z, t0, pitch=steps[0])  # the lattice's pitch: the depth rule's
    with step("weights"):
        h = _area_weights(weights, pos)
    n_x_out = len(axes[0])
    n_y_out = len(axes[1]) if d == 2 else 1
    square = d == 2 and abs(steps[1] - steps[0]) <= 1e-9 * steps[0]
    n_y, n_x = fast_lateral(n_y_out, n_x_out, square)  # transform sizes; the image is cropped back
    dx = steps[0]
    dy = steps[1] if d == 2 else 1.0
    checks.check_memory(
        memory.planar_peak(n_t, n_x, n_y, n_z=n_work, upsample=upsample, dtype=rdtype, points=True,
                           n_points=n_points),
        memory_limit,
    )
    kernel = rising(progress)  # strictly increasing fractions, each step through its span
    space = _workspace(n_t, n_work, n_y * (n_x // 2 + 1), rdtype)
    keep = (n_z, n_y_out * upsample if d == 2 else 1, n_x_out * upsample)

    def spectrum() -> np.ndarray:
        with step("lateral spectrum"):
            return _lateral_spectrum(al, h, pos, axes, steps, (n_y, n_x), eps, rdtype, space, kernel)

    def on_cpu() -> np.ndarray:
        return _invert(spectrum(), n_x, dx, dy, dt, c, n_work, dz, float(t0), method, eps, rdtype, upsample, keep,
                       progress=span_of(kernel, 0.3, 1.0), space=space)

    def on_gpu() -> np.ndarray:
        from fpscan.service.recon import gpu

        xp = devices.gpu_module()
        A = xp.asarray(spectrum())
        return xp.asnumpy(gpu.invert(xp, A, n_x, dx, dy, dt, c, n_work, dz, float(t0), eps, rdtype, upsample, keep))

    p0, ran = _on_device(device, method, n_t, n_y * (n_x // 2 + 1), n_work, int(np.prod(keep)), eps, rdtype, 0,
                         on_gpu, on_cpu)
    if positivity:
        np.maximum(p0, 0, out=p0)
    x = axes[0][0] + np.arange(n_x_out * upsample) * (dx / upsample)
    y = None if d == 1 else axes[1][0] + np.arange(n_y_out * upsample) * (dy / upsample)
    params = dict(method="nedner" if method == "ner" else method, temporal=method, dt=dt, sound_speed=c, eps=eps,
                  dtype=rdtype.name, dz=dz, n_z=n_z, upsample=upsample, positivity=bool(positivity),
                  t0=float(t0), n_t=n_t, n_points=n_points, depth_rows=n_work, lateral_transform=[n_y, n_x],
                  dx=dx, dy=dy if d == 2 else None,
                  weights="voronoi" if weights is None else "given", **ran)
    return Reconstruction(p0[:, 0, :] if d == 1 else p0, np.arange(n_z) * dz, x, y, params)
