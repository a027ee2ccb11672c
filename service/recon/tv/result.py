"""tv's record of a run: the result's ``params`` (`reconstruct_tv`'s Returns list them).

The warm start's params, then the grid (the record's ``dt``, the operator's sampling and band,
the record kept) and the solve: λ and how it was set (`fpscan.service.recon.tv.lam`), the noise
levels, the stopping rule's outcome (`fpscan.service.recon.tv.stopping`), the operator pairs used
and the wall time.
"""
from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from fpscan.service.recon.tv.fista import MARGIN, Solved
from fpscan.service.recon.tv.lam import Continuation, DiscrepancyRule
from fpscan.service.recon.tv.problem import Model, Record
from fpscan.service.recon.tv.stopping import WINDOW

__all__ = ["result_params"]


def result_params(warm_params: dict[str, Any], record: Record, model: Model, solved: Solved, rule: DiscrepancyRule,
            schedule: Continuation | None, options: dict[str, Any], *, lam_auto: bool, geometry_kept: bool,
            debiased: bool, started: float) -> dict[str, Any]:
    """The result's params (`fpscan.service.recon.tv.reconstruct.reconstruct_tv`'s Returns list them).

    ``warm_params`` updated with the grid of ``record`` (the record's ``dt``, the operator's
    sampling and band, the record kept) and the solve: λ and how it was set, the noise levels,
    the stopping rule's outcome, the operator pairs of ``model`` and the wall time.

    Parameters
    ----------
    warm_params : dict
        The warm start's params (``method`` among them).
    record : Record
        The record (`fpscan.service.recon.tv.problem.Record`: ``g``, ``grid``, ``n_t``, ``sigma``,
        ``noise_norm``).
    model : Model
        Its ``pos`` (None: grid data) and ``operator_pairs``.
    solved : Solved
        The solver's outcome (`fpscan.service.recon.tv.fista.Solved`).
    rule : DiscrepancyRule
        The automatic λ's rule (`fpscan.service.recon.tv.lam.DiscrepancyRule.params`: how λ came about).
    schedule : Continuation or None
        λ's continuation.
    options : dict
        The run's ``dt`` (s), ``bandwidth`` (Hz), ``whole_record``, ``max_iter``, ``tol``,
        ``dtype``, ``positivity``, ``periodic`` and ``time_limit`` (s).
    lam_auto : bool
        λ was automatic.
    geometry_kept : bool
        ‖BA‖ and the noise image came from `fpscan.service.recon.tv.geometry.GEOMETRY`.
    debiased : bool
        The amplitudes were refit.
    started : float
        The run's `time.monotonic` start, s.

    Returns
    -------
    dict
        The params.

    Examples
    --------
    >>> import time
    >>> import numpy as np
    >>> from types import SimpleNamespace
    >>> from fpscan.service.recon.tv.fista import Solved
    >>> from fpscan.service.recon.tv.lam import DiscrepancyRule
    >>> from fpscan.service.recon.tv.result import result_params
    >>> grid = SimpleNamespace(dt=1e-8, band=None, reason="nyquist", record_n_t=4, extent_reason="record")
    >>> record = SimpleNamespace(g=np.ones((4, 2)), grid=grid, n_t=4, sigma=0.0, noise_norm=0.0)
    >>> solved = Solved(np.ones((3, 2)), 5, "converged", 1e-3, np.ones((4, 2)), 2.2, 0.0)
    >>> options = dict(dt=1e-8, bandwidth=None, whole_record=False, max_iter=50, tol=0.005,
    ...                dtype=np.dtype("float32"), positivity=True, periodic=False, time_limit=60.0)
    >>> p = result_params({"method": "ner"}, record, SimpleNamespace(pos=None, operator_pairs=8.0), solved,
    ...                   DiscrepancyRule(0.0, 0.0), None, options, lam_auto=True, geometry_kept=False,
    ...                   debiased=False, started=time.monotonic())
    >>> p["method"], p["warm_start"], p["residual"], p["norm_A"], p["stop_reason"], p["solver"]
    ('tv', 'ner', 0.0, 2.0, 'converged', 'FISTA preconditioned by NER')
    >>> p["lam_note"].startswith("the data show no noise"), p["exact_from"]
    (True, None)
    """
    chosen, o = record.grid, options
    x, it, stop_reason, change, Ax, L, lam, exact_from = solved
    gw_norm = float(np.linalg.norm(record.g))
    res = Ax - record.g
    params = dict(warm_params)
    params.update(dt=o["dt"], operator_dt=chosen.dt, operator_n_t=record.n_t, band=chosen.band,
                  band_reason=chosen.reason, bandwidth=o["bandwidth"], record_n_t=chosen.record_n_t,
                  extent_reason=chosen.extent_reason, whole_record=bool(o["whole_record"]))
    params.update(method="tv", warm_start=warm_params["method"], lam=float(lam), **rule.params(lam, lam_auto),
                  lam_start_factor=schedule.start_factor if schedule else 1.0,
                  continuation_iterations=schedule.iterations if schedule else 0,
                  stop_armed_at=((schedule.iterations if schedule else 0) + WINDOW) if o["tol"] > 0 else None,
                  noise_sigma=record.sigma, noise_share=record.noise_norm / max(gw_norm, 1e-300), iterations=it,
                  max_iter=o["max_iter"], tol=o["tol"], dtype=o["dtype"].name,
                  residual=float(np.linalg.norm(res) / max(gw_norm, 1e-300)),
                  norm_A=L / MARGIN, positivity=bool(o["positivity"]), weights_mean_one=False,
                  data_weights="equal", periodic=bool(o["periodic"]),
                  solver="FISTA preconditioned by " + ("NER" if model.pos is None else "NEDNER"),
                  iterate_change=change if math.isfinite(change) else None,
                  operator_pairs=model.operator_pairs, geometry_kept=geometry_kept, debias=debiased,
                  exact_from=exact_from,
                  converged=stop_reason == "converged", stop_reason=stop_reason,
                  time_limit=o["time_limit"], solve_s=time.monotonic() - started)
    if lam_auto and lam == 0:  # said, not silent: on noiseless data the automatic λ has nothing to scale
        params["lam_note"] = ("the data show no noise (σ̂ = 0: the finest wavelet coefficients along time vanish), "
                              "so the automatic λ is 0, a least-squares fit"
                              + (" with positivity" if o["positivity"] else "")
                              + "; set λ (--lambda; lam over HTTP) for a TV weight")
    return params
