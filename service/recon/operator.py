"""The planar photoacoustic operator pair: p0 on a grid -> sensor data, and its adjoint.

`PlanarOperator` wraps the exact planar forward model of `fpscan.physics.forward`
(the wave problem of the paper §2) as a linear operator A with its true adjoint Aᴴ (= Aᵀ,
everything is real), for 2-D (line sensor, p0 of shape (n_z, n_x)) and 3-D (plane sensor,
(n_z, n_y, n_x)), with the sensors either on the image's lateral grid or at arbitrary
lateral positions. It is a `pylops.LinearOperator` (``dims`` = `ishape`, ``dimsd`` =
`oshape`), so every pylops/pyproximal solver runs on it; `forward` / `adjoint` take and
return arrays of the natural shapes.

The discrete sums (periodic case; the non-periodic default first zero-pads p0 to the
working grid (N_z, N_y, N_x) = `padded_shape`, the one `forward_grid` / `forward_points`
use, and crops/embeds accordingly). With F(k_lat, k_z,l) = dz Σ_x e^{-i k_lat·x}
DCT-I_z(p0)_l on the DFT lateral wavenumbers and k_z,l = l Δk, Δk = π / ((N_z - 1) dz),
τ_0 = τ_last = ½, τ_l = 1 otherwise::

    G(k_lat, t_n) = (Δk / 4π) Σ_l τ_l F(k_lat, k_z,l) 2 cos(c |k| t_n),   t_n = t0 + n dt
    forward (grid):   g(x, t_n)   = IDFT_lat G(·, t_n)(x)
    forward (points): g_m(t_n)    = Re Σ_k G(k, t_n) e^{i k·x_m} / (N_x N_y)

(the temporal sum is a type-1 NUFFT in time, the point evaluation a type-2 NUFFT with
finufft; both to the tolerance ``eps``). The adjoint applies the transposed steps in
reverse: lateral DFT of the data (grid) or a type-1 NUFFT from the sensor positions
Σ_m g_m e^{-i k·x_m} symmetrised to a Hermitian spectrum (points); the temporal type-2
NUFFT Σ_n a_n 2 cos(c |k| t_n) times dz Δk / 4π; the DCT-I in depth with both end rows
halved; the inverse lateral DFT; crop to the image. ⟨A x, y⟩ = ⟨x, Aᴴ y⟩ holds to the
NUFFT tolerance (dot test ~1e-12 at eps = 1e-12 in float64, ~1e-6 in float32).

Padding (`fpscan.physics.grid_sizes.pad_sizes`)
---------------------------------------------
The trigonometric model is periodic: laterally with period N dx, in depth (DCT-I) with
period 2 (N_z - 1) dz about the sensor plane. The data are exact free-space data of the
band-limited p0 as long as no periodic image of the image reaches a sensor within the
record, t <= t_last = t0 + (n_t - 1) dt. A source at depth z and lateral offset r from a
sensor is heard from time sqrt(z² + r²) / c on, never earlier (causality, in 2-D and
3-D alike), so:

- laterally, the gap between the image (and the sensors) and its nearest periodic copy,
  N dx - (n - 1) dx, must exceed the record's reach c t_last; the source that needs it
  is one in row 0 (a deeper one arrives later: sqrt(z² + r²) >= r), so the image's depth
  gives no discount. Sensors outside the image widen the gap by their overhang;
- in depth, the nearest non-physical image of a source at depth z lies at
  2 (N_z - 1) dz - z, so 2 (N_z - 1) dz >= c t_last + (n_z - 1) dz; no padding at all
  when the image already reaches deeper than half of that.

Both get a margin of half a sample and two lateral pitches (depth: one pitch) and are
rounded up to fast FFT lengths
(`fpscan.physics.fast_lengths`: the DCT-I's 2 (N_z - 1) and x's real FFT 5-smooth, y's
complex FFT 7-smooth; N_y = N_x where that pads at most 15 % more, so that columns of
equal |k_lat| share their temporal taps). Beyond that no padding reaches a sensor in the
record, hence the model is exact for it: tests/recon/test_recon_operator.py compares a
source touching the image's edge and its deepest row with the analytic free-space field
(2-D and 3-D, grid and points: ~3e-6 of the peak; the periodic model is off by more than
the peak). The rule is exact for what the record can hear, not for the trigonometric
interpolant's own tails: a source with a sharp edge at the image's border (a voxel-sized
box in its deepest corner) has sinc tails beyond the image whose periodic copies decay
only as 1/distance, and differs from a three times larger working grid by a few per cent
of its peak near the end of the record (with more margin as well: 2 % at five samples). The cost of a pair therefore grows with c t_last / dx: the padded lateral area
is (n + c t_last / dx)² against NER's n².

Cost
----
Everything that does not depend on the vector is made once per operator: the |k_lat|
groups of the temporal step, its fine grid, and the lateral NUFFT plans (point sensors;
`fpscan.physics.nufft_plans`). The transforms run in the working precision (float32:
complex64 and single-precision lateral NUFFTs at tolerance max(eps, 2e-5), oversampling
1.25; float64: complex128). The lateral FFTs skip what is known to be zero or cropped:
the forward transforms only the image's n_z rows (the padding rows are zero) and the
adjoint's inverse transforms only the image's rows and the n_y lines kept; the point
forward runs the temporal step on the half spectrum and completes it by Hermitian
symmetry for the type-2 NUFFT. Sensors that all sit on nodes of the working grid (a scan
plan's points are on the scanner's lattice, which is the image's lateral grid) need no
NUFFT at all: the point forward is the inverse lateral DFT read at their nodes (on the rows
that hold sensors only) and its adjoint the DFT of the data placed on their nodes — exact,
and without the NUFFT's oversampled grid (the tv solver at 256 × 128², 533 sensors, float32:
41 → 35 s). The temporal step gathers and scatters its chunks of columns in place
(`fpscan.physics.nufft.gather_columns` / `scatter_columns`: no copies of the chosen
columns; the same run 35 → 28 s), and a step's input and output k-space (image and data)
share one array, since a chunk reads its columns of the one whole before it writes them in
the other (tv at 512 × 128², 533 sensors, float32: peak 19.3 → 15.7 times the volume).
Every step runs on every core: the transforms on pocketfft's threads
(`fpscan.physics.fft_engine.workers`), and the copies, zero fills and scatters between them in
compiled parallel loops (`fpscan.physics.array_kernels`, `fpscan.physics.nufft`), each writing
every entry of its output, so that the k-space, the chunks' arrays and the images come from the
work-array pool (`fpscan.physics.workspace`) as they are: from the second application on, the
forward and the adjoint fault in no fresh pages. `benchmarks/bench_tv_operator.py` times a pair
against one NER of the same image; `benchmarks/bench_cpu_scaling.py` times its steps at 1 and 2
threads.

The adjoint is not the inverse: the inverse is the NER/NEDNER reconstruction
(`reconstruct_grid` / `reconstruct_points`), which weights k-space by k_z/ω instead.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
import pylops
import scipy.fft

from fpscan.constants import C_DEFAULT
from fpscan.physics import array_kernels, fft_engine, nufft, workspace
from fpscan.physics.axes import centred_axis, centred_index, node_indices
from fpscan.physics.grid_sizes import pad_sizes
from fpscan.physics.nufft_plans import lateral_plan
from fpscan.physics.step_times import step
from fpscan.service.recon import checks, memory

__all__ = ["PlanarOperator"]

#: elements (complex) per block of rows of the lateral FFTs
_BLOCK = 1 << 20
_BATCH = memory.OPERATOR_BATCH
_CHUNK = memory.OPERATOR_CHUNK

class PlanarOperator(pylops.LinearOperator):
    """The planar forward model A: p0 on a regular grid -> data at the sensors, with its adjoint.

    A ``pylops.LinearOperator`` (``dims`` = `ishape`, ``dimsd`` = `oshape`), so every
    pylops/pyproximal solver runs on it; `forward` / `adjoint` take and return arrays of the
    natural shapes. The adjoint is not the inverse (that is NER/NEDNER).

    Parameters
    ----------
    shape : tuple of int
        Image shape ``(n_z, n_x)`` (2-D) or ``(n_z, n_y, n_x)`` (3-D), n_z >= 2; row 0 at
        z = 0, lateral coordinates centred on the optical axis, x_i = (i - (n_x - 1)/2) dx.
    dx : float
        Lateral pitch, m (x and y).
    dz : float
        Depth spacing, m.
    dt : float
        Sample interval, s.
    n_t : int
        Samples per A-line (>= 1).
    c : float, optional
        Sound speed, m/s (default 1500).
    positions : ndarray, shape ``(n_points, 1)`` or ``(n_points, 2)``, optional
        None (default): sensors on the image's lateral grid, data ``(n_t, n_x)`` /
        ``(n_t, n_y, n_x)``, time first. Else x or (x, y) in m, centred coordinates as
        above; data ``(n_points, n_t)``.
    t0 : float, optional
        Time of sample 0, s (>= 0).
    eps : float, optional
        NUFFT tolerance in [1e-14, 1e-1] (default 1e-6).
    periodic : bool, optional
        Keep the grid's lateral/depth periodicity (no zero padding); the default False models
        free space exactly as `forward_grid` / `forward_points` do.
    dtype : float32 or float64, optional
        Dtype of the arrays returned and working precision of the transforms (complex64 /
        complex128).
    checkpoint : callable, optional
        ``checkpoint()``, called between the steps of `forward` and `adjoint` and inside
        their long steps (after each chunk of k-space columns, each batch of the point
        NUFFTs, each block of the lateral FFTs); it may raise to abandon the application (a
        cancelled job: `fpscan.service.recon.tv`). Settable later as the attribute ``checkpoint``.
    chunk_elements : int, optional
        The depth and temporal steps run on chunks of k-space columns of about this many
        elements per row of their largest array (default
        `fpscan.service.recon.memory.OPERATOR_CHUNK`, 2²³; the memory model counts one chunk); the
        result does not depend on it.
    band : float, optional
        A temporal band limit f_c in Hz (None, the default: none). The model's data are then
        those of the field low-passed at f_c, exactly: a k-space component of p0 sounds at
        the one frequency c |k| / 2π (the paper, eq. (1)), so the low-pass is the k-space ball
        |k| <= 2π f_c / c, applied to the depth transform's coefficients before the temporal
        step (and after it in the adjoint: the pair stays each other's transpose). Columns
        with |k_lat| beyond it are skipped whole. With f_c at most the Nyquist frequency
        1 / (2 dt) the samples carry no aliased energy, so data resampled to dt by an ideal
        low-pass (`fpscan.physics.resample`) are this model's data (`fpscan.service.recon.tv.grid`).
    device : {"auto", "cpu", "cuda"}, optional
        Where `forward` and `adjoint` run (`fpscan.service.recon.device.choose`; default ``"auto"``):
        on a GPU (`fpscan.service.recon.gpu.OperatorPair`, sensors on the grid or on its nodes) the
        arrays are copied there and back; the lock that keeps one job per GPU is the caller's
        (`fpscan.service.recon.device.run`).

    Attributes
    ----------
    ishape : tuple of int
        Image shape.
    oshape : tuple of int
        Data shape.
    padded_shape : tuple of int
        The working grid ``(N_z, N_y, N_x)`` (= the image shape when ``periodic``).
    dtype : numpy.dtype
        As given.
    device : str
        ``"cpu"`` or ``"cuda"``: where the pair runs.
    shape : tuple of int
        ``(prod(oshape), prod(ishape))``, the matrix shape pylops sees.

    Raises
    ------
    ValueError
        Naming the problem: bad shape, non-positive dx/dz/dt/c/band, n_t < 1, t0 < 0, eps outside
        its range, positions of the wrong shape, non-finite or duplicated, bad dtype, a bad
        device or ``device="cuda"`` where the GPU cannot run it (`fpscan.service.recon.device.Unsuited`);
        `forward`/`adjoint` raise it for arrays of the wrong shape or with NaN/inf.

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", eqs. (1)-(5) (the planar model it transposes).
    .. [2] M. Ravasi, I. Vasconcelos, "PyLops -- A linear-operator Python library for
       scalable algebra and optimization", SoftwareX 11 (2020).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.forward import forward_grid
    >>> from fpscan.service.recon import PlanarOperator
    >>> kw = dict(dx=1e-4, dz=1e-4, dt=1e-4 / 1500, n_t=40, c=1500.0)
    >>> op = PlanarOperator((16, 32), **kw)
    >>> op.ishape, op.oshape, op.shape  # p0 (n_z, n_x) -> data (n_t, n_x)
    ((16, 32), (40, 32), (1280, 512))
    >>> p0 = np.zeros((16, 32))
    >>> p0[8, 16] = 1.0
    >>> bool(np.allclose(op.forward(p0), forward_grid(p0, **kw)))  # the simulator's model
    True

    The adjoint is the true one (dot test):

    >>> rng = np.random.default_rng(0)
    >>> x, y = rng.standard_normal(op.ishape), rng.standard_normal(op.oshape)
    >>> lhs, rhs = np.vdot(op.forward(x), y), np.vdot(x, op.adjoint(y))
    >>> bool(abs(lhs - rhs) <= 1e-9 * abs(rhs))
    True
    """

    def __init__(self, shape: Sequence[int], dx: float, dz: float, dt: float, n_t: int, c: float = C_DEFAULT, *,
                 positions: npt.ArrayLike | None = None, t0: float = 0.0, eps: float = 1e-6, periodic: bool = False,
                 dtype: npt.DTypeLike = np.float64, checkpoint: Callable[[], None] | None = None,
                 chunk_elements: int = _CHUNK, band: float | None = None, device: str = "auto") -> None:
        shape = tuple(int(s) for s in shape)
        if len(shape) not in (2, 3) or min(shape) < 1 or shape[0] < 2:
            raise ValueError(f"shape must be (n_z, n_x) or (n_z, n_y, n_x) with n_z >= 2, got {shape}")
        self.dx = checks.positive("dx", dx)
        self.dz = checks.positive("dz", dz)
        self.dt = checks.positive("dt", dt)
        self.c = checks.positive("c", c)
        if int(n_t) != n_t or n_t < 1:
            raise ValueError(f"n_t must be an integer >= 1, got {n_t!r}")
        self.n_t = int(n_t)
        if not np.isfinite(t0) or t0 < 0:
            raise ValueError(f"t0 must be finite and >= 0 s, got {t0!r}")
        self.t0 = float(t0)
        self.eps = checks.check_eps(eps)
        self.periodic = bool(periodic)
        self.band = None if band is None else checks.positive("band", band)
        self.checkpoint = checkpoint
        if int(chunk_elements) != chunk_elements or chunk_elements < 1:
            raise ValueError(f"chunk_elements must be an integer >= 1, got {chunk_elements!r}")
        self._chunk_elements = int(chunk_elements)
        rdtype = checks.check_dtype(dtype)
        self.is2d = len(shape) == 2
        vol = (shape[0], 1, shape[1]) if self.is2d else shape
        if positions is None:
            self.positions = None
            oshape = (self.n_t,) + shape[1:]
            extra = 0.0
        else:
            d = 1 if self.is2d else 2
            pos = checks.finite_array("positions", positions, (1, 2)).astype(np.float64)
            pos = pos[:, None] if pos.ndim == 1 else pos
            if pos.shape[1] != d:
                raise ValueError(f"positions must have shape (n_points, {d}) for a {len(shape)}-D image, got {pos.shape}")
            self.positions = pos
            oshape = (len(pos), self.n_t)
            half = 0.5 * (max(vol[1], vol[2]) - 1) * self.dx
            extra = 2.0 * max(0.0, float(np.max(np.abs(pos))) - half)
        self._vol = vol
        self.padded_shape = vol if self.periodic else pad_sizes(vol, self.dx, self.dz, self.dt, self.n_t,
                                                                   self.c, self.t0, extra_lateral=extra)
        self._ctype = np.dtype(np.complex64 if rdtype == np.float32 else np.complex128)
        super().__init__(dtype=rdtype, dims=shape, dimsd=oshape, explicit=False, name="PlanarOperator")
        self._setup()
        self._pair: Any = None
        self.device = "cpu"
        if device != "cpu":
            from fpscan.service.recon import device as devices
            from fpscan.service.recon import gpu

            off = None if self.positions is None or self._nodes is not None else (
                "the operator's sensors are off the nodes of the image's lateral grid (its lateral NUFFTs run on the CPU)")
            if devices.choose(device, gpu.operator_peak(self), off) == "cuda":
                self._pair = gpu.OperatorPair(self, devices.gpu_module())
                self.device = "cuda"

    # -- shapes ------------------------------------------------------------------
    @property
    def ishape(self) -> tuple[int, ...]:
        """Image shape (n_z, n_x) or (n_z, n_y, n_x)."""
        return tuple(self.dims)

    @property
    def oshape(self) -> tuple[int, ...]:
        """Data shape: (n_t, n_x) / (n_t, n_y, n_x) on the grid, (n_points, n_t) at points."""
        return tuple(self.dimsd)

    def transform_lengths(self) -> dict[str, tuple[int, ...]]:
        """The FFT lengths `forward` and `adjoint` run on the working grid `padded_shape`.

        Without ``periodic`` they are fast lengths (`fpscan.physics.fast_lengths`); a periodic
        operator keeps the image's own grid.

        Returns
        -------
        dict of str to tuple of int
            ``"lateral"`` (``(N_x,)`` or ``(N_y, N_x)``), ``"depth"`` (``(2 (N_z - 1),)``, the
            DCT-I), ``"temporal"`` (``(L,)``, the temporal NUFFT's oversampled grid).

        Examples
        --------
        >>> from fpscan.service.recon import PlanarOperator
        >>> PlanarOperator((16, 32), 1e-4, 1e-4, 1e-4 / 1500, 40, 1500.0).transform_lengths()
        {'lateral': (80,), 'depth': (60,), 'temporal': (80,)}
        """
        n_z2, n_y2, n_x2 = self.padded_shape
        lat = (n_x2,) if self.is2d else (n_y2, n_x2)
        return {"lateral": lat, "depth": (2 * (n_z2 - 1),),
                "temporal": (nufft.grid_length(self.n_t, "nufft", self.eps),)}

    def _check(self, name: str, a: npt.ArrayLike, shape: tuple[int, ...]) -> np.ndarray:
        arr = checks.finite_array(name, a, (len(shape),))
        if arr.shape != shape:
            raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
        return arr

    # -- set-up: everything that does not depend on the vector ---------------------------
    def _setup(self) -> None:
        """Wavenumbers, their |k_lat| groups, depth weights, the temporal grid and the
        lateral NUFFT plans of the working grid, made once per operator."""
        n_z2, n_y2, n_x2 = self.padded_shape
        n_z, n_y, n_x = self._vol
        self._off = ((n_y2 - n_y) // 2, (n_x2 - n_x) // 2)
        self._n_xr = n_x2 // 2 + 1
        kx = 2 * np.pi * scipy.fft.rfftfreq(n_x2, self.dx)
        ky = 2 * np.pi * scipy.fft.fftfreq(n_y2, self.dx)
        self._klat2 = (ky[:, None] ** 2 + kx[None, :] ** 2).ravel()
        self._grid = nufft.make_grid(self.n_t, "nufft", self.eps)
        dk = np.pi / ((n_z2 - 1) * self.dz)
        self._kz = dk * np.arange(n_z2)
        kept = np.arange(len(self._klat2))
        if self.band is not None:
            kc2 = (2 * np.pi * self.band / self.c) ** 2
            kept = np.flatnonzero(self._klat2 <= kc2)
        self._skipped = np.setdiff1d(np.arange(len(self._klat2)), kept)
        chunks = _column_chunks(self._klat2[kept], max(n_z2, self._grid.L), self._chunk_elements)
        self._chunks = []
        for idx, klat2, groups in chunks:
            cols = kept[idx]
            rows = None
            if self.band is not None:
                rows = np.minimum(np.floor(np.sqrt(np.maximum(kc2 - klat2, 0.0)) / dk).astype(np.int64) + 1, n_z2)
                if np.all(rows >= n_z2):
                    rows = None
            self._chunks.append((cols, klat2, groups, rows))
        tau = np.ones(n_z2)
        tau[[0, -1]] = 0.5
        # forward: F = dz DCT-I(p0), weight Δk τ_l / 4π (dz folded in); adjoint: dz Δk / 4π,
        # τ applied after its DCT-I
        self._qw_forward = self.dz * dk * tau / (4 * np.pi)
        self._qw_adjoint = np.full(n_z2, self.dz * dk / (4 * np.pi))
        self._plans: dict[tuple[int, int], Any] = {}
        self._nodes: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        if self.positions is not None:
            self._nodes = _lattice_nodes(self.positions, self.padded_shape, self.dx)
        if self.positions is not None and self._nodes is None:
            pos = self.positions
            coords: tuple[np.ndarray, ...] = (2 * np.pi * centred_index(pos[:, 0], n_x2, self.dx) / n_x2,)
            modes: tuple[int, ...] = (n_x2,)
            if not self.is2d:
                coords = (2 * np.pi * centred_index(pos[:, 1], n_y2, self.dx) / n_y2,) + coords
                modes = (n_y2, n_x2)
            # single precision honours about 2e-5 at oversampling 1.25 (fpscan.service.recon.planar._type1);
            # both directions share tolerance and oversampling, so they stay each other's adjoint
            tol = max(self.eps, 2e-5) if self._ctype == np.complex64 else max(self.eps, 1e-14)
            opts: dict[str, Any] = dict(eps=tol, dtype=self._ctype, upsampfac=1.25 if tol >= 1e-9 else 2.0)
            # planned in batches of time samples (`_BATCH`, the last one shorter), so that a
            # checkpoint runs between batches and the full spectrum is built per batch
            self._plans = {(t, n): lateral_plan(t, coords, modes, n, isign=1 if t == 2 else -1, **opts)
                           for t in (1, 2) for n in {min(_BATCH, self.n_t), self.n_t % _BATCH or _BATCH}}

    # -- the pair ------------------------------------------------------------------
    def forward(self, p0: npt.ArrayLike) -> np.ndarray:
        """A p0: the sensor data of an initial pressure image.

        The model of `forward_grid` / `forward_points` with the same parameters (to the NUFFT
        tolerance), computed in the operator's working precision.

        Parameters
        ----------
        p0 : array_like, shape `ishape`
            ``(n_z, n_x)`` or ``(n_z, n_y, n_x)``, Pa.

        Returns
        -------
        ndarray, shape `oshape`
            ``(n_t, n_x)`` / ``(n_t, n_y, n_x)`` on the grid, ``(n_points, n_t)`` at points; Pa.

        Raises
        ------
        ValueError
            A wrong shape, NaN or inf.

        Examples
        --------
        >>> import numpy as np
        >>> from fpscan.service.recon import PlanarOperator
        >>> op = PlanarOperator((16, 32), 1e-4, 1e-4, 1e-4 / 1500, 40, 1500.0)
        >>> op.forward(np.zeros((16, 32))).shape
        (40, 32)
        >>> op.forward(np.zeros((3, 3)))
        Traceback (most recent call last):
        ...
        ValueError: p0 must have shape (16, 32), got (3, 3)
        """
        p0 = self._check("p0", p0, self.ishape)
        return self._apply_forward(p0)

    def adjoint(self, data: npt.ArrayLike) -> np.ndarray:
        """Aᴴ data: the true adjoint of `forward` (not its inverse).

        Parameters
        ----------
        data : array_like, shape `oshape`
            Sensor data, Pa.

        Returns
        -------
        ndarray, shape `ishape`

        Raises
        ------
        ValueError
            A wrong shape, NaN or inf.

        Examples
        --------
        >>> import numpy as np
        >>> from fpscan.service.recon import PlanarOperator
        >>> op = PlanarOperator((16, 32), 1e-4, 1e-4, 1e-4 / 1500, 40, 1500.0)
        >>> op.adjoint(np.ones(op.oshape)).shape
        (16, 32)
        >>> op.adjoint(np.full(op.oshape, np.nan))
        Traceback (most recent call last):
        ...
        ValueError: data contains NaN or inf
        """
        data = self._check("data", data, self.oshape)
        return self._apply_adjoint(data)

    def _tick(self) -> None:
        if self.checkpoint is not None:
            self.checkpoint()

    def _kspace(self, m_in: int, m_out: int) -> tuple[np.ndarray, np.ndarray]:
        """The step's input spectrum (m_in, N_y (N_x//2+1)) and its output (m_out, same columns)
        as two views of one array of max(m_in, m_out) rows, its contents undefined: the lateral
        step writes every entry of the input, the temporal and depth steps read a chunk's
        columns of the input whole before they write its columns of the output (each column
        belongs to one chunk, the columns above a band limit are zeroed), so one k-space array
        serves both (at the paper's size 0.77 GB less at the peak). From the work-array pool
        (`fpscan.physics.workspace`): the forward's and the adjoint's are one warm buffer from
        the second application on."""
        _, n_y2, _ = self.padded_shape
        buf = workspace.take((max(m_in, m_out), n_y2 * self._n_xr), self._ctype)
        return buf[:m_in], buf[:m_out]

    def _row_blocks(self, m: int) -> list[slice]:
        """Blocks of rows of an (m, N_y, N_x//2+1) spectrum of about `_BLOCK` elements each:
        the inverse lateral transforms run per block with a checkpoint between blocks."""
        _, n_y2, _ = self.padded_shape
        step = max(1, _BLOCK // (n_y2 * self._n_xr))
        return [slice(a, min(a + step, m)) for a in range(0, m, step)]

    def _lateral_spectrum(self, vol: np.ndarray, out: np.ndarray) -> np.ndarray:
        """(m, n_y, n_x) real -> (m, N_y, N_x//2+1) half spectrum of its zero-padded,
        centred embedding in the working grid, written into ``out`` (every entry, a view of
        `_kspace`) and returned: the rows padded and centred, the x transforms, their rows
        centred in y and the y transforms, slab by slab on every core
        (`fpscan.physics.fft_engine.rfft2_planes`); a checkpoint after each slab."""
        m = vol.shape[0]
        _, n_y2, n_x2 = self.padded_shape
        _, n_y, n_x = self._vol
        oy, ox = self._off
        src = np.ascontiguousarray(vol, dtype=self.dtype)
        step = max(1, fft_engine.SLAB_BYTES // (n_y * n_x2 * self.dtype.itemsize))
        buf = workspace.take((min(step, m), n_y, n_x2), self.dtype)

        def planes(a: int, b: int) -> np.ndarray:
            if a:
                self._tick()
            array_kernels.pad_rows(src[a:b], buf[: b - a], ox)
            return buf[: b - a]

        fft_engine.rfft2_planes(planes, m, n_y, n_x2, out, step=step, row_offset=oy)
        self._tick()
        return out

    def _lateral_inverse(self, S: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(m, N_y, N_x//2+1) half spectrum -> the image's (m, n_y, n_x) lateral window of
        its inverse DFT (the transpose of `_lateral_spectrum` up to the DFT's 1/(N_y N_x)):
        the x transforms run on the n_y rows kept only, and the window is copied out on every
        core. S is consumed (the y transforms run in its memory). Into ``out`` if given (it may
        be the start of S's own memory: a block of rows is read whole before its rows of
        ``out`` are written, and a row of ``out``, n_y n_x reals, is shorter than a row of S,
        N_y (N_x//2+1) complex values, so no row of S is written before it is read), else an
        array of the work-array pool (the forward's data, the adjoint's image)."""
        m = S.shape[0]
        _, n_y2, n_x2 = self.padded_shape
        _, n_y, n_x = self._vol
        oy, ox = self._off
        if out is None:
            out = workspace.take((m, n_y, n_x), self.dtype)
        for rows in self._row_blocks(m):
            block = S[rows]
            if n_y2 > 1:
                fft_engine.fft_in_place(block, axis=1, inverse=True)
            res = scipy.fft.irfft(block[:, oy : oy + n_y], n=n_x2, axis=2, workers=fft_engine.workers())
            array_kernels.crop_rows(res, out[rows], 0, ox)
            del block, res
            self._tick()
        return out

    def _apply_forward(self, p0: np.ndarray) -> np.ndarray:
        if self._pair is not None:
            return self._pair.xp.asnumpy(self._pair.forward(p0))
        n_z2, n_y2, n_x2 = self.padded_shape
        n_z = self._vol[0]
        # the image's k-space Y and the data's T share one array (`_kspace`): a chunk's columns
        # of Y are read before its columns of T are written, and no other chunk reads them
        with step("forward: lateral FFT"):
            Y, T = self._kspace(n_z, self.n_t)
            self._lateral_spectrum(p0.reshape(self._vol), out=Y.reshape(n_z, n_y2, self._n_xr))
        for idx, klat2, groups, rows in self._chunks:  # columns in chunks of whole |k_lat| groups
            with step("forward: depth DCT-I"):
                # depth: the n_z image rows of each column, zeros below, DCT-I of length N_z
                B = workspace.take((len(idx), n_z2), self._ctype)
                nufft.gather_columns(Y, idx, B)
                B = fft_engine.dct1(B, axis=1, overwrite_x=True)  # of the real and imaginary parts
                if rows is not None:
                    array_kernels.zero_beyond(B, rows)
            with step("forward: spreading"):
                R = nufft.spread(B, self._grid, klat2, self._kz, self._qw_forward, self.c, self.dt, self.t0,
                                 groups=groups, out=workspace.take((len(idx), self._grid.L), self._ctype))
            del B
            with step("forward: temporal FFT"):  # the series back to time, into T's columns
                nufft.scatter_fine_grid(R, self._grid, False, idx, T)
            del R
            self._tick()
        if len(self._skipped):
            array_kernels.zero_columns(T, self._skipped)
        T = T.reshape(self.n_t, n_y2, self._n_xr)
        with step("forward: inverse lateral FFT"):
            if self.positions is None:
                g = self._lateral_inverse(T)
                return g[:, 0, :] if self.is2d else g
            if self._nodes is not None:
                return self._values_at_nodes(T)
        vals = np.empty((len(self.positions), self.n_t), dtype=self.dtype)
        for a, b in self._time_batches():  # the full spectrum batch by batch, then the type-2 NUFFT
            full = self._hermitian_full(T[a:b])
            out = self._plans[2, b - a].execute(full[:, 0, :] if self.is2d else full)  # (b - a, n_points)
            vals[:, a:b] = out.real.T
            del full, out
            self._tick()
        vals /= n_x2 * n_y2
        return vals

    def _hermitian_full(self, T: np.ndarray) -> np.ndarray:
        """The full lateral spectrum (n_t, N_y, N_x) of a real field from its half
        (n_t, N_y, N_x//2+1): S(-k) = conj S(k)."""
        n_t, n_y2, n_xr = T.shape
        n_x2 = self.padded_shape[2]
        full = np.empty((n_t, n_y2, n_x2), dtype=T.dtype)
        full[:, :, :n_xr] = T
        if n_x2 > n_xr:
            _conj_reflected(T, n_xr, n_x2, n_x2, full[:, :, n_xr:])
        return full

    def _apply_adjoint(self, data: np.ndarray) -> np.ndarray:
        if self._pair is not None:
            return self._pair.xp.asnumpy(self._pair.adjoint(data))
        n_z2, n_y2, n_x2 = self.padded_shape
        n_z, n_y, n_x = self._vol
        # the data's k-space A and the image's K (its rows only) share one array (`_kspace`)
        with step("adjoint: lateral FFT"):
            A, K = self._kspace(self.n_t, n_z)
            spectrum = A.reshape(self.n_t, n_y2, self._n_xr)
            if self.positions is None:
                self._lateral_spectrum(data.reshape(self.n_t, n_y, n_x), out=spectrum)
            else:
                self._spectrum_at_points(data, spectrum)
        for idx, klat2, groups, rows in self._chunks:  # columns in chunks of whole |k_lat| groups
            U = nufft.to_fine_grid(A, self._grid, t0_is_zero=False, columns=idx)
            with step("adjoint: interpolation"):
                F = nufft.evaluate(U, self._grid, klat2, self._kz, self._qw_adjoint, self.c, self.dt, self.t0,
                                   inversion=False, n_chunks=1, groups=groups,
                                   out=workspace.take((len(idx), n_z2), U.dtype))
            del U
            with step("adjoint: depth DCT-I"):
                if rows is not None:
                    array_kernels.zero_beyond(F, rows)
                F = fft_engine.dct1(F, axis=1, overwrite_x=True)
            with step("adjoint: scatter"):
                nufft.scatter_columns(F[:, :n_z], idx, K)
            del F
            self._tick()
        with step("adjoint: inverse lateral FFT"):
            if len(self._skipped):
                array_kernels.zero_columns(K, self._skipped)
            # DCT-Iᵀ = diag(τ) DCT-I diag(1/τ), τ = ½ at both ends (the last row only where the image reaches it)
            array_kernels.scale_rows(K, 0.5, 0.5 if n_z == n_z2 else 1.0)
            # the image in an array of its own (the pool's): the k-space is free again as soon as the
            # adjoint returns, however long the caller keeps the image (a power iteration feeds it to the
            # next forward, which then takes the same k-space)
            p = self._lateral_inverse(K.reshape(n_z, n_y2, self._n_xr))
            del A, K
            return p[:, 0, :] if self.is2d else p

    def _values_at_nodes(self, T: np.ndarray) -> np.ndarray:
        """Point forward for sensors on working-grid nodes: the inverse lateral DFT of the half
        spectrum T (n_t, N_y, N_x//2+1) (= Re Σ_k G(k) e^{i k·x_m} / (N_x N_y) of the full
        Hermitian spectrum, exactly), on the rows that hold sensors only; (n_points, n_t). T
        is consumed (the y transforms run in its memory); the rows and the nodes' values are
        copied on every core."""
        _, n_y2, n_x2 = self.padded_shape
        assert self._nodes is not None
        rows, row_of, cols = self._nodes
        vals = np.empty((len(row_of), self.n_t), dtype=self.dtype)
        batches = self._time_batches()
        kept = workspace.take((batches[0][1] - batches[0][0], len(rows), self._n_xr), self._ctype)
        for a, b in batches:
            block = T[a:b]
            if n_y2 > 1:
                fft_engine.fft_in_place(block, axis=1, inverse=True)
            array_kernels.take_rows(block, rows, kept[: b - a])
            g = scipy.fft.irfft(kept[: b - a], n=n_x2, axis=2, workers=fft_engine.workers())  # (b - a, len(rows), N_x)
            array_kernels.gather_nodes(g, row_of, cols, a, vals)
            del block, g
            self._tick()
        return vals

    def _spectrum_at_nodes(self, data: np.ndarray, H: np.ndarray) -> np.ndarray:
        """Adjoint of `_values_at_nodes`: the data placed on their nodes of the working grid
        (zero elsewhere), lateral half spectrum (n_t, N_y, N_x//2+1) — the Hermitian part of
        Σ_m g_m e^{-i k·x_m} exactly, since the placed field is real — written into ``H``
        (every entry) and returned; the placing and the rows' copies on every core."""
        _, n_y2, n_x2 = self.padded_shape
        assert self._nodes is not None
        rows, row_of, cols = self._nodes
        slot = np.full(n_y2, -1, dtype=np.int64)  # each grid row's place among the rows with sensors
        slot[rows] = np.arange(len(rows))
        values = np.ascontiguousarray(data)
        ones = np.ones(len(row_of))
        batches = self._time_batches()
        grid = workspace.take((batches[0][1] - batches[0][0], len(rows), n_x2), self.dtype)
        for a, b in batches:
            placed = grid[: b - a]
            array_kernels.place_points(values, ones, row_of, cols, a, placed)  # distinct nodes (`_lattice_nodes`)
            spectra = scipy.fft.rfft(placed, axis=2, workers=fft_engine.workers())
            block = H[a:b]
            array_kernels.embed_row_set(spectra, slot, block)
            if n_y2 > 1:
                fft_engine.fft_in_place(block, axis=1)
            del spectra, block
            self._tick()
        return H

    def _spectrum_at_points(self, data: np.ndarray, H: np.ndarray) -> np.ndarray:
        """Adjoint of the type-2 point evaluation: Hermitian part of the type-1 NUFFT
        Σ_m g_m(t) e^{-i k·x_m}, as an rfft2-shaped half spectrum (n_t, N_y, N_x//2+1),
        written into ``H`` (every entry) and returned."""
        if self._nodes is not None:
            return self._spectrum_at_nodes(data, H)
        _, n_y, n_x = self.padded_shape
        n_xr = n_x // 2 + 1
        strengths = np.ascontiguousarray(data.T, dtype=self._ctype)  # (n_t, n_points)
        for a, b in self._time_batches():
            Y = self._plans[1, b - a].execute(strengths[a:b]).reshape(b - a, n_y, n_x)
            # Re(·) in the forward -> Hermitian part here: ½ (Y(k) + conj Y(-k)), FFT index order
            _conj_reflected(Y, 0, n_xr, n_x, H[a:b])
            H[a:b] += Y[:, :, :n_xr]
            del Y
            self._tick()
        H *= 0.5
        return H

    def _time_batches(self) -> list[tuple[int, int]]:
        """[a, b) ranges of time samples, `_BATCH` long (the last one shorter): the lateral
        NUFFTs of point data run per batch (their plans are made for these lengths)."""
        return [(a, min(a + _BATCH, self.n_t)) for a in range(0, self.n_t, _BATCH)]


    # -- pylops ------------------------------------------------------------------
    def _matvec(self, x: np.ndarray) -> np.ndarray:
        # solver vectors: flat, finite, in the working dtype; reshapes are views
        return self._apply_forward(np.asarray(x, dtype=self.dtype).reshape(self.ishape)).ravel()

    def _rmatvec(self, y: np.ndarray) -> np.ndarray:
        return self._apply_adjoint(np.asarray(y, dtype=self.dtype).reshape(self.oshape)).ravel()


def _lattice_nodes(pos: np.ndarray, padded_shape: tuple[int, ...],
                   dx: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Where every sensor sits on a node of the working grid (`fpscan.physics.axes.node_indices`;
    the scanner's lattice, the image's lateral grid, is one): (the node rows that hold sensors,
    each sensor's place among them, each sensor's column), so that the lateral point
    transforms are exact DFTs on those rows; else None (the lateral NUFFTs)."""
    _, n_y2, n_x2 = padded_shape
    axes = (centred_axis(n_x2, dx), centred_axis(n_y2, dx))[: pos.shape[1]]
    nodes = node_indices(pos, axes, (dx, dx)[: pos.shape[1]])
    if nodes is None:
        return None
    cols, node_rows = nodes
    if len(np.unique(node_rows * n_x2 + cols)) < len(cols):  # two sensors on one node: the NUFFTs sum them
        return None
    rows, row_of = np.unique(node_rows, return_inverse=True)
    return rows, row_of.astype(np.int64), cols


def _conj_reflected(src: np.ndarray, i_lo: int, i_hi: int, n_x: int, out: np.ndarray) -> None:
    """out[:, j, i - i_lo] = conj(src[:, (-j) % n_y, (-i) % n_x]) for i in [i_lo, i_hi): the
    reflected wavenumbers S(-k) of a lateral spectrum (FFT order; ``src`` (m, n_y, >= the
    columns read)), written through strided views (no fancy-index copies of the volume)."""
    n_y = src.shape[1]
    rows = [(slice(0, 1), slice(0, 1))]
    if n_y > 1:
        rows.append((slice(1, n_y), slice(n_y - 1, 0, -1)))
    cols = []
    if i_lo == 0:
        cols.append((slice(0, 1), slice(0, 1)))
    a = max(i_lo, 1)
    if i_hi > a:
        cols.append((slice(a - i_lo, i_hi - i_lo), slice(n_x - a, n_x - i_hi, -1)))
    for out_y, src_y in rows:
        for out_x, src_x in cols:
            np.conjugate(src[:, src_y, src_x], out=out[:, out_y, out_x])


def _column_chunks(klat2: np.ndarray, row: int, elements: int) -> list[tuple[np.ndarray, np.ndarray, tuple]]:
    """The k-space columns in chunks of whole |k_lat| groups (`fpscan.physics.nufft.group_columns`:
    columns of one group share their temporal taps), each about ``elements`` / ``row``
    columns: a list of (column indices (sorted), their |k_lat|², their groups)."""
    gvals, gptr, order = nufft.group_columns(klat2)
    target = max(1, elements // max(1, row))
    chunks = []
    a = 0
    while a < len(gvals):
        b = int(np.searchsorted(gptr, gptr[a] + target, side="left"))
        b = min(max(b, a + 1), len(gvals))
        idx = np.sort(order[gptr[a] : gptr[b]])
        chunks.append((idx, klat2[idx], nufft.group_columns(klat2[idx])))
        a = b
    return chunks
