"""tv's λ: the automatic rule of the image's noise level and the warm start's discrepancy, and
the continuation from a stronger weight down to λ.

Automatic λ (``lam=None``): λ = `LAM_SCALE` s · max(1, (D₀ / `LAM_KNEE`) ** `LAM_POWER`)
(`DiscrepancyRule`). s = ‖P Aᵀ n̂‖_rms is the image's noise level, the RMS of the
preconditioned adjoint of one seeded white-noise record n̂ of the estimated noise level σ̂
(`fpscan.service.recon.tv.grid.noise_sigma`); with P AᵀA ≈ c I the problem is TV denoising of the
least-squares image with weight λ / c, and a weight of the order of the image's noise level
is the classical choice (c cancels). D₀ = ‖A x₀ − g‖ / (σ̂ √N) is the warm start's
discrepancy in units of the noise's norm (free: the solver's first forward): on sparse masks
the image's error is mostly undersampling artefacts, which D₀ measures, and λ rises mildly
with it.

The reach floor: the automatic λ is at least `REACH_FLOOR` · L · max x₀ (L the step's 1 / step
size, `fpscan.service.recon.tv.fista.MARGIN` ‖BA‖; x₀ the warm start). Each iteration's proximal
step weighs TV by λ / L, so ρ = λ / (L max x₀) is how far TV can reshape the image in one
iteration relative to its peak; the directions the sparse data leave to TV move by about that much
a step. Where the noise is low, the noise-level rule's λ gives ρ of 2e-5 to 2e-4, and the image at
the stopping rule is still far from J's minimiser at that λ (up to 0.06 CC below its 300-iteration
image), while a stronger weight both lifts the stopped image and stops it near its own minimiser.
What sets `REACH_FLOOR`: docs/tv-measurements.md, "Automatic λ".

Continuation (``continuation=True``): iteration k takes its proximal step with λ_k = λ ·
max(1, D₀ · `CONTINUATION_RATE` ** (k − 1)) (`Continuation`), from λ D₀ down to λ, D₀ at
least 1 and capped so that λ is reached within `CONTINUATION_MAX` iterations and half of
``max_iter``; the restart test
compares J at λ_k, and the stopping rule's window holds iterations at λ itself only
(`fpscan.service.recon.tv.stopping`). The calibration of the scale, knee and power, and the
continuation's measurements: docs/tv-measurements.md, "Automatic λ" and "Continuation".
"""
from __future__ import annotations

import math

__all__ = ["LAM_SCALE", "LAM_KNEE", "LAM_POWER", "REACH_FLOOR", "CONTINUATION_RATE", "CONTINUATION_MAX",
           "DiscrepancyRule", "Continuation"]

#: the automatic λ = image noise level × LAM_SCALE × max(1, (D₀ / LAM_KNEE) ** LAM_POWER),
#: D₀ the warm start's discrepancy over the noise's norm (module doc; calibrated on
#: docs/results.md's sweep at the stopping rule's default)
LAM_SCALE = 0.6
LAM_KNEE = 9.5
LAM_POWER = 0.25
#: the automatic λ is at least REACH_FLOOR · L · max x₀: its proximal step's weight λ / L at least
#: this share of the warm start's peak (module doc)
REACH_FLOOR = 3e-4
CONTINUATION_RATE = 0.9  # λ_k / λ_{k−1} while λ continues down to λ (module doc)
#: the continuation's iterations at most (half of ``max_iter`` where that is fewer): the cap on
#: noiseless data, where D₀ is in the thousands; it was half the default ``max_iter`` of 100 when
#: the continuation was measured (docs/tv-measurements.md, "Continuation") and stays 50 for any
#: larger ``max_iter``, so that a higher iteration cap lets a run go on without changing its start
CONTINUATION_MAX = 50


class DiscrepancyRule:
    """The automatic λ as a rule of the warm start's residual r₀ = ‖A x₀ − g‖ (module doc).

    ``rule(r₀)`` = max(s · `LAM_SCALE` · max(1, (D₀ / `LAM_KNEE`) ** `LAM_POWER`), `REACH_FLOOR` ·
    ``reach_unit``), D₀ = r₀ / (σ̂ √N), for the image's noise level s and the noise's norm σ̂ √N;
    the noise level after Donoho & Johnstone, Biometrika 81 (1994) 425, the problem after Arridge
    et al., PMB 61 (2016) 8908.

    Parameters
    ----------
    image_noise : float
        s = σ̂ ‖P Aᵀ n̂‖_rms, the image's noise level (the data's unit, Pa).
    noise_norm : float
        σ̂ √N, the noise's norm over the record's N samples (Pa); 0: no noise estimate.
    reach_unit : float, optional
        L · max x₀ (Pa): the step's L times the warm start's peak, the λ at which the proximal
        step would weigh TV by the whole peak (ρ = 1; module doc). 0 (the default): no floor.

    Attributes
    ----------
    image_noise, noise_norm, reach_unit : float
        As given.
    factor : float
        λ / s after the call (`LAM_SCALE` before it, or without a noise estimate).
    warm_discrepancy : float or None
        D₀ after the call (None while unknown, or without a noise estimate).
    floored : bool
        The floor set λ (after the call).
    noise_level_lam : float or None
        The noise-level rule's λ alone, before the floor (after the call; None before it).

    Examples
    --------
    >>> from fpscan.service.recon.tv.lam import DiscrepancyRule
    >>> rule = DiscrepancyRule(image_noise=2.0, noise_norm=10.0)
    >>> rule(50.0), rule.warm_discrepancy, rule.factor  # D₀ = 5 < 9.5: 0.6 s
    (1.2, 5.0, 0.6)
    >>> round(rule(950.0), 6), round(rule.factor, 6)  # D₀ = 95: raised by (95 / 9.5) ** 0.25
    (2.133935, 1.066968)
    >>> low = DiscrepancyRule(image_noise=2.0, noise_norm=10.0, reach_unit=1e4)  # a peak far above s
    >>> round(low(50.0), 6), round(low.factor, 6), low.floored, low.noise_level_lam  # 3e-4 · 1e4 = 3 > 1.2
    (3.0, 1.5, True, 1.2)
    """

    def __init__(self, image_noise: float, noise_norm: float, reach_unit: float = 0.0):
        self.image_noise, self.noise_norm, self.reach_unit = image_noise, noise_norm, reach_unit
        self.factor: float = LAM_SCALE
        self.warm_discrepancy: float | None = None
        self.floored = False
        self.noise_level_lam: float | None = None

    def __call__(self, start_residual: float) -> float:
        d0 = start_residual / self.noise_norm if self.noise_norm > 0 else math.inf
        if math.isfinite(d0):
            self.warm_discrepancy, self.factor = d0, LAM_SCALE * max(1.0, (d0 / LAM_KNEE) ** LAM_POWER)
        lam = self.noise_level_lam = self.image_noise * self.factor
        floor = REACH_FLOOR * self.reach_unit if math.isfinite(self.reach_unit) else 0.0
        self.floored = bool(self.image_noise > 0 and floor > lam)
        if self.floored:
            lam = floor
            self.factor = lam / self.image_noise
        return lam

    def params(self, lam: float, automatic: bool) -> dict:
        """How λ came about, as a result's ``params`` and `fpscan.tv_problem`'s say it (after the call):
        ``lam_auto``, ``image_noise`` (s, Pa), ``warm_discrepancy`` (D₀), ``lam_factor`` (λ / s),
        ``lam_floored``, ``lam_noise_level`` (the noise-level rule's λ before the floor, Pa),
        ``reach_unit`` (L · max x₀, Pa; None without one) and ``prox_reach`` (ρ = λ / ``reach_unit``;
        None without one); ``lam_factor`` and ``lam_noise_level`` are None, and ``lam_floored``
        False, for a λ given by the user.

        Parameters
        ----------
        lam : float
            The λ used (Pa).
        automatic : bool
            λ is this rule's (not given by the user).

        Returns
        -------
        dict
            The eight params.

        Examples
        --------
        >>> from fpscan.service.recon.tv.lam import DiscrepancyRule
        >>> rule = DiscrepancyRule(image_noise=2.0, noise_norm=10.0, reach_unit=1e4)
        >>> p = rule.params(rule(50.0), automatic=True)
        >>> p["lam_floored"], p["lam_noise_level"], p["reach_unit"], p["prox_reach"], round(p["lam_factor"], 6)
        (True, 1.2, 10000.0, 0.0003, 1.5)
        >>> rule.params(0.5, automatic=False)["lam_factor"], rule.params(0.5, automatic=False)["prox_reach"]
        (None, 5e-05)
        """
        return dict(lam_auto=bool(automatic), image_noise=self.image_noise, warm_discrepancy=self.warm_discrepancy,
                    lam_factor=self.factor if automatic else None, lam_floored=bool(automatic and self.floored),
                    lam_noise_level=self.noise_level_lam if automatic else None,
                    reach_unit=float(self.reach_unit) if self.reach_unit > 0 else None,
                    prox_reach=float(lam) / self.reach_unit if self.reach_unit > 0 else None)


class Continuation:
    """λ continuation (module doc): iteration k proximal-steps with λ_k = λ · max(1, f₀ ·
    `CONTINUATION_RATE` ** (k − 1)), from f₀ = D₀ = ‖A x₀ − g‖ / (σ̂ √N) (the warm start's
    discrepancy in noise norms, at least 1) down to λ, in at most `CONTINUATION_MAX` iterations
    and half of ``max_iter`` (f₀ is capped there).

    Parameters
    ----------
    noise_norm : float
        σ̂ √N, the noise's norm over the record (Pa); 0: no noise estimate, no continuation.

    Attributes
    ----------
    noise_norm : float
        As given.
    start_factor : float
        f₀ after ``start(r₀, λ, max_iter)`` (1: none; without a noise estimate, or at λ = 0).
    iterations : int
        How many iterations have λ_k > λ.

    Examples
    --------
    >>> from fpscan.service.recon.tv.lam import Continuation
    >>> c = Continuation(noise_norm=10.0)
    >>> c.start(40.0, 0.1, max_iter=100)  # D₀ = 4
    >>> c.start_factor, c.iterations, c.factor(1), c.factor(100)
    (4.0, 14, 4.0, 1.0)
    >>> c.start(40.0, 0.0, max_iter=100); c.start_factor  # λ = 0: nothing to continue
    1.0
    >>> c.start(58000.0, 0.1, max_iter=150); c.iterations  # D₀ = 5800 (noiseless): capped at 50
    50
    >>> c.start(58000.0, 0.1, max_iter=40); c.iterations  # and at half of max_iter
    20
    """

    def __init__(self, noise_norm: float):
        self.noise_norm = noise_norm
        self.start_factor, self.iterations = 1.0, 0

    def start(self, start_residual: float, lam: float, max_iter: int) -> None:
        d0 = start_residual / self.noise_norm if self.noise_norm > 0 else 1.0
        if not (lam > 0 and math.isfinite(d0) and d0 > 1):
            self.start_factor, self.iterations = 1.0, 0
            return
        # in logs: the cap r^−K, K = min(CONTINUATION_MAX, max_iter // 2)
        cap = min(CONTINUATION_MAX, max_iter // 2)
        steps = math.log(d0) / -math.log(CONTINUATION_RATE)  # the iterations D₀ alone would take
        self.start_factor = math.exp(min(steps, cap) * -math.log(CONTINUATION_RATE))
        # iterations k with f₀ r^(k−1) > 1 (the cap itself where it binds: no rounding past it)
        self.iterations = cap if steps >= cap else math.ceil(steps)

    def factor(self, k: int) -> float:
        return max(1.0, self.start_factor * CONTINUATION_RATE ** (k - 1))

