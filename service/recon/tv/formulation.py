"""tv's problem, set up once for its own solver and for any other: the model, the data, the
warm start, the grid and λ.

- `set_up`: on the record tv works on (`fpscan.service.recon.tv.problem.working_record`), the
  warm start (`fpscan.service.recon.tv.problem.warm_start`), the model A and B = P Aᵀ
  (`fpscan.service.recon.tv.problem.Model`), the geometry's ‖BA‖ and noise image
  (`fpscan.service.recon.tv.geometry`) and the automatic λ's rule
  (`fpscan.service.recon.tv.lam.DiscrepancyRule`): what `reconstruct_tv` runs its solver on.
- `TvProblem`: the same problem for a user's solver (pylops, pyproximal): the operator A as a
  ``pylops.LinearOperator``, the data g it fits, the warm start, the grid, λ, the TV's gradient
  and NER's preconditioner as operators, and J itself (`TvProblem.objective`);
  `problem_of` makes it from `set_up`'s parts and the warm start's residual (the automatic λ's
  D₀), so that it is the problem `reconstruct_tv` solves, to the bit.

The problem (Arridge et al., Phys. Med. Biol. 61 (2016) 8908; the package doc)::

    p0 = argmin_{p >= 0}  J(p) = ½ ‖A p − g‖² + λ TV(p),   TV(p) = Σ_voxels |∇p|₂

with ∇ the forward differences in voxel units, 0 across the image's last row, column and
plane (pylops' ``Gradient(kind="forward", edge=False)``).
"""
from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from fpscan.physics import workspace
from fpscan.service.progress import span
from fpscan.service.recon.tv.fista import MARGIN
from fpscan.service.recon.tv.geometry import geometry_numbers
from fpscan.service.recon.tv.lam import DiscrepancyRule
from fpscan.service.recon.tv.preconditioner import apply_weight
from fpscan.service.recon.tv.problem import Model, Record, start_image, warm_start
from fpscan.service.recon.tv.prox import tv_norm

if TYPE_CHECKING:
    import pylops

    from fpscan.service.recon.reconstruction import Reconstruction
    from fpscan.service.recon.tv.grid import TvGrid
    from fpscan.service.recon.tv.progress import Reporter

__all__ = ["SetUp", "set_up", "TvProblem", "problem_of"]


class SetUp(NamedTuple):
    """What `set_up` returns: tv's problem before its solver.

    Attributes
    ----------
    warm : Reconstruction
        The warm start (NER / NEDNER on the record's grid; p0 ``(n_z, n_x)`` /
        ``(n_z, n_y, n_x)``, axes in m).
    model : Model
        A and B = P Aᵀ (`fpscan.service.recon.tv.problem.Model`).
    gain : float
        The ‖BA‖ estimate (`fpscan.service.recon.tv.geometry`).
    noise_rms : float
        The noise image's RMS per unit σ.
    geometry_kept : bool
        Both came from an earlier run on this geometry.
    rule : DiscrepancyRule
        The automatic λ's rule of the warm start's residual (`fpscan.service.recon.tv.lam`).

    Examples
    --------
    >>> from fpscan.service.recon.tv.formulation import SetUp
    >>> SetUp._fields
    ('warm', 'model', 'gain', 'noise_rms', 'geometry_kept', 'rule')
    """

    warm: Reconstruction
    model: Model
    gain: float
    noise_rms: float
    geometry_kept: bool
    rule: DiscrepancyRule


def set_up(record: Record, dev: str, report: Reporter, *, c: float, dx: float | None,
           positions: np.ndarray | None, weights: np.ndarray | None, grid: Any, dtype: np.dtype, eps: float,
           t0: float, positivity: bool, periodic: bool, memory_limit: int | None) -> SetUp:
    """The problem tv solves on ``record``, on the device ``dev``: the warm start, A and B = P Aᵀ, the
    step's ‖BA‖ and the noise image, and the automatic λ's rule (module doc); progress 0 -> 0.1.

    Parameters
    ----------
    record : Record
        `fpscan.service.recon.tv.problem.working_record`'s.
    dev : {"cpu", "cuda"}
        Where the warm start and the operator pair run.
    report : Reporter
        The run's progress (`fpscan.service.recon.tv.progress.Reporter`; its ``poll`` is the
        operator's checkpoint).
    c : float
        Sound speed, m/s.
    dx, positions, weights, grid
        As `fpscan.service.recon.tv.problem.warm_start`'s (m; ``positions`` ``(n_points, d)``).
    dtype : dtype
        The working precision (float32 or float64).
    eps, t0, positivity, periodic, memory_limit
        The NUFFT tolerance, the time of sample 0 (s), p >= 0, a laterally periodic model, bytes.

    Returns
    -------
    SetUp

    Raises
    ------
    ValueError
        What the warm start and the model refuse; no sensor that sees the image within the
        record (‖A‖ = 0).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.formulation import set_up
    >>> from fpscan.service.recon.tv.problem import working_record
    >>> from fpscan.service.recon.tv.progress import Reporter
    >>> g = np.random.default_rng(0).standard_normal((32, 8))
    >>> rec = working_record(g, 2e-8, 1500.0, 1e-4, None, None, n_z=16)
    >>> s = set_up(rec, "cpu", Reporter(None), c=1500.0, dx=1e-4, positions=None, weights=None, grid=None,
    ...            dtype=np.dtype(np.float64), eps=1e-6, t0=0.0, positivity=True, periodic=False,
    ...            memory_limit=None)
    >>> s.warm.p0.shape, s.gain > 0, s.rule.image_noise > 0
    ((16, 8), True, True)
    """
    warm, pos = warm_start(record, c, dx, positions, weights, grid, dtype=dtype, t0=t0, eps=eps,
                           positivity=positivity, memory_limit=memory_limit,
                           progress=span(report, 0.0, 0.05, "warm start"), device=dev)
    report(0.05, "warm start")
    workspace.release()  # the warm start's work arrays (free now) make way for the operator's
    # A, and B = P Aᵀ: the exact adjoint with NER's k-space weight P = k_z / |k|
    model = Model(record, warm, c, pos, t0=t0, eps=eps, dtype=dtype, periodic=periodic, checkpoint=report.poll,
                  memory_limit=memory_limit, device=dev)
    report(0.06, "norm estimate")  # the operator's set-up and the first adjoint: no longer the warm start
    # the step's ‖BA‖ and the noise image's RMS (per unit σ): the geometry's, kept per geometry
    gain, noise_rms, geometry_kept = geometry_numbers(model, span(report, 0.05, 0.1, "norm estimate"))
    if not gain > 0:
        raise ValueError("no sensor sees the image within the record (‖A‖ = 0): nothing to reconstruct")
    report(0.1, "norm estimate")
    # λ's rule of the image's noise level and the warm start's discrepancy, at least the reach floor's
    # share of L · max x₀ (`fpscan.service.recon.tv.lam`; L = MARGIN ‖BA‖, the solver's first)
    rule = DiscrepancyRule(record.sigma * noise_rms, record.noise_norm,
                           reach_unit=MARGIN * gain * max(0.0, float(warm.p0.max())))
    return SetUp(warm, model, gain, noise_rms, geometry_kept, rule)


@dataclasses.dataclass(frozen=True, eq=False)
class TvProblem:
    """tv's problem for a dataset, as its solver sees it (module doc; Arridge et al., PMB 61
    (2016) 8908): p0 = argmin_{p >= 0} J(p) = ½ ‖A p − g‖² + λ TV(p).

    Vectors are the images and records flattened in C order: an image ``(n_z, n_x)`` /
    ``(n_z, n_y, n_x)`` (the operator's ``dims``), a record as `data` (its ``dimsd``).

    Attributes
    ----------
    operator : pylops.LinearOperator
        A, the exact planar forward model on tv's grid
        (`fpscan.service.recon.operator.PlanarOperator`: ``dims`` the image's shape, ``dimsd`` the
        data's, its ``dtype`` tv's working precision); ``operator.H`` is its exact adjoint.
    data : ndarray
        g, the record tv fits, ``operator.dimsd``: A-lines ``(n_points, n_t)`` (what
        ``fpscan.tv_problem`` gives, a grid dataset's too: one A-line per grid point), or grid
        data ``(n_t, n_x)`` / ``(n_t, n_y, n_x)``; cut where the model predicts silence and
        resampled to the operator's band and samples (`grid`); float64, the data's unit (Pa).
    warm_start : ndarray
        tv's first iterate: the NER / NEDNER image on tv's grid, clipped to >= 0 with
        ``positivity``, ``operator.dims``, the operator's dtype.
    grid : TvGrid
        The grid (`fpscan.service.recon.tv.grid.TvGrid`: the operator's ``n_t``, ``dt`` and
        ``band``, the image's ``dz`` and ``n_z``, the record kept) that λ belongs to.
    lam : float
        λ, the data's unit (Pa): the automatic λ (`fpscan.service.recon.tv.lam`) or the one given.
    positivity : bool
        Whether the problem constrains p >= 0.
    z, x : ndarray
        The image's axes ``(n_z,)``, ``(n_x,)``, m.
    y : ndarray or None
        ``(n_y,)``, m (None for a line).
    gradient : pylops.LinearOperator
        ∇ of TV(p) = ‖∇p‖₂,₁: pylops' ``Gradient(dims, kind="forward", edge=False)`` (voxel
        units), so that pyproximal's ``L21(ndim=len(dims), sigma=lam)`` of ``gradient @ p`` is λ TV(p).
    preconditioner : pylops.LinearOperator
        tv's P = k_z / |k| (NER's k-space weight, `fpscan.service.recon.tv.preconditioner`):
        symmetric positive definite, P AᵀA ≈ const · I for a full planar aperture.
    params : dict
        How λ came about: ``lam_auto``, ``image_noise`` (s, Pa), ``warm_discrepancy`` (D₀),
        ``lam_factor`` (λ / s; None for a given λ), ``lam_floored`` (the automatic λ is the reach
        floor's), ``lam_noise_level`` (the noise-level rule's λ before the floor; None for a given λ),
        ``reach_unit`` (L max x₀, Pa: the step's L times the warm start's peak), ``prox_reach`` (ρ = λ /
        ``reach_unit``), ``noise_sigma`` (σ̂, Pa), ``warm_residual``
        (‖A x₀ − g‖, Pa) and ``step_gain`` (tv's ‖P AᵀA‖ estimate).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.forward import forward_grid
    >>> from fpscan.service.recon.tv.reconstruct import tv_problem
    >>> p0 = np.zeros((12, 16)); p0[5:8, 7:10] = 1.0
    >>> g = forward_grid(p0, dx=1e-4, dz=1e-4, dt=1e-4 / 1500, n_t=24, c=1500.0)
    >>> pb = tv_problem(g, 1e-4 / 1500, 1500.0, dx=1e-4, n_z=12)
    >>> pb.operator.dims, pb.data.shape, pb.warm_start.shape, tuple(map(int, pb.gradient.dimsd))
    ((12, 16), (24, 16), (12, 16), (2, 12, 16))
    >>> bool(np.isclose(pb.objective(pb.warm_start), 0.5 * float(np.sum((pb.operator @ pb.warm_start.ravel()
    ...      - pb.data.ravel()) ** 2)) + pb.lam * pb.total_variation(pb.warm_start)))
    True
    """

    operator: pylops.LinearOperator
    data: np.ndarray
    warm_start: np.ndarray
    grid: TvGrid
    lam: float
    positivity: bool
    z: np.ndarray
    x: np.ndarray
    y: np.ndarray | None
    gradient: pylops.LinearOperator
    preconditioner: pylops.LinearOperator
    params: dict[str, Any]

    def total_variation(self, p: np.ndarray) -> float:
        """TV(p) = Σ_voxels |∇p|₂ (forward differences in voxel units; the solver's own sum,
        `fpscan.service.recon.tv.prox.tv_norm`).

        Parameters
        ----------
        p : array_like
            An image, ``operator.dims`` or flat, Pa.

        Returns
        -------
        float
            Pa.

        Raises
        ------
        ValueError
            ``p`` of another size.
        """
        return tv_norm(self._image(p))

    def objective(self, p: np.ndarray) -> float:
        """J(p) = ½ ‖A p − g‖² + λ TV(p) (Pa²), the value tv minimises (its constraint
        p >= 0 is not part of the value: project first).

        Parameters
        ----------
        p : array_like
            An image, ``operator.dims`` or flat, Pa.

        Returns
        -------
        float
            J(p), Pa²; the residual summed in float64.

        Raises
        ------
        ValueError
            ``p`` of another size.
        """
        image = self._image(p)
        residual = np.asarray(self.operator.matvec(image.ravel()), dtype=np.float64) - self.data.ravel()
        return 0.5 * float(residual @ residual) + self.lam * (tv_norm(image) if self.lam > 0 else 0.0)

    def _image(self, p: np.ndarray) -> np.ndarray:
        dims = tuple(self.operator.dims)
        a = np.asarray(p)
        if a.size != math.prod(dims):
            raise ValueError(f"an image of tv's problem has {math.prod(dims)} values {dims}, got shape {a.shape}")
        return np.ascontiguousarray(a.reshape(dims), dtype=self.operator.dtype)


def problem_of(parts: SetUp, record: Record, lam: float | None, positivity: bool) -> TvProblem:
    """`TvProblem` from `set_up`'s ``parts`` on ``record``: the automatic λ from the warm start's
    residual (one forward, as the solver's first), or ``lam`` as given.

    Parameters
    ----------
    parts : SetUp
        `set_up`'s, made on the CPU.
    record : Record
        The record it was made on.
    lam : float or None
        λ (Pa), or None: the automatic λ.
    positivity : bool
        p >= 0.

    Returns
    -------
    TvProblem

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.formulation import problem_of, set_up
    >>> from fpscan.service.recon.tv.problem import working_record
    >>> from fpscan.service.recon.tv.progress import Reporter
    >>> g = np.random.default_rng(0).standard_normal((32, 8))
    >>> rec = working_record(g, 2e-8, 1500.0, 1e-4, None, None, n_z=16)
    >>> parts = set_up(rec, "cpu", Reporter(None), c=1500.0, dx=1e-4, positions=None, weights=None, grid=None,
    ...                dtype=np.dtype(np.float64), eps=1e-6, t0=0.0, positivity=True, periodic=False,
    ...                memory_limit=None)
    >>> pb = problem_of(parts, rec, 0.5, True)
    >>> pb.lam, pb.params["lam_auto"], pb.operator is parts.model.op
    (0.5, False, True)
    """
    import pylops

    model, warm, rule = parts.model, parts.warm, parts.rule
    start = start_image(warm, model.dtype, positivity)
    residual = model.residual(model.forward(start))
    value = rule(residual) if lam is None else float(lam)
    shape = model.shape
    n = math.prod(shape)
    P = model.P

    def weight(v: np.ndarray) -> np.ndarray:  # P is symmetric: its own adjoint
        return apply_weight(P, np.array(v, dtype=model.dtype).reshape(shape)).ravel()

    preconditioner = pylops.FunctionOperator(weight, weight, n, n, dtype=model.dtype, name="P")
    gradient = pylops.Gradient(shape, sampling=1.0, edge=False, kind="forward", dtype=model.dtype)
    params = dict(rule.params(value, lam is None), noise_sigma=record.sigma, warm_residual=residual,
                  step_gain=parts.gain)
    return TvProblem(operator=model.op, data=record.g, warm_start=start, grid=record.grid, lam=value,
                     positivity=bool(positivity), z=warm.z, x=warm.x, y=warm.y, gradient=gradient,
                     preconditioner=preconditioner, params=params)
