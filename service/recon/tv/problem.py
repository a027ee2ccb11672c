"""tv's problem: the options, the record it works on, the warm start, and the model A, B = P Aᵀ.

- `check_options`: the model-based options by their rules (``fpscan.service.recon.checks``).
- `working_record`: the record at the band the lateral pitch resolves (or a declared one), cut where
  the model of the image predicts silence and resampled to the fewest samples whose band
  reaches it, with the depth grid (`fpscan.service.recon.tv.grid.tv_grid`); σ̂ from the record as
  sampled (`Record`, package doc "Grid").
- `warm_start`: NER (grid data) or NEDNER (A-lines) on that record, and the sensors centred
  on its lateral grid; `start_image` the solver's first iterate from it.
- `Model`: the exact planar forward model A (`fpscan.service.recon.operator.PlanarOperator`, its
  memory checked first) and B = P Aᵀ with NER's k-space weight P
  (`fpscan.service.recon.tv.preconditioner`), counting their applications.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import numpy.typing as npt

from fpscan.physics.resample import resample
from fpscan.physics.step_times import step
from fpscan.service.recon import checks, memory
from fpscan.service.recon.tv.grid import TvGrid, noise_sigma, tv_grid
from fpscan.service.recon.tv.preconditioner import apply_weight, ner_weight

if TYPE_CHECKING:
    from fpscan.service.recon.reconstruction import Reconstruction

__all__ = ["check_options", "Record", "working_record", "lateral_extent", "warm_start", "start_image", "Model"]


def check_options(lam: float | None, max_iter: int, tol: float,
                      time_limit: float) -> tuple[float | None, int, float, float]:
    """The model-based options by their rules (``fpscan.service.recon.checks``: one owner each).

    Parameters
    ----------
    lam : float or None
        TV weight λ (data's unit, Pa), or None (automatic).
    max_iter : int
        Iterations at most.
    tol : float
        The stopping rule's threshold (dimensionless).
    time_limit : float
        Wall-time limit, s.

    Returns
    -------
    tuple
        ``(lam, max_iter, tol, time_limit)`` as the rules normalise them.

    Raises
    ------
    fpscan.service.recon.checks.OptionError
        A value out of its range (the message names it).

    Examples
    --------
    >>> from fpscan.service.recon.tv.problem import check_options
    >>> check_options(None, 100, 0.005, 60)
    (None, 100, 0.005, 60.0)
    >>> check_options(-1.0, 100, 0.005, 60)
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: lam (the TV weight λ) must be in [0, 1e+30], got -1.0
    """
    lam = None if lam is None else checks.check_lam(lam)
    max_iter = checks.check_max_iter(max_iter)
    tol = checks.check_tol(tol)
    return lam, max_iter, tol, checks.check_time_limit(time_limit)


class Record(NamedTuple):
    """The record tv works on (`working_record`).

    Attributes
    ----------
    g : ndarray
        The data, float64, cut and resampled to ``grid``, time along ``time_axis``: grid data
        ``(n_t, n_x)`` / ``(n_t, n_y, n_x)`` or A-lines ``(n_points, n_t)`` (Pa).
    time_axis : int
        0 (grid data) or 1 (A-lines).
    grid : TvGrid
        The grid tv chose (`fpscan.service.recon.tv.grid.TvGrid`).
    sampled_sigma : float
        σ̂ of the record as sampled (Pa; `fpscan.service.recon.tv.grid.noise_sigma`).
    n_t : int
        The operator's time samples (property).
    sigma : float
        σ̂ at the operator's rate: white noise of σ resampled from K to M samples keeps
        σ √((M − 1) / (K − 1)) per sample (property, Pa).
    noise_norm : float
        The noise's norm σ̂ √N over the record's N samples (property, Pa).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.problem import working_record
    >>> rng = np.random.default_rng(0)
    >>> rec = working_record(rng.standard_normal((64, 8)), 2e-8, 1500.0, 1e-4, None, None)
    >>> rec.time_axis, rec.g.shape == (rec.n_t, 8), rec.grid.record_n_t
    (0, True, 64)
    >>> 0.8 < rec.sampled_sigma < 1.2  # white noise of σ = 1
    True
    """

    g: np.ndarray
    time_axis: int
    grid: TvGrid
    sampled_sigma: float

    @property
    def n_t(self) -> int:
        """The operator's time samples."""
        return int(self.g.shape[self.time_axis])

    @property
    def sigma(self) -> float:
        """σ̂ at the operator's rate: white noise of σ resampled from K to M samples keeps σ
        √((M − 1) / (K − 1)) per sample (the DCT-I terms kept)."""
        return self.sampled_sigma * math.sqrt((self.grid.n_t - 1) / (self.grid.record_n_t - 1))

    @property
    def noise_norm(self) -> float:
        """The noise's norm σ̂ √N over the record's N samples."""
        return self.sigma * math.sqrt(self.g.size)


def working_record(data: npt.ArrayLike, dt: float, c: float, dx: float | None, positions: np.ndarray | None,
            grid: np.ndarray | Sequence[npt.ArrayLike] | None, **chosen: Any) -> Record:
    """The record tv works on: ``data`` checked (finite, at least 2 time samples), cut where the
    model of the image predicts silence (unless ``whole_record``) and resampled to the band, on
    the grid `fpscan.service.recon.tv.grid.tv_grid` chooses for the image's lateral extent
    (`lateral_extent`); σ̂ from the record as sampled.

    Parameters
    ----------
    data : array_like
        Grid data ``(n_t, n_x)`` / ``(n_t, n_y, n_x)`` (time first; with ``dx``) or A-lines
        ``(n_points, n_t)`` (with ``positions``), Pa.
    dt : float
        Sample interval, s.
    c : float
        Sound speed, m/s.
    dx : float or None
        Lateral pitch of grid data, m.
    positions : ndarray or None
        Sensor positions ``(n_points, 1)`` / ``(n_points, 2)``, m (A-lines), or None (grid data).
    grid : optional
        The A-lines' output lattice (`fpscan.service.recon.planar.reconstruct_points`'s).
    **chosen
        `tv_grid`'s keywords: ``bandwidth`` (Hz), ``dz`` (m), ``n_z``, ``t0`` (s), ``whole_record``.

    Returns
    -------
    Record
        The record, its grid and σ̂.

    Raises
    ------
    ValueError
        Non-finite data, data of the wrong dimensions or fewer than 2 time samples; what
        `tv_grid` refuses.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.problem import working_record
    >>> rec = working_record(np.zeros((64, 8)), 2e-8, 1500.0, 1e-4, None, None, dz=3e-5, n_z=16)
    >>> rec.grid.dz, rec.grid.n_z
    (3e-05, 16)
    >>> working_record(np.zeros((1, 8)), 2e-8, 1500.0, 1e-4, None, None)
    Traceback (most recent call last):
    ...
    ValueError: data need at least 2 time samples, got shape (1, 8)
    """
    # the grid the data can resolve (`fpscan.service.recon.tv.grid`): the operator's samples and band,
    # the image's depth grid; the data low-passed and resampled to those samples
    time_axis = 0 if positions is None else 1
    g = np.asarray(checks.finite_array("data" if positions is None else "alines", data, (2, 3)), dtype=np.float64)
    if g.shape[time_axis] < 2:
        raise ValueError(f"data need at least 2 time samples, got shape {g.shape}")
    pitch, reach = lateral_extent(g, dx, positions, grid)
    # σ̂ of the record as sampled (Haar differences need a signal smooth at the sample scale, which the record
    # resampled to its band is not: there they read 7-48 % high on k-Wave's data); `Record.sigma` scales it
    record_sigma = noise_sigma(g, time_axis)
    g, tv_grid_ = _cut_and_resample(g, dt, c, time_axis, sigma=record_sigma, pitch=pitch, reach=reach, **chosen)
    return Record(g, time_axis, tv_grid_, record_sigma)


def lateral_extent(g: np.ndarray, dx: float | None, positions: np.ndarray | None,
                    grid: np.ndarray | Sequence[npt.ArrayLike] | None) -> tuple[float | None, float | None]:
    """(pitch, reach) of tv's image for `fpscan.service.recon.tv.grid.tv_grid`.

    The lateral pitch (m; None where the warm start will refuse the positions or grid) and the
    largest lateral distance between a sensor and a corner of its lateral extent (m; None in
    2-D: a 2-D wave does not end when its front has passed, its tail ∝ 1/t² lasts to the
    record's end, so a line keeps its whole record; in 3-D, Huygens' principle: silence after
    the last front).

    Parameters
    ----------
    g : ndarray
        Grid data ``(n_t, n_x)`` / ``(n_t, n_y, n_x)`` or A-lines ``(n_points, n_t)``.
    dx : float or None
        Grid data's pitch, m.
    positions : ndarray or None
        The A-lines' positions ``(n_points, 1)`` / ``(n_points, 2)``, m.
    grid : optional
        Their lattice (default: the positions' lattice, as
        `fpscan.service.recon.planar.reconstruct_points` makes it,
        `fpscan.service.recon.planar.default_grid`).

    Returns
    -------
    tuple
        ``(pitch, reach)``, m or None.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.problem import lateral_extent
    >>> lateral_extent(np.zeros((10, 4, 5)), 1e-4, None, None)  # a 4 x 5 plane: its diagonal
    (0.0001, 0.0005)
    >>> lateral_extent(np.zeros((10, 5)), 1e-4, None, None)  # a line keeps its whole record
    (0.0001, None)
    """
    from fpscan.service.recon.planar import (  # the warm start's own lattice and grid rules
        check_grid,
        default_grid,
    )

    if positions is None:
        if dx is None or not (math.isfinite(dx) and dx > 0):
            return None, None
        sides = [(n - 1) * dx for n in g.shape[1:]]
        return float(dx), (math.hypot(*sides) if len(sides) == 2 else None)
    try:
        pos = np.asarray(positions, dtype=np.float64).reshape(len(g), -1)
        if grid is None:
            axes, pitch = default_grid(pos)
        else:
            axes = check_grid(grid, pos.shape[1])
            pitch = float(axes[0][1] - axes[0][0])
    except (ValueError, IndexError, TypeError):  # the warm start refuses them, naming the problem
        return None, None
    if not (math.isfinite(pitch) and pitch > 0):
        return None, None
    if pos.shape[1] == 1:  # a line: 2-D waves ring on (a tail ∝ 1/t² after the last front), keep it all
        return pitch, None
    far = np.zeros(len(pos))
    for a, ax in enumerate(axes):  # per axis, the farther of the extent's two ends
        far += np.maximum(np.abs(pos[:, a] - float(ax.min())), np.abs(pos[:, a] - float(ax.max()))) ** 2
    return pitch, float(np.sqrt(far.max())) if len(far) else None


def _cut_and_resample(g: np.ndarray, dt: float, c: float, time_axis: int, **grid: Any) -> tuple[np.ndarray, TvGrid]:
    """The record tv works on and its grid (`fpscan.service.recon.tv.grid.tv_grid` with ``grid``'s
    keywords): ``g`` cut where the model of the image predicts silence (unless ``whole_record``)
    and resampled to the band, time along ``time_axis``."""
    chosen = tv_grid(g.shape[time_axis], dt, c, data=g, time_axis=time_axis, **grid)
    if chosen.cut:  # after it the model of the image predicts silence at every sensor (module doc)
        g = np.ascontiguousarray(g[: chosen.record_n_t] if time_axis == 0 else g[:, : chosen.record_n_t])
    if chosen.resampled:
        g = resample(g, chosen.n_t, axis=time_axis)
    return g, chosen


def warm_start(record: Record, c: float, dx: float | None, positions: np.ndarray | None,
                weights: np.ndarray | None, grid: np.ndarray | Sequence[npt.ArrayLike] | None,
                **common: Any) -> tuple[Reconstruction, np.ndarray | None]:
    """The warm start on ``record``: NER (grid data, with ``dx``) or NEDNER (A-lines at
    ``positions``, with ``weights`` and ``grid``) on the record's depth grid, and the sensor
    positions centred on its lateral grid.

    Parameters
    ----------
    record : Record
        `working_record`'s.
    c : float
        Sound speed, m/s.
    dx : float or None
        Grid data's pitch, m.
    positions : ndarray or None
        Sensor positions ``(n_points, 1)`` / ``(n_points, 2)``, m (A-lines).
    weights : ndarray or None
        The A-lines' area weights ``(n_points,)`` (default: clipped Voronoi areas).
    grid : optional
        The A-lines' output lattice.
    **common
        The planar methods' keywords (``dtype``, ``t0``, ``eps``, ``positivity``,
        ``memory_limit``, ``progress``, ``device``).

    Returns
    -------
    tuple
        ``(warm, pos)``: the warm start's `Reconstruction` (p0 ``(n_z, n_x)`` /
        ``(n_z, n_y, n_x)``, axes in m) and the positions centred on its lateral grid (m; None
        for grid data).

    Raises
    ------
    ValueError
        Unequal x and y pitch (tv's image needs one); what the planar methods refuse.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.problem import warm_start, working_record
    >>> rec = working_record(np.zeros((64, 8)), 2e-8, 1500.0, 1e-4, None, None, n_z=16)
    >>> warm, pos = warm_start(rec, 1500.0, 1e-4, None, None, None)
    >>> warm.p0.shape, pos
    ((16, 8), None)
    """
    from fpscan.service.recon.planar import reconstruct_grid, reconstruct_points

    kw: dict[str, Any] = dict(dz=record.grid.dz, n_z=record.grid.n_z, **common)
    if positions is None:
        assert dx is not None  # checked by the caller
        return reconstruct_grid(record.g, dx, record.grid.dt, c, **kw), None
    warm = reconstruct_points(record.g, positions, record.grid.dt, c, weights=weights, grid=grid, **kw)
    dx = warm.params["dx"]
    if warm.params.get("dy") is not None and not np.isclose(warm.params["dy"], dx, rtol=1e-9):
        raise ValueError(f"tv needs equal x and y pitch, got {dx} and {warm.params['dy']} m")
    pos = np.asarray(positions, dtype=np.float64).reshape(len(record.g), -1).copy()
    pos[:, 0] -= 0.5 * (warm.x[0] + warm.x[-1])
    if pos.shape[1] == 2 and warm.y is not None:  # 2-D lattice: y is set
        pos[:, 1] -= 0.5 * (warm.y[0] + warm.y[-1])
    return warm, pos


def start_image(warm: Reconstruction, dtype: np.dtype, positivity: bool) -> np.ndarray:
    """The solver's first iterate: the warm start's image in the working dtype (that image
    itself where it already is), clipped to >= 0 with ``positivity``.

    Parameters
    ----------
    warm : Reconstruction
        The warm start (`warm_start`), p0 ``(n_z, n_x)`` / ``(n_z, n_y, n_x)``, Pa.
    dtype : dtype
        The working precision (float32 or float64).
    positivity : bool
        Clip below 0.

    Returns
    -------
    ndarray
        p0's shape, ``dtype``, C-contiguous.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.reconstruction import Reconstruction
    >>> from fpscan.service.recon.tv.problem import start_image
    >>> warm = Reconstruction(np.array([[-1.0, 2.0]]), np.zeros(1), np.zeros(2), None, {})
    >>> start_image(warm, np.dtype(np.float32), True).tolist()
    [[0.0, 2.0]]
    >>> start_image(warm, np.dtype(np.float64), False) is warm.p0  # already the working dtype
    True
    """
    x = np.ascontiguousarray(warm.p0, dtype=dtype)
    if positivity:
        np.maximum(x, 0, out=x)
    return x


class Model:
    """A and B = P Aᵀ on the warm start's grid (module doc; Arridge et al., PMB 61 (2016) 8908).

    ``forward(v)`` = A v in the record's shape (`fpscan.service.recon.operator.PlanarOperator`, the
    exact planar model), ``B(r)`` = P Aᵀ r as an image (the exact adjoint, NER's k-space weight
    P = k_z / |k|, `fpscan.service.recon.tv.preconditioner`: symmetric positive definite),
    ``residual(Ax)`` = ‖A x − g‖. Made after the memory check
    (`fpscan.service.recon.memory.tv_memory`).

    Parameters
    ----------
    record : Record
        `working_record`'s.
    warm : Reconstruction
        The warm start (its grid: p0's shape, ``dx``, ``dz`` in m).
    c : float
        Sound speed, m/s.
    pos : ndarray or None
        Sensor positions centred on the image's lateral grid ``(n_points, d)``, m (None: grid data).
    t0 : float
        Time of sample 0, s.
    eps : float
        NUFFT tolerance.
    dtype : dtype
        The working precision.
    periodic : bool
        Laterally periodic model (no zero padding).
    checkpoint : callable or None
        The operator's (a cancel's poll).
    memory_limit : int or None
        Bytes (None: available now).
    device : {"cpu", "cuda"}, optional
        The operator's (``"cuda"``: A, Aᵀ and P run on the GPU, and ``forward``, ``B`` and
        ``residual`` take and give arrays there).

    Attributes
    ----------
    g, pos, dtype, shape, dx, dz
        The record's data, the positions, the precision and the image's grid (m).
    op : PlanarOperator
        A.
    P : NerWeight
        The preconditioner.
    applied : list of int
        Forward and adjoint applications so far.
    operator_pairs : float
        Their mean (property).
    xp : module
        The solver's array module (numpy; cupy on a GPU).
    g_dev : array
        The data in it.

    Raises
    ------
    ValueError
        The estimated memory above ``memory_limit``.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.problem import Model, warm_start, working_record
    >>> rec = working_record(np.zeros((32, 8)), 2e-8, 1500.0, 1e-4, None, None, n_z=16)
    >>> warm, pos = warm_start(rec, 1500.0, 1e-4, None, None, None)
    >>> model = Model(rec, warm, 1500.0, pos, t0=0.0, eps=1e-6, dtype=np.dtype(np.float64), periodic=False,
    ...               checkpoint=None, memory_limit=None)
    >>> model.B(model.forward(np.ones((16, 8)))).shape, model.operator_pairs
    ((16, 8), 1.0)
    """

    def __init__(self, record: Record, warm: Reconstruction, c: float, pos: np.ndarray | None, *, t0: float,
                 eps: float, dtype: np.dtype, periodic: bool, checkpoint: Callable[[], None] | None,
                 memory_limit: int | None, device: str = "cpu") -> None:
        from fpscan.service.recon.operator import PlanarOperator

        band, n_t = record.grid.band, record.n_t
        self.g, self.pos, self.dtype = record.g, pos, dtype
        self.shape: tuple[int, ...] = warm.p0.shape
        self.dx: float = warm.params["dx"]
        self.dz: float = warm.params["dz"]
        self.op = PlanarOperator(self.shape, self.dx, self.dz, record.grid.dt, n_t, c, positions=pos, t0=t0, eps=eps,
                                 dtype=dtype, periodic=periodic, checkpoint=checkpoint, band=band, device=device)
        kept_columns = None if band is None else memory.band_columns(self.op.padded_shape, self.dx, c, band)
        checks.check_memory(memory.tv_memory(self.shape, self.op.padded_shape, self.g.size, n_t, dtype,
                                             kept_columns=kept_columns), memory_limit)
        self.P = ner_weight(self.shape, self.dx, self.dz)
        self.applied = [0, 0]  # forward, adjoint applications: params' operator_pairs is their mean
        pair = self.op._pair
        #: the solver's array module and the data in it: on a GPU the solver's images and the
        #: data stay there (the kernels: `fpscan.service.recon.tv.kernels`)
        self.xp = np if pair is None else pair.xp
        self.g_dev = self.g if pair is None else pair.xp.asarray(self.g)

    def B(self, r: np.ndarray) -> np.ndarray:
        self.applied[1] += 1
        pair = self.op._pair
        if pair is not None:  # on the GPU: Aᵀ and P there, the image stays there
            return apply_weight(self.P, pair.adjoint(pair.xp.asarray(r, dtype=self.dtype).reshape(self.op.oshape)))
        image = self.op.rmatvec(r.astype(self.dtype, copy=False).ravel()).reshape(self.shape)
        with step("preconditioner"):
            return apply_weight(self.P, image)

    def precondition(self, v: np.ndarray) -> np.ndarray:
        """P v of an image (NER's weight, `fpscan.service.recon.tv.preconditioner`; v may be
        overwritten), on the solver's device."""
        return apply_weight(self.P, v)

    def forward(self, v: np.ndarray) -> np.ndarray:
        self.applied[0] += 1
        pair = self.op._pair
        if pair is not None:
            return pair.forward(pair.xp.asarray(v).reshape(self.shape)).reshape(self.g.shape)
        return self.op.matvec(v.ravel()).reshape(self.g.shape)

    def residual(self, Ax: np.ndarray) -> float:
        if self.xp is not np:
            return float(self.xp.linalg.norm(Ax - self.g_dev))
        if Ax.shape != self.g.shape or not (Ax.flags.c_contiguous and self.g.flags.c_contiguous):
            return float(np.linalg.norm(Ax - self.g))
        # compiled, on every core: numpy's norm sums in BLAS, whose OpenBLAS threads spin for about
        # 0.1 s after it, and the adjoint that follows ran on one core of two (tv at half the
        # paper's size 1.2x from 1 to 2 cores; docs/performance.md, "CPU scaling on the 2-core machine")
        from fpscan.physics.array_kernels import difference_norm

        return float(difference_norm(Ax.reshape(-1), self.g.reshape(-1)))

    @property
    def operator_pairs(self) -> float:
        return 0.5 * (self.applied[0] + self.applied[1])
