"""Model-based reconstruction: total variation + positivity on the exact planar model.

Solves (Arridge, Beard, Betcke, Cox, Huynh, Lucka, Ogunlade, Zhang,
"Accelerated high-resolution photoacoustic tomography via compressed sensing",
Phys. Med. Biol. 61 (2016) 8908)::

    p0 = argmin_{p >= 0}  J(p) = ½ ‖A p − g‖² + λ TV(p)

with A the exact planar forward model (`fpscan.service.recon.operator.PlanarOperator`, free space,
sensors on the grid or at arbitrary positions), every A-line weighted equally (each carries
white noise of the same σ: the maximum-likelihood data term) and TV(p) = Σ_voxels |∇p|₂ the
isotropic total variation with forward differences in voxel units (J in Pa², so λ is in Pa).
Positivity is on by default (``positivity=False`` drops it). `tv_problem` hands out this problem
for any solver (the operator A as a ``pylops.LinearOperator``, g, the warm start, the grid, λ and
J itself; ``fpscan.tv_problem`` for a dataset).

What a run returns: the solver's iterations converge to J's minimiser, in two phases
(``fista``). The first, NER-preconditioned, is fast but its fixed point solves 0 ∈ P ∇f(p) +
∂(λ TV + positivity)(p) with f = ½‖A p − g‖² and P NER's weight, not J's minimiser; the default
stopping rule (``tol`` 5e-3) ends there, once the image has settled (on k-Wave's vessel tree at
11 % of the lattice: J 2.4 % above its minimum, CC 0.989 with the true p0). A run with a smaller
``tol`` (or 0) then goes on with exact steps, whose fixed point is J's minimiser (there, after
300 iterations, J 0.03 % below pyproximal's tuned PrimalDual's, CC 0.989: docs/tv-measurements.md,
"What tv minimises"). `reconstruct_tv` is the algorithm; each of its parts is a module of this
package, with its own public interface (its ``__all__``):

- ``reconstruct``: `reconstruct_tv`, the parts below assembled, and its defaults
  (``DEFAULT_MAX_ITER``, ``DEFAULT_TOL``, ``DEFAULT_TIME_LIMIT``); `tv_problem`, the problem alone.
- ``formulation``: the problem set up once for tv's solver and for any other (`set_up`,
  `TvProblem`): the warm start, A and B, the step's ‖BA‖, λ's rule.
- ``grid``: the grid tv works on (`TvGrid`, `tv_grid`): the operator's band (c / (2 pitch), or a
  declared ``bandwidth``) and time sampling, the image's depth grid (isotropic by default),
  the record kept (cut where the model predicts silence) and the noise level `noise_sigma`;
  pure numpy, so that a server sizes a tv job from it (`RecordFacts`, `record_facts`).
- ``problem``: the options' checks, the record on that grid (`working_record`), the warm start
  on it (NER for grid data, NEDNER for A-lines, clipped to >= 0) and the model A and B = P Aᵀ
  (`Model`).
- ``preconditioner``: P = k_z / |k|, NER's k-space weight, which inverts AᵀA's symbol |k| /
  k_z for a full planar aperture.
- ``geometry``: the step 1 / L, L ≈ 1.1 ‖P AᵀA‖ from two seeded power iterations, and the
  image's noise level; kept for the last few geometries (``params["geometry_kept"]``).
- ``lam``: the automatic λ (``lam=None``) = 0.6 s · max(1, (D₀ / 9.5)^0.25), s the image's
  noise level ‖P Aᵀ n̂‖_rms and D₀ = ‖A x₀ − g‖ / (σ̂ √N) the warm start's discrepancy; and
  the continuation (``continuation=True``): λ_k = λ · max(1, D₀ · 0.9^(k−1)).
- ``fista``: the solver loop, accelerated proximal gradient (FISTA) preconditioned by P,
  with a constant momentum 0.94 restarted when J rises or the momentum points uphill; L rises
  where the iterates show a larger gain; once the image has settled at λ, a run asked to go on
  takes the exact steps (the gradient step corrected by L (P s − s), s the last proximal step's
  v − x: fixed points are J's minimisers); ``debias=True`` refits the amplitudes at λ = 0 on
  tv's support.
- ``prox``: the proximal map of λ TV + positivity, gradient projection on the dual (Chambolle
  2005), warm-started from the previous iteration's dual, in compiled sweeps that work in place.
- ``stopping``: the image's relative change per iteration below ``tol`` in each of the last 3
  iterations at λ itself ("converged"), so never before iteration K + 3 after a continuation of K
  (``armed_at``, known from the first iteration); else ``max_iter`` ("iterations") or the time limit.
- ``stores``: the dual, the last gradient and the last move wait between iterations as 16-bit
  fixed point, so the solver holds about 1 image, the dual's d/2 and two halves while the
  operator works (`fpscan.service.recon.memory.tv_memory`).
- ``progress``: increasing fractions and stages ("iteration k/N (λ continuation k/K)" while λ
  falls), polled inside long steps so a cancel acts.
- ``result``: the result's ``params``.
- ``kernels``: the solver's whole-image operations as one set per array namespace (the
  compiled loops on the CPU, CuPy's array expressions on a GPU).

Why each rule and number is what it is (the measurements on the test cases, k-Wave's vessel
tree and the paper's scan, and the rules measured and not built): docs/tv-measurements.md.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

__all__ = ["DEFAULT_MAX_ITER", "DEFAULT_TOL", "DEFAULT_TIME_LIMIT", "TvGrid", "TvProblem", "noise_sigma", "reconstruct_tv",
           "tv_grid", "tv_problem"]

#: where each public name lives: imported on first use (PEP 562), so that importing the package
#: (or its numba-free ``grid``, as the server's memory admission does) loads no solver
_LAZY = {"DEFAULT_MAX_ITER": "reconstruct", "DEFAULT_TOL": "reconstruct", "DEFAULT_TIME_LIMIT": "reconstruct",
         "reconstruct_tv": "reconstruct", "tv_problem": "reconstruct", "TvProblem": "formulation", "TvGrid": "grid",
         "noise_sigma": "grid", "tv_grid": "grid"}

if TYPE_CHECKING:
    from fpscan.service.recon.tv.formulation import TvProblem
    from fpscan.service.recon.tv.grid import TvGrid, noise_sigma, tv_grid
    from fpscan.service.recon.tv.reconstruct import (
        DEFAULT_MAX_ITER,
        DEFAULT_TIME_LIMIT,
        DEFAULT_TOL,
        reconstruct_tv,
        tv_problem,
    )


def __getattr__(name: str) -> Any:
    """`reconstruct_tv`, `tv_problem` and their names (they load the solver: numba, pylops) and
    the grid's names, on first use."""
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
