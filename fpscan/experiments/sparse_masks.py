"""Experiment ``sparse-masks-3d`` (paper §7): ~3 % of a dense planar scan.

From a dense dataset on an ``n × n`` lattice (built in: a yarn phantom on 226 × 226
points of 60 µm through the exact forward model; or any dense file, e.g. the k-Wave
3-D data), the full NER reconstruction's xy-MIP is the model standard. Sensor masks
picking ~3 % of the points are compared with it:

- equi-steradian (:func:`fpscan.service.plans.equisteradian_mask`, ``fraction`` of the lattice,
  point of interest at the lattice centre at depth 0.53 × half the aperture — 3.6 mm
  for the paper's 13.56 mm), NEDNER-NUFFT with its r³-weights;
- equispaced ``m × m`` sub-grids (:func:`fpscan.service.plans.subgrid_mask`; 41 × 41 on
  226 × 226, scaled to the lattice) with intervals 2..5, NEDNER-NUFFT with weights
  interval² · pitch².

Measures on the xy-MIPs: CC vs number of pixels of interest (within a centred disc of
0.62 × the aperture = 8.4 mm of 13.56 mm), CC and Tenenbaum sharpness vs disc diameter
at the 4 % threshold. Paper: at 7.2 mm (0.531 × aperture) CC 0.960 (equi-steradian) vs
0.947 (interval 4) and 0.944 (interval 5).
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from fpscan.constants import C_DEFAULT
from fpscan.experiments.dense import DenseDataset, add_noise
from fpscan.experiments.phantoms import yarn_phantom
from fpscan.experiments.result import ExperimentResult, setup_matplotlib
from fpscan.physics.axes import centred_axis
from fpscan.service.metrics import (
    cc_vs_diameter,
    cc_vs_pixels,
    correlation_coefficient,
    disc_mask,
    mip,
    roi_mask,
    sharpness_vs_diameter,
)
from fpscan.service.pipeline import reconstruct
from fpscan.service.recon.dataset import PointDataset

__all__ = [
    "NAME", "PAPER", "POI_DEPTH_RATIO", "EVAL_DIAMETER_RATIO", "DISC_RATIO", "simulate_yarn", "run", "plot",
]

NAME = "sparse-masks-3d"
PAPER = {"diameter_mm": 7.2, "aperture_mm": 13.56, "cc_equisteradian": 0.960, "cc_interval_4": 0.947,
         "cc_interval_5": 0.944, "n_equisteradian": 1625, "n_equispaced": 1681, "disc_mm": 8.4}
#: Ratios to the aperture side taken from the paper (13.56 mm).
POI_DEPTH_RATIO = 3.6 / 13.56
EVAL_DIAMETER_RATIO = 7.2 / 13.56
DISC_RATIO = 8.4 / 13.56


def simulate_yarn(*, small: bool, snr_db: float | None = None, seed: int = 0) -> DenseDataset:
    """Built-in dense dataset: the yarn phantom through the exact planar forward model.

    A 226 × 226 (small: 64 × 64) lattice of 60 µm, dt = 8 ns, c = 1500 m/s, n_t samples in
    which sound travels 0.6 of the lattice's side.

    Parameters
    ----------
    small : bool
        The small version (tests).
    snr_db : float, optional
        Noise level, dB below the data's mean power (`add_noise`); None (default): clean.
    seed : int, optional
        Seed of the noise.

    Returns
    -------
    DenseDataset
        ``data`` ``(n_t, n, n)``, ``p0`` the yarn ``(n_z, n, n)`` (z, y, x) with dz = the pitch.
    """
    from fpscan.service.recon import forward_grid

    n, d, dt, c = (64, 60e-6, 8e-9, C_DEFAULT) if small else (226, 60e-6, 8e-9, C_DEFAULT)
    half = n * d / 2
    n_z = int(np.ceil((0.53 * half + 0.3 * half) / d))
    p0, _ = yarn_phantom(n_z, n, d)
    n_t = round(0.6 * n * d / (c * dt))
    data = add_noise(forward_grid(p0, d, d, dt, n_t, c), snr_db, seed)
    return DenseDataset(data=data, dx=d, dt=dt, sound_speed=c, dy=d, p0=p0, dz=d, source="yarn phantom (built in)",
                        meta={"snr_db": snr_db, "seed": seed})


def run(
    data: DenseDataset | None = None,
    *,
    small: bool = False,
    fraction: float = 1625 / 226**2,
    intervals: Sequence[int] = (2, 3, 4, 5),
    n_side: int | None = None,
    poi_depth: float | None = None,
    n_diameters: int = 40,
    snr_db: float | None = None,
    model_based: bool = True,
    tv_iterations: int | None = None,
) -> ExperimentResult:
    """Run the §7 comparison.

    Parameters
    ----------
    data : 3-D :class:`DenseDataset` (``(n_t, n, n)``, square lattice); default the
        built-in yarn phantom.
    small : the 64 × 64 built-in phantom (tests).
    fraction : requested equi-steradian points / lattice points (paper 1625/51076).
    intervals : equispaced intervals (paper 2..5).
    n_side : equispaced points per side; default ``round(41 · n / 226)``, reduced until
        the largest interval fits.
    poi_depth : depth of the point of interest in m; default 0.2655 × aperture side.
    n_diameters : samples of the CC/sharpness vs diameter curves.
    snr_db : white noise that many dB below the built-in phantom's signal power (seeded;
        None: clean, the paper's setting). Ignored for ``data``.
    model_based : also reconstruct the equi-steradian points with ``tv`` (model-based:
        TV + positivity, automatic λ; ``tv_iterations`` caps its iterations): row
        ``equi-steradian-tv``.

    Returns
    -------
    ExperimentResult; table rows: ``arrangement``, ``interval``, ``n_points``,
    ``fraction``, ``cc_eval_diameter`` (CC at 0.531 × aperture, 4 % threshold),
    ``cc_disc`` (all 4 %-pixels in the 0.62 × aperture disc), ``sharpness_eval_diameter``,
    ``closer_to_1_pct`` vs each equispaced grid..., ``cc_vs_phantom`` (the xy-MIP's CC
    with the true p0's xy-MIP in the 4 % disc ROI; NaN without a p0 on the lattice) and
    ``time_s``.

    Raises
    ------
    ValueError for 2-D data or a non-square lattice.
    """
    if data is None:
        data = simulate_yarn(small=small, snr_db=snr_db)
    n = _square_side(data)
    d = data.dx
    side = n * d
    n_z = data.depth_rows(4)
    x = centred_axis(n, d)
    n_side = _fitting_side(n, intervals, n_side)
    if poi_depth is None:
        poi_depth = POI_DEPTH_RATIO * side

    t0 = time.perf_counter()
    full = reconstruct(data, "ner", n_z=n_z, dz=data.sound_speed * data.dt, dtype="float64")
    t_full = time.perf_counter() - t0
    score = _Scoring.of(mip(full.p0, "xy"), data.p0, x, side, n_diameters)
    arrangements, weight_ratio = _arrangements(n, d, poi_depth, round(fraction * n * n), intervals, n_side,
                                               model_based)
    rows = [score.full_row(n * n, t_full)]
    mips_, masks = {"full": score.ref}, {}
    curves = {"diameter_m": score.diameters, "pixels": score.counts}
    for arrangement in arrangements:
        t0 = time.perf_counter()
        img = _reconstruct(data, arrangement, x, n_z, tv_iterations)
        elapsed = time.perf_counter() - t0
        m = mip(img, "xy")
        m = m / m.max()
        key = arrangement.name if arrangement.name != "equispaced" else f"interval {arrangement.interval}"
        mips_[key] = m
        masks[key] = arrangement.positions
        curves.update(score.curves(m, key))
        n_points = len(arrangement.ix)
        rows.append({"arrangement": arrangement.name, "interval": arrangement.interval, "n_points": n_points,
                     "fraction": n_points / (n * n), **score.measures(m), "time_s": elapsed})
    summary = _summary(rows, curves, score, side, weight_ratio, model_based)
    params = {"source": data.source, "n_lattice": n, "pitch_m": d, "n_t": data.data.shape[0], "dt_s": data.dt,
              "sound_speed": data.sound_speed, "n_z": n_z, "poi_depth_m": poi_depth, "fraction_requested": fraction,
              "n_side": n_side, "intervals": list(intervals), "threshold": 0.04, "disc_diameter_m": score.disc_d,
              "eval_diameter_m": score.eval_d, "small": small, "reference": "xy-MIP of NER from every lattice point",
              "snr_db": data.meta.get("snr_db") if data.source == "yarn phantom (built in)" else None,
              "tv_iterations": tv_iterations if model_based else None}
    return ExperimentResult(NAME, params, rows, summary, curves=curves,
                            images={"mips": mips_, "masks": masks, "x": x, "disc_d": score.disc_d,
                                    "eval_d": score.eval_d})


def _square_side(data: DenseDataset) -> int:
    """The side n of the dataset's square lattice: ``data.data`` must be ``(n_t, n, n)``
    (ValueError for 2-D data or a non-square lattice)."""
    if data.ndim != 3:
        raise ValueError(f"{NAME} needs 3-D planar data (n_t, n_y, n_x); got shape {data.data.shape}")
    _n_t, n_y, n_x = data.data.shape
    if n_y != n_x:
        raise ValueError(f"{NAME} needs a square lattice, got {n_y} × {n_x}")
    return n_x


def _fitting_side(n: int, intervals: Sequence[int], n_side: int | None) -> int:
    """The equispaced sub-grids' points per side: ``n_side``, by default 41 on 226 scaled
    to the lattice side ``n`` (at least 2), reduced until the largest interval's sub-grid
    fits on the lattice (down to 2)."""
    if n_side is None:
        n_side = max(2, round(41 * n / 226))
    while n_side > 2 and (n_side - 1) * max(intervals) + 1 > n:
        n_side -= 1
    return n_side


class _Arrangement(NamedTuple):
    """One sensor arrangement compared with the full lattice: its ``name``, sub-grid
    ``interval`` (NaN: not a sub-grid), the lattice columns ``ix`` and rows ``iy``
    ``(n_points,)`` of its A-lines, their ``positions`` ``(n_points, 2)`` (x, y) m and area
    ``weights`` ``(n_points,)`` m², and the reconstruction ``method``."""

    name: str
    interval: float
    ix: np.ndarray
    iy: np.ndarray
    positions: np.ndarray
    weights: np.ndarray
    method: str


def _arrangements(n: int, d: float, poi_depth: float, n_points: int, intervals: Sequence[int], n_side: int,
                  model_based: bool) -> tuple[list[_Arrangement], float]:
    """The arrangements on the ``n`` × ``n`` lattice of pitch ``d`` m, in the table's order:
    the equi-steradian mask of ``n_points`` around the lattice centre at ``poi_depth`` m
    (NEDNER), the ``n_side`` × ``n_side`` sub-grid of each interval (NEDNER) and, with
    ``model_based``, the equi-steradian A-lines again with ``tv``; and the equi-steradian
    mask's weight ratio (outer/inner, `fpscan.service.plans.weight_ratio`)."""
    from fpscan.service.plans import Lattice, equisteradian_mask, subgrid_mask

    lattice = Lattice(n, n, d)
    es = equisteradian_mask(lattice, poi_depth, n_points)
    idx = np.asarray(es.indices)
    es_run = (idx[:, 0], idx[:, 1], np.asarray(es.positions, float), np.asarray(es.weights, float))
    out = [_Arrangement("equi-steradian", np.nan, *es_run, "nedner")]
    for interval in intervals:
        sub = subgrid_mask(lattice, int(interval), n_side)
        idx = np.asarray(sub.indices)
        out.append(_Arrangement("equispaced", int(interval), idx[:, 0], idx[:, 1], np.asarray(sub.positions, float),
                                np.asarray(sub.weights, float), "nedner"))
    if model_based:  # the same equi-steradian A-lines, model-based (TV + positivity, automatic λ)
        out.append(_Arrangement("equi-steradian-tv", np.nan, *es_run, "tv"))
    return out, es.weight_ratio


def _reconstruct(data: DenseDataset, arrangement: _Arrangement, x: np.ndarray, n_z: int,
                 tv_iterations: int | None) -> np.ndarray:
    """p0 ``(n_z, n, n)`` (float64, rows of c·dt) reconstructed on the lattice (axis ``x`` m both ways)
    from the arrangement's A-lines of the dense data, with its positions, weights and
    method (``tv`` capped at ``tv_iterations``)."""
    opts: dict[str, Any] = {"max_iter": tv_iterations} if arrangement.method == "tv" else {}
    points = PointDataset(alines=data.data[:, arrangement.iy, arrangement.ix].T, positions=arrangement.positions,
                          weights=arrangement.weights, dt=data.dt, sound_speed=data.sound_speed, grid=(x, x))
    return reconstruct(points, arrangement.method, n_z=n_z, dz=data.sound_speed * data.dt, dtype="float64", **opts).p0


@dataclass(frozen=True)
class _Scoring:
    """The measures an xy-MIP is scored with: against ``ref`` (the full NER reconstruction's
    xy-MIP) on the lattice ``axes`` (x, y) m, CC and Tenenbaum sharpness at ``eval_d`` m
    and along ``diameters`` m (4 % threshold), CC vs the brightest ``counts`` pixels within
    the ``disc`` (diameter ``disc_d`` m), CC over its 4 %-pixels (``disc_roi``), and CC
    there with the true p0's xy-MIP ``truth`` (None: unknown)."""

    ref: np.ndarray
    axes: tuple[np.ndarray, np.ndarray]
    eval_d: float
    disc_d: float
    diameters: Any  # (n_diameters,) float64 m, passed on as the metrics' Sequence[float]
    counts: np.ndarray
    disc: np.ndarray
    disc_roi: np.ndarray
    truth: np.ndarray | None

    @classmethod
    def of(cls, ref: np.ndarray, p0: np.ndarray | None, x: np.ndarray, side: float, n_diameters: int) -> _Scoring:
        """The scoring against ``ref`` ``(n, n)`` on the square lattice of axis ``x``
        ``(n,)`` m and side ``side`` m, along ``n_diameters`` ROI diameters; the truth is the
        xy-MIP of ``p0`` ``(n_z, n, n)`` when it lies on the lattice."""
        n = len(x)
        axes = (x, x)
        disc_d = DISC_RATIO * side
        disc = disc_mask(axes, disc_d)
        truth = None
        if p0 is not None and p0.ndim == 3 and p0.shape[1:] == (n, n):
            truth = mip(p0, "xy")  # the xy-MIP does not depend on the depth sampling
        return cls(ref=ref, axes=axes, eval_d=EVAL_DIAMETER_RATIO * side, disc_d=disc_d,
                   diameters=np.linspace(0.05, 1.0, n_diameters) * side * np.sqrt(2),
                   counts=np.unique(np.geomspace(10, int(disc.sum()), 40).astype(int)), disc=disc,
                   disc_roi=roi_mask(ref, axes=axes, diameter=disc_d, threshold=0.04), truth=truth)

    def vs_truth(self, m: np.ndarray) -> float:
        """CC of the xy-MIP ``m`` with the truth's over ``disc_roi``; NaN without a truth."""
        return correlation_coefficient(m, self.truth, self.disc_roi) if self.truth is not None else np.nan

    def full_row(self, n_points: int, time_s: float) -> dict:
        """The table row of the reference itself (``n_points`` lattice points, reconstructed
        in ``time_s`` s)."""
        ref = self.ref
        return {"arrangement": "full", "interval": 1, "n_points": n_points, "fraction": 1.0,
                "cc_eval_diameter": 1.0, "cc_disc": 1.0,
                "sharpness_eval_diameter": float(sharpness_vs_diameter(ref / ref.max(), ref, [self.eval_d],
                                                                       axes=self.axes)[0]),
                "cc_vs_phantom": self.vs_truth(ref), "time_s": time_s}

    def curves(self, m: np.ndarray, key: str) -> dict[str, np.ndarray]:
        """The curves of the normalised xy-MIP ``m`` (arrangement ``key``): CC vs pixels, CC
        and sharpness vs diameter."""
        ref, axes, diameters = self.ref, self.axes, self.diameters
        return {f"cc_vs_pixels[{key}]": cc_vs_pixels(m, ref, self.counts, region=self.disc),
                f"cc_vs_diameter[{key}]": cc_vs_diameter(m, ref, diameters, axes=axes, threshold=0.04),
                f"sharpness_vs_diameter[{key}]": sharpness_vs_diameter(m, ref, diameters, axes=axes, threshold=0.04)}

    def measures(self, m: np.ndarray) -> dict[str, float]:
        """The table's measures of the normalised xy-MIP ``m``: CC and sharpness at the
        evaluation diameter, CC over the disc's 4 %-pixels and with the truth."""
        ref, axes, eval_d = self.ref, self.axes, self.eval_d
        return {"cc_eval_diameter": float(cc_vs_diameter(m, ref, [eval_d], axes=axes, threshold=0.04)[0]),
                "cc_disc": correlation_coefficient(m, ref, self.disc_roi),
                "sharpness_eval_diameter": float(sharpness_vs_diameter(m, ref, [eval_d], axes=axes,
                                                                       threshold=0.04)[0]),
                "cc_vs_phantom": self.vs_truth(m)}


def _summary(rows: list[dict], curves: dict, score: _Scoring, side: float, weight_ratio: float,
             model_based: bool) -> dict:
    """The headline numbers: the equi-steradian CC at the evaluation diameter (and its
    ``tv`` row's with ``model_based``), the mask's weight ratio, every row's CC with the
    phantom, and the comparison with each equispaced grid (`_versus_grids`) within the
    paper's 2..8 mm band scaled to the lattice side ``side`` m."""
    es_row = rows[1]
    diameters = score.diameters
    band = (diameters >= 2 / 13.56 * side) & (diameters <= 8 / 13.56 * side)
    summary = {"cc_equisteradian": es_row["cc_eval_diameter"], "eval_diameter_m": score.eval_d,
               "weight_ratio_equisteradian": weight_ratio,  # outer/inner, fpscan.service.plans.weight_ratio
               "paper": PAPER}
    if model_based:
        summary["cc_equisteradian_tv"] = rows[-1]["cc_eval_diameter"]
    summary["cc_vs_phantom"] = {r["arrangement"] if r["arrangement"] != "equispaced" else f"interval_{r['interval']}":
                                r["cc_vs_phantom"] for r in rows}
    summary.update(_versus_grids(es_row, rows, curves, band))
    return summary


def _versus_grids(es_row: dict, rows: list[dict], curves: dict, band: np.ndarray) -> dict:
    """The equi-steradian mask against each equispaced grid: its CC, how much closer to 1
    the equi-steradian CC is at the evaluation diameter and on average within ``band``
    (the paper's 2..8 mm, scaled) of the CC-vs-diameter curves."""
    out: dict = {}
    for r in rows:
        if r["arrangement"] != "equispaced":
            continue
        key = f"interval {r['interval']}"
        out[f"cc_{key.replace(' ', '_')}"] = r["cc_eval_diameter"]
        out[f"closer_to_1_pct_vs_{key.replace(' ', '_')}"] = 100 * (1 - (1 - es_row["cc_eval_diameter"]) / (1 - r["cc_eval_diameter"]))
        a = 1 - np.asarray(curves["cc_vs_diameter[equi-steradian]"])[band]
        b = 1 - np.asarray(curves[f"cc_vs_diameter[{key}]"])[band]
        ok = np.isfinite(a) & np.isfinite(b) & (b > 0)
        out[f"mean_closer_to_1_pct_2_to_8mm_scaled_vs_{key.replace(' ', '_')}"] = (
            float(100 * np.mean(1 - a[ok] / b[ok])) if ok.any() else np.nan)
    return out


def plot(result: ExperimentResult, out_dir: str | Path) -> list[Path]:
    """Plot the §7 comparison into ``out_dir``.

    ``sparse-masks-3d_curves.png`` (CC vs pixels, CC vs diameter, sharpness vs diameter) and
    ``sparse-masks-3d_mips.png`` (masks and xy-MIPs).

    Parameters
    ----------
    result : ExperimentResult
        The result of `run`.
    out_dir : str or pathlib.Path
        An existing folder.

    Returns
    -------
    list of pathlib.Path
        The two PNG files.
    """
    plt = setup_matplotlib()
    out = Path(out_dir)
    cur = result.curves
    keys = [k for k in result.images["mips"] if k != "full"]
    side = result.params["n_lattice"] * result.params["pitch_m"]
    fig, ax = plt.subplots(1, 3, figsize=(15, 4))
    dmm = np.asarray(cur["diameter_m"]) * 1e3
    for k in keys:
        ls = {"equi-steradian": "-", "equi-steradian-tv": "-."}.get(k, "--")
        lw = 2 if k.startswith("equi-steradian") else 1
        ax[0].semilogx(cur["pixels"], cur[f"cc_vs_pixels[{k}]"], ls, lw=lw, label=k)
        ax[1].plot(dmm, cur[f"cc_vs_diameter[{k}]"], ls, lw=lw, label=k)
        ax[2].plot(dmm, cur[f"sharpness_vs_diameter[{k}]"], ls, lw=lw, label=k)
    ax[1].axvline(result.params["eval_diameter_m"] * 1e3, color="k", lw=0.7, ls=":")
    ax[0].set(xlabel="pixels of interest (brightest first)", ylabel="CC of xy-MIP",
              title=f"CC vs pixels (disc {result.params['disc_diameter_m'] * 1e3:.1f} mm)")
    ax[1].set(xlabel="ROI diameter (mm)", ylabel="CC of xy-MIP", title="CC vs ROI diameter (4 % threshold)")
    ax[2].set(xlabel="ROI diameter (mm)", ylabel="Tenenbaum sharpness (MIP / max)", title="sharpness vs ROI diameter")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    ax[1].set_ylim(max(0.0, np.nanmin([np.nanmin(cur[f'cc_vs_diameter[{k}]']) for k in keys]) - 0.02), 1.0)
    fig.tight_layout()
    p1 = out / f"{NAME}_curves.png"
    fig.savefig(p1, dpi=110)
    plt.close(fig)

    x = result.images["x"] * 1e3
    ext = [x[0], x[-1], x[-1], x[0]]
    show = ["full"] + keys
    fig, axs = plt.subplots(2, len(show), figsize=(3 * len(show), 6), squeeze=False)
    ref = result.images["mips"]["full"]
    for j, k in enumerate(show):
        im = result.images["mips"][k]
        axs[1, j].imshow(im, extent=ext, cmap="gray", vmin=0, vmax=np.percentile(im, 99.9))
        axs[1, j].add_patch(plt.Circle((0, 0), result.images["eval_d"] / 2 * 1e3, fill=False, color="r", ls=":"))
        axs[1, j].set_title(f"xy-MIP: {k}", fontsize=9)
        if k in result.images["masks"]:
            pos = result.images["masks"][k] * 1e3
            axs[0, j].plot(pos[:, 0], pos[:, 1], ".", ms=1.5)
            axs[0, j].set_title(f"{k}: {len(pos)} points", fontsize=9)
        else:
            axs[0, j].imshow(ref > 0.04 * ref.max(), extent=ext, cmap="gray")
            axs[0, j].set_title("pixels >= 4 % of max", fontsize=9)
        axs[0, j].set_xlim(x[0], x[-1])
        axs[0, j].set_ylim(x[-1], x[0])
        axs[0, j].set_aspect("equal")
    fig.suptitle(f"lattice {result.params['n_lattice']}² at {result.params['pitch_m'] * 1e6:.0f} µm "
                 f"({side * 1e3:.2f} mm); red: {result.params['eval_diameter_m'] * 1e3:.2f} mm ROI", fontsize=10)
    fig.tight_layout()
    p2 = out / f"{NAME}_mips.png"
    fig.savefig(p2, dpi=100)
    plt.close(fig)
    return [p1, p2]
