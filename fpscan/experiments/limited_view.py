"""Experiment ``limited-view-2d`` (paper §6): 32 sensors on a 1024-point line.

A tree phantom (crown of discs, vertical trunk) is simulated with the exact planar
forward model (:func:`fpscan.service.recon.forward_grid`) plus white noise 30 dB below the
signal power. The reference (model standard) is the NER reconstruction from all line
points. 32 sensors are then placed

- equispaced (centred, :func:`fpscan.service.plans.subgrid_mask`) with intervals 1..32
  lattice points, reconstructed with NEDNER-NUFFT (weights = interval · pitch);
- equiangular around the point of interest (the ROI centre), NEDNER-NUFFT with the
  mask's r²-weights (:func:`fpscan.service.plans.equiangular_mask`);
- equiangular, linearly interpolated to every line point, then NER (the
  "conventional" route).

Each is scored by the correlation coefficient within the ROI disc and the Tenenbaum
sharpness on the disc's bounding rectangle, against the reference.
Paper: equiangular CC 0.913 vs best equispaced 0.849 (interval 13), interpolated 0.7348;
sharpness equiangular 23001 (above every equispaced), interpolated 21474.
"""
from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from fpscan.constants import C_DEFAULT
from fpscan.experiments.dense import DenseDataset, add_noise
from fpscan.experiments.phantoms import tree_phantom, tree_roi
from fpscan.experiments.result import ExperimentResult, setup_matplotlib
from fpscan.physics.axes import centred_axis
from fpscan.service.metrics import (
    bounding_box,
    correlation_coefficient,
    disc_mask,
    tenenbaum_sharpness,
)
from fpscan.service.pipeline import reconstruct
from fpscan.service.recon.dataset import GridDataset, PointDataset

if TYPE_CHECKING:
    from fpscan.service.plans import Lattice

__all__ = ["NAME", "PAPER", "resample_depth", "simulate_tree", "run", "plot"]

NAME = "limited-view-2d"
PAPER = {"cc_equiangular": 0.913, "cc_best_equispaced": 0.849, "best_interval": 13,
         "cc_interpolated": 0.7348, "sharpness_equiangular": 23001, "sharpness_interpolated": 21474}


def resample_depth(img: np.ndarray, z: np.ndarray, z_new: np.ndarray) -> np.ndarray:
    """Rows of ``img`` linearly interpolated to other depths.

    Parameters
    ----------
    img : ndarray, shape ``(n_z, ...)``
        An image, depth first.
    z : ndarray, shape ``(n_z,)``
        The depths of its rows, m, increasing (at least two).
    z_new : ndarray, shape ``(n_new,)``
        The depths wanted, m, within ``z`` (outside it the end rows are repeated).

    Returns
    -------
    ndarray, shape ``(n_new,) + img.shape[1:]``
        The interpolated rows.
    """
    j = np.clip(np.searchsorted(z, z_new) - 1, 0, len(z) - 2)
    f = np.clip((z_new - z[j]) / (z[j + 1] - z[j]), 0.0, 1.0).reshape((-1,) + (1,) * (img.ndim - 1))
    return img[j] * (1 - f) + img[j + 1] * f


def _normalised(img: np.ndarray, rect: tuple[slice, ...]) -> np.ndarray:
    peak = float(np.max(np.abs(img[rect])))
    return img / peak if peak > 0 else img


def simulate_tree(*, small: bool, snr_db: float | None, seed: int = 0) -> DenseDataset:
    """The built-in §6 dataset: the tree phantom, its forward model and optional noise.

    The phantom on ``(256, 1024)`` (small: ``(64, 256)``) pixels of 50 µm, dt = dx/c, n_t =
    n_x + n_z samples (`fpscan.service.recon.forward_grid`).

    Parameters
    ----------
    small : bool
        The small phantom (tests).
    snr_db : float or None
        Noise level, dB below the data's mean power (`add_noise`); None: clean.
    seed : int, optional
        Seed of the noise.

    Returns
    -------
    DenseDataset
        ``data`` ``(n_t, n_x)`` with noise, ``p0`` the phantom (dz = dx), ``meta['clean']`` the
        clean data (and ``snr_db``, ``seed``).
    """
    from fpscan.service.recon import forward_grid

    n_z, n_x = (64, 256) if small else (256, 1024)
    dx, c = 50e-6, C_DEFAULT
    dt = dx / c
    p0 = tree_phantom(n_z, n_x)
    n_t = n_x + n_z
    clean = forward_grid(p0, dx, dx, dt, n_t, c)
    noisy = add_noise(clean, snr_db, seed)
    return DenseDataset(data=noisy, dx=dx, dt=dt, sound_speed=c, p0=p0, dz=dx, source="tree phantom (built in)",
                        meta={"clean": clean, "snr_db": snr_db, "seed": seed})


def run(
    data: DenseDataset | None = None,
    *,
    small: bool = False,
    n_sensors: int = 32,
    intervals: Iterable[int] | None = None,
    snr_db: float | None = 30.0,
    seed: int = 0,
    roi: tuple[tuple[float, float], float] | None = None,
    include_equiangular: bool = True,
    model_based: bool = True,
    tv_iterations: int | None = None,
) -> ExperimentResult:
    """Run the §6 comparison.

    Parameters
    ----------
    data : a 2-D :class:`DenseDataset` (``(n_t, n_x)``); default the built-in tree
        phantom (noise ``snr_db`` dB, seeded).
    small : smaller built-in phantom (``(64, 256)`` pixels) for tests.
    n_sensors : sensors per arrangement (paper: 32).
    intervals : equispaced intervals; default 1..32, limited to those that fit.
    snr_db : noise level of the built-in phantom (None: clean). Ignored for ``data``.
    roi : ``((z_c, x_c), diameter)`` in m; default the tree's disc (built-in) or a
        disc centred at half the reconstructed depth spanning 95 % of it.
    include_equiangular : also run the equiangular (NEDNER and interpolated) sensors.
    model_based : also reconstruct the equiangular sensors with ``tv`` (model-based:
        TV + positivity, automatic λ; ``tv_iterations`` caps its iterations).

    Returns
    -------
    ExperimentResult with one table row per arrangement: ``arrangement``, ``interval``,
    ``n_sensors``, ``cc`` (ROI, vs the full-data reconstruction), ``sharpness``
    (normalised to the ROI maximum), ``sharpness_rel`` (vs the reference's),
    ``cc_vs_phantom`` (ROI, vs the true p0 when known and on the same grid), ``time_s``.

    Raises
    ------
    ValueError for 3-D data or too few lattice points for ``n_sensors``.
    """
    built_in = data is None
    if data is None:
        data = simulate_tree(small=small, snr_db=snr_db, seed=seed)
    if data.ndim != 2:
        raise ValueError(f"{NAME} needs 2-D line data (n_t, n_x); got shape {data.data.shape}")
    g = data.data
    n_t, n_x = g.shape
    if n_sensors > n_x:
        raise ValueError(f"{n_sensors} sensors do not fit on a line of {n_x} points")
    dx, dt, c = data.dx, data.dt, data.sound_speed
    dz = c * dt
    n_z = data.depth_rows(4)
    x = centred_axis(n_x, dx)

    t_start = time.perf_counter()
    ref_img = reconstruct(data, "ner", n_z=n_z, dz=dz, dtype="float64")
    t_ref = time.perf_counter() - t_start
    ref = ref_img.p0
    z = np.asarray(ref_img.z)
    if roi is None:
        roi = _default_roi(data, built_in, n_z, dz)
    (zc, xc), diameter = roi
    table = _Table(_scorer(data, ref, z, x, roi))
    table.rows.append(table.score(ref, arrangement="full", interval=1, n_sensors=n_x, time_s=t_ref))
    table.images["reference"] = ref
    from fpscan.service.plans import Lattice

    lattice = Lattice(n_x, 1, dx)
    line = _Line(g=g, x=x, dx=dx, dt=dt, c=c, n_z=n_z, dz=dz)
    _run_equispaced(table, line, lattice, range(1, 33) if intervals is None else intervals, n_sensors)
    weight_ratio = np.nan
    if include_equiangular:
        weight_ratio = _run_equiangular(table, line, lattice, (zc, xc), n_sensors, model_based=model_based,
                                        tv_iterations=tv_iterations)

    rows = table.rows
    eqs = [r for r in rows if r["arrangement"] == "equispaced"]
    params = {
        "source": data.source, "n_x": n_x, "n_t": n_t, "n_z": n_z, "dx_m": dx, "dt_s": dt, "sound_speed": c,
        "n_sensors": n_sensors, "snr_db": data.meta.get("snr_db") if built_in else None,
        "seed": seed if built_in else None, "roi_center_m": [zc, xc], "roi_diameter_m": diameter,
        "reference": "NER from every line point", "small": small,
    }
    images = table.images
    images["phantom"] = data.p0
    return ExperimentResult(NAME, params, rows, _summary(rows, weight_ratio),
                            curves={"interval": [r["interval"] for r in eqs], "cc": [r["cc"] for r in eqs],
                                    "sharpness_rel": [r["sharpness_rel"] for r in eqs]},
                            images={"recons": images, "sensors": table.sensors, "z": z, "x": x,
                                    "roi": (zc, xc, diameter)})


def _default_roi(data: DenseDataset, built_in: bool, n_z: int, dz: float) -> tuple[tuple[float, float], float]:
    """``run``'s ROI ``((z_c, x_c), diameter)`` in m when none is given: the built-in tree's
    disc, else a disc centred at half the reconstructed depth spanning 95 % of it."""
    if built_in and data.p0 is not None and data.dz is not None:  # the built-in tree has both
        return tree_roi(data.p0.shape[0], data.dz)
    return (0.5 * n_z * dz, 0.0), 0.95 * n_z * dz


@dataclass
class _Scorer:
    """Scores of a reconstruction ``(n_z, n_x)`` in the ROI ``mask`` against the reference
    ``ref`` and, when known, the true p0 ``truth`` on its own depths ``z_truth`` (m)."""

    ref: np.ndarray
    z: np.ndarray
    mask: np.ndarray
    rect: tuple
    ref_sharp: float
    truth: np.ndarray | None = None
    z_truth: np.ndarray | None = None
    truth_mask: np.ndarray | None = None

    def vs_truth(self, img: np.ndarray) -> float:
        """CC in the ROI against the true p0, ``img`` resampled to its depths (NaN: unknown)."""
        if self.truth is None or self.z_truth is None:
            return np.nan
        return correlation_coefficient(resample_depth(img, self.z, self.z_truth), self.truth, self.truth_mask)

    def __call__(self, img: np.ndarray, **row: Any) -> dict:
        """``row`` with ``cc``, ``sharpness``, ``sharpness_rel`` and ``cc_vs_phantom`` added."""
        sh = tenenbaum_sharpness(_normalised(img, self.rect), self.mask)
        row.update(
            cc=correlation_coefficient(img, self.ref, self.mask),
            sharpness=sh,
            sharpness_rel=sh / self.ref_sharp if self.ref_sharp > 0 else np.nan,
            cc_vs_phantom=self.vs_truth(img),
        )
        return row


def _scorer(data: DenseDataset, ref: np.ndarray, z: np.ndarray, x: np.ndarray,
            roi: tuple[tuple[float, float], float]) -> _Scorer:
    """The scorer of ``run``: the ROI disc on the reconstruction grid ``(z, x)`` (m), and
    the true p0 on its own depth grid (rows within the reconstructed depth, the disc drawn
    on that grid) when the data hold it."""
    (zc, xc), diameter = roi
    mask = disc_mask((z, x), diameter, (zc, xc))
    rect = bounding_box(mask)
    scorer = _Scorer(ref=ref, z=z, mask=mask, rect=rect, ref_sharp=tenenbaum_sharpness(_normalised(ref, rect), mask))
    if data.p0 is not None and data.dz is not None:
        z_truth = np.arange(data.p0.shape[0]) * data.dz
        keep = z_truth <= z[-1] * (1 + 1e-9)
        if keep.sum() >= 2:
            scorer.z_truth, scorer.truth = z_truth[keep], data.p0[keep]
            scorer.truth_mask = disc_mask((scorer.z_truth, x), diameter, (zc, xc))
    return scorer


@dataclass
class _Line:
    """The line data ``g`` ``(n_t, n_x)`` with lateral axis ``x`` (m), and what every
    reconstruction of it shares: ``dx`` m, ``dt`` s, ``c`` m/s, ``n_z`` depth rows of ``dz`` m."""

    g: np.ndarray
    x: np.ndarray
    dx: float
    dt: float
    c: float
    n_z: int
    dz: float

    def points(self, idx: np.ndarray, positions: np.ndarray, weights: np.ndarray) -> PointDataset:
        """The A-lines of line points ``idx`` at ``positions`` ``(n, 1)`` m with ``weights`` (m)."""
        return PointDataset(alines=self.g[:, idx].T, positions=positions, weights=weights, dt=self.dt, sound_speed=self.c,
                            grid=(self.x,))

    def reconstruct(self, data: GridDataset | PointDataset, method: str, **params: Any) -> np.ndarray:
        """p0 ``(n_z, n_x)`` of ``data`` by ``method`` on this line's grid (float64)."""
        return reconstruct(data, method, n_z=self.n_z, dz=self.dz, dtype="float64", **params).p0


@dataclass
class _Table:
    """``run``'s rows, reconstructions and sensor x positions (m) by arrangement."""

    score: _Scorer
    rows: list[dict] = field(default_factory=list)
    images: dict[str, np.ndarray | None] = field(default_factory=dict)
    sensors: dict[str, np.ndarray] = field(default_factory=dict)

    def add(self, key: str, img: np.ndarray, sensor_x: np.ndarray, t0: float, **row: Any) -> None:
        """Score ``img`` (reconstructed since ``t0``, ``time.perf_counter`` s) as ``row``."""
        self.rows.append(self.score(img, **row, time_s=time.perf_counter() - t0))
        self.images[key] = img
        self.sensors[key] = sensor_x


def _run_equispaced(table: _Table, line: _Line, lattice: Lattice, intervals: Iterable[int], n_sensors: int) -> None:
    """``n_sensors`` equispaced sensors at each interval that fits, NEDNER-NUFFT."""
    from fpscan.service.plans import subgrid_mask

    for s in intervals:
        s = int(s)
        if (n_sensors - 1) * s + 1 > line.x.size:
            continue
        sub = subgrid_mask(lattice, s, n_sensors)
        idx = np.asarray(sub.indices)[:, 0]
        t0 = time.perf_counter()
        img = line.reconstruct(line.points(idx, np.asarray(sub.positions, float)[:, :1],
                                           np.asarray(sub.weights, float)), "nedner")
        table.add(f"equispaced_{s}", img, line.x[idx], t0, arrangement="equispaced", interval=s,
                  n_sensors=len(idx))


def _run_equiangular(table: _Table, line: _Line, lattice: Lattice, poi: tuple[float, float], n_sensors: int, *,
                     model_based: bool, tv_iterations: int | None) -> float:
    """``n_sensors`` equiangular sensors around ``poi`` ``(z, x)`` m: NEDNER-NUFFT, ``tv``
    (``model_based``) and interpolated to every line point + NER. Returns the mask's
    outer/inner weight ratio."""
    from fpscan.service.plans import equiangular_mask

    zc, xc = poi
    mask_eq = equiangular_mask(lattice, zc, n_sensors, poi=(xc, 0.0))
    pos = np.asarray(mask_eq.positions, dtype=float)[:, :1]
    w = np.asarray(mask_eq.weights, dtype=float)
    idx = np.asarray(mask_eq.indices)[:, 0]
    row = {"interval": np.nan, "n_sensors": len(idx)}
    t0 = time.perf_counter()
    img = line.reconstruct(line.points(idx, pos, w), "nedner")
    table.add("equiangular", img, pos[:, 0], t0, arrangement="equiangular", **row)
    if model_based:  # the same 32 A-lines, model-based (TV + positivity, automatic λ)
        t0 = time.perf_counter()
        img = line.reconstruct(line.points(idx, pos, w), "tv", max_iter=tv_iterations)
        table.add("equiangular-tv", img, pos[:, 0], t0, arrangement="equiangular-tv", **row)
    # conventional: interpolate the 32 A-lines linearly to every line point, then NER
    t0 = time.perf_counter()
    filled = _interpolated_to_line(pos[:, 0], line.g[:, idx], line.x)
    img = line.reconstruct(GridDataset(data=filled, dx=line.dx, dt=line.dt, sound_speed=line.c), "ner")
    table.add("equiangular-interpolated", img, pos[:, 0], t0, arrangement="equiangular-interpolated", **row)
    return mask_eq.weight_ratio  # outer/inner (fpscan.service.plans.weight_ratio), as every plan states it


def _interpolated_to_line(sensor_x: np.ndarray, alines: np.ndarray, x: np.ndarray) -> np.ndarray:
    """A-lines ``(n_t, n)`` at ``sensor_x`` ``(n,)`` m, linearly interpolated to every line
    point ``x`` ``(n_x,)`` m (constant beyond the outer sensors): ``(n_t, n_x)``."""
    order = np.argsort(sensor_x)
    xs, a = sensor_x[order], alines[:, order]
    j = np.clip(np.searchsorted(xs, x) - 1, 0, len(xs) - 2)
    f = np.clip((x - xs[j]) / (xs[j + 1] - xs[j]), 0.0, 1.0)
    return a[:, j] * (1 - f) + a[:, j + 1] * f


def _summary(rows: list[dict], weight_ratio: float) -> dict:
    """``run``'s summary: the best equispaced CC and its interval, the equiangular CCs and
    sharpness (relative to the reference's), the paper's values."""
    eqs = [r for r in rows if r["arrangement"] == "equispaced"]
    best = max(eqs, key=lambda r: r["cc"]) if eqs else None
    by = {r["arrangement"]: r for r in rows}
    summary = {
        "cc_best_equispaced": best["cc"] if best else np.nan,
        "best_interval": best["interval"] if best else np.nan,
        "cc_equiangular": by.get("equiangular", {}).get("cc", np.nan),
        "cc_interpolated": by.get("equiangular-interpolated", {}).get("cc", np.nan),
        "cc_equiangular_tv": by.get("equiangular-tv", {}).get("cc", np.nan),
        "cc_vs_phantom": {r["arrangement"] if r["arrangement"] != "equispaced" else f"equispaced_{r['interval']}":
                          r["cc_vs_phantom"] for r in rows},
        "sharpness_equiangular_rel": by.get("equiangular", {}).get("sharpness_rel", np.nan),
        "sharpness_max_equispaced_rel": max((r["sharpness_rel"] for r in eqs), default=np.nan),
        "sharpness_interpolated_rel": by.get("equiangular-interpolated", {}).get("sharpness_rel", np.nan),
        "equiangular_weight_ratio": weight_ratio,
        "paper": PAPER,
    }
    if best and "equiangular" in by:
        summary["equiangular_closer_to_1_than_best_equispaced_pct"] = 100 * (1 - (1 - by["equiangular"]["cc"]) / (1 - best["cc"]))
    return summary


def plot(result: ExperimentResult, out_dir: str | Path) -> list:
    """Plot the §6 comparison into ``out_dir``.

    ``limited-view-2d_cc.png`` (CC and sharpness vs interval, equiangular as lines) and
    ``limited-view-2d_images.png`` (reference, best equispaced, equiangular, interpolated, with
    the ROI and the sensors).

    Parameters
    ----------
    result : ExperimentResult
        The result of `run` (its ``curves``, ``table`` and ``images``).
    out_dir : str or pathlib.Path
        An existing folder.

    Returns
    -------
    list of pathlib.Path
        The two PNG files.
    """
    from pathlib import Path

    plt = setup_matplotlib()
    out = Path(out_dir)
    paths = []
    s = result.summary
    cur = result.curves
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    ax[0].plot(cur["interval"], cur["cc"], "o-", ms=3, label="equispaced (NEDNER)")
    ax[1].plot(cur["interval"], cur["sharpness_rel"], "o-", ms=3, label="equispaced (NEDNER)")
    by = {r["arrangement"]: r for r in result.table}
    for key, style, label in (("equiangular", "r-", "equiangular (NEDNER)"),
                              ("equiangular-interpolated", "g--", "equiangular, interpolated + NER"),
                              ("equiangular-tv", "m-.", "equiangular (tv)")):
        if key in by:
            ax[0].axhline(by[key]["cc"], color=style[0], ls=style[1:], label=label)
            ax[1].axhline(by[key]["sharpness_rel"], color=style[0], ls=style[1:], label=label)
    ax[0].set(xlabel="equispaced interval (lattice points)", ylabel="correlation coefficient in ROI",
              title=f"{result.params['n_sensors']} sensors vs full-data NER")
    ax[1].set(xlabel="equispaced interval (lattice points)", ylabel="Tenenbaum sharpness / reference's",
              title="sharpness on the ROI rectangle")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    fig.tight_layout()
    p = out / f"{NAME}_cc.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)

    rec = result.images["recons"]
    z, x = result.images["z"], result.images["x"]
    zc, xc, d = result.images["roi"]
    panels = [("reference", "full data, NER")]
    bi = s.get("best_interval")
    if bi is not None and np.isfinite(bi):
        panels.append((f"equispaced_{int(bi)}", f"best equispaced (interval {int(bi)})"))
    for key, title in (("equiangular", "equiangular, NEDNER"), ("equiangular-interpolated", "equiangular, interpolated + NER"),
                       ("equiangular-tv", "equiangular, tv (model-based)")):
        if key in rec:
            panels.append((key, title))
    ext = [x[0] * 1e3, x[-1] * 1e3, z[-1] * 1e3, z[0] * 1e3]
    fig, axs = plt.subplots(len(panels), 1, figsize=(10, 2.6 * len(panels)), squeeze=False)
    for a, (key, title) in zip(axs[:, 0], panels):
        img = rec[key]
        cc = next((r["cc"] for r in result.table if (r["arrangement"] == key or f"{r['arrangement']}_{r['interval']}" == key)), None)
        a.imshow(img, extent=ext, cmap="gray", aspect="equal", vmin=0, vmax=np.percentile(img, 99.9) or None)
        a.add_patch(plt.Circle((xc * 1e3, zc * 1e3), d / 2 * 1e3, fill=False, color="w", ls=":"))
        sx = result.images["sensors"].get(key)
        if sx is not None:
            a.plot(sx * 1e3, np.zeros_like(sx), "s", color="orange", ms=3, clip_on=False)
        a.set_title(f"{title}" + (f" — CC {cc:.3f}" if cc is not None and key != "reference" else ""), fontsize=9)
        a.set_ylabel("z (mm)")
    axs[-1, 0].set_xlabel("x (mm)")
    fig.tight_layout()
    p = out / f"{NAME}_images.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    paths.append(p)
    return paths
