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
from fpscan.service.recon import checks, memory
from fpscan.service.recon.tv.grid import TvGrid, noise_sigma, tv_grid
from fpscan.service.recon.tv.preconditioner import apply_weight, ner_weight

if TYPE_CHECKING:
    from fpscan.service.recon.reconstruction import Reconstruction

__all__: list[str] = []


def check_options(lam: float | None, max_iter: int, tol: float,
                      time_limit: float) -> tuple[float | None, int, float, float]:
    """The model-based options by their rules (``fpscan.service.recon.checks``: one owner each)."""
    lam = None if lam is None else checks.check_lam(lam)
    max_iter = checks.check_iterations(max_iter)
    tol = checks.check_tol(tol)
    return lam, max_iter, tol, checks.check_time_limit(time_limit)


class Record(NamedTuple):
    """The record tv works on (`working_record`): ``g`` float64, time along ``time_axis`` (0: grid
    data ``(n_t, n_x)`` / ``(n_t, n_y, n_x)``; 1: A-lines ``(n_points, n_t)``), cut and
    resampled to ``grid`` (`fpscan.service.recon.tv.grid.TvGrid`); ``sampled_sigma`` σ̂ of the record
    as sampled (Pa)."""

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
    """The record tv works on (`Record`): ``data`` checked (finite, at least 2 time samples),
    then `_cut_and_resample` on the grid `fpscan.service.recon.tv.grid.tv_grid` chooses (``chosen``: its
    keywords ``bandwidth``, ``dz``, ``n_z``, ``t0``, ``whole_record``) for the image's lateral
    extent (`lateral_extent`)."""
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
    """(pitch, reach) of tv's image for `fpscan.service.recon.tv.grid.tv_grid`: its lateral pitch (m;
    None where the warm start will refuse the positions or grid) and the largest lateral distance
    between a sensor and a corner of its lateral extent (m; None in 2-D: a 2-D wave does not end
    when its front has passed, its tail ∝ 1/t² lasts to the record's end, so a line keeps its
    whole record; in 3-D, Huygens' principle: silence after the last front). Grid data ``(n_t, n_x)`` /
    ``(n_t, n_y, n_x)`` with ``dx``; A-lines with ``positions`` on ``grid`` (default: the
    positions' lattice, as `fpscan.service.recon.planar.reconstruct_points` makes it)."""
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
    """The warm start on ``record`` — NER (grid data, with ``dx``) or NEDNER (A-lines at
    ``positions``, with ``weights`` and ``grid``) on the record's depth grid, ``common`` the
    planar methods' keywords — and the sensor positions centred on its lateral grid (None for
    grid data). Raises ValueError for unequal x and y pitch (tv's image needs one)."""
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
    itself where it already is), clipped to >= 0 with ``positivity``."""
    x = np.ascontiguousarray(warm.p0, dtype=dtype)
    if positivity:
        np.maximum(x, 0, out=x)
    return x


class Model:
    """A and B = P Aᵀ on the warm start's grid (module doc): ``forward(v)`` = A v in the
    record's shape, ``B(r)`` = P Aᵀ r as an image (the exact adjoint, NER's k-space weight P =
    k_z / |k|, symmetric positive definite), ``residual(Ax)`` = ‖A x − g‖, ``operator_pairs``
    the (forward + adjoint applications) / 2 so far. Made after the memory check
    (`fpscan.service.recon.memory.tv_memory`; raises ValueError above ``memory_limit``); ``checkpoint``
    is the operator's (a cancel's poll); ``device`` the operator's (``"cuda"``: A, Aᵀ and P run on
    the GPU, and ``forward``, ``B`` and ``residual`` take and give arrays there, ``g_dev`` the data
    there; ``xp`` is the solver's array module)."""

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
        return apply_weight(self.P, self.op.rmatvec(r.astype(self.dtype, copy=False).ravel()).reshape(self.shape))

    def forward(self, v: np.ndarray) -> np.ndarray:
        self.applied[0] += 1
        pair = self.op._pair
        if pair is not None:
            return pair.forward(pair.xp.asarray(v).reshape(self.shape)).reshape(self.g.shape)
        return self.op.matvec(v.ravel()).reshape(self.g.shape)

    def residual(self, Ax: np.ndarray) -> float:
        if self.xp is not np:
            return float(self.xp.linalg.norm(Ax - self.g_dev))
        return float(np.linalg.norm(Ax - self.g))

    @property
    def operator_pairs(self) -> float:
        return 0.5 * (self.applied[0] + self.applied[1])
