"""Experiment ``limited-view-2d`` (paper §6): 32 sensors on a 1024-point line.

A tree phantom (crown of discs, vertical trunk) is simulated with the exact planar
forward model (:func:`service.recon.forward_grid`) plus white noise 30 dB below the
signal power. The reference (model standard) is the NER reconstruction from all line
points. 32 sensors are then placed

- equispaced (centred, :func:`service.plans.subgrid_mask`) with intervals 1..32
  lattice points, reconstructed with NEDNER-NUFFT (weights = interval · pitch);
- equiangular around the point of interest (the ROI centre), NEDNER-NUFFT with the
  mask's r²-weights (:func:`service.plans.equiangular_mask`);
- equiangular, linearly interpolated to every line point, then NER (the
  "conventional" route).

Each is scored by the correlation coefficient within the ROI disc and the Tenenbaum
sharpness on the disc's bounding rectangle, against the reference.
Paper: equiangular CC 0.913 vs best equispaced 0.849 (interval 13), interpolated 0.7348;
sharpness equiangular 23001 (above every equispaced), interpolated 21474.
"""
from __future__ import annotations

import time

import numpy as np

from driver.constants import C_DEFAULT
from driver.physics.axes import centred_axis
from service.metrics import (
    bounding_box,
    correlation_coefficient,
    disc_mask,
    tenenbaum_sharpness,
)
from service.pipeline import reconstruct
from service.recon.dataset import GridDataset, PointDataset

from .datasets import DenseDataset, add_noise
from .phantoms import tree_phantom, tree_roi
from .result import ExperimentResult, setup_matplotlib

NAME = "limited-view-2d"
PAPER = {"cc_equiangular": 0.913, "cc_best_equispaced": 0.849, "best_interval": 13,
         "cc_interpolated": 0.7348, "sharpness_equiangular": 23001, "sharpness_interpolated": 21474}


def resample_depth(img: np.ndarray, z: np.ndarray, z_new: np.ndarray) -> np.ndarray:
    """Rows of ``img`` (depths ``z``, m, increasing) linearly interpolated to the depths
    ``z_new`` (within ``z``): ``(len(z_new),) + img.shape[1:]``."""
    j = np.clip(np.searchsorted(z, z_new) - 1, 0, len(z) - 2)
    f = np.clip((z_new - z[j]) / (z[j + 1] - z[j]), 0.0, 1.0).reshape((-1,) + (1,) * (img.ndim - 1))
    return img[j] * (1 - f) + img[j + 1] * f


def _normalised(img: np.ndarray, rect) -> np.ndarray:
    peak = float(np.max(np.abs(img[rect])))
    return img / peak if peak > 0 else img


def simulate_tree(*, small: bool, snr_db: float | None, seed: int = 0) -> DenseDataset:
    """The built-in §6 dataset: tree phantom on ``(256, 1024)`` (small: ``(64, 256)``)
    pixels of 50 µm, dt = dx/c, forward model, optional noise. ``data`` is noisy;
    ``meta['clean']`` holds the clean data."""
    from service.recon import forward_grid

    n_z, n_x = (64, 256) if small else (256, 1024)
    dx, c = 50e-6, C_DEFAULT
    dt = dx / c
    p0 = tree_phantom(n_z, n_x)
    n_t = n_x + n_z
    clean = forward_grid(p0, dx, dx, dt, n_t, c)
    noisy = add_noise(clean, snr_db, seed)
    return DenseDataset(data=noisy, dx=dx, dt=dt, c=c, p0=p0, dz=dx, source="tree phantom (built in)",
                        meta={"clean": clean, "snr_db": snr_db, "seed": seed})


def run(  # noqa: C901 -- one experiment: its arrangements in sequence, one table
    data: DenseDataset | None = None,
    *,
    small: bool = False,
    n_sensors: int = 32,
    intervals=None,
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
    dx, dt, c = data.dx, data.dt, data.c
    dz = c * dt
    n_z = data.depth_rows(4)
    x = centred_axis(n_x, dx)

    t_start = time.perf_counter()
    ref_img = reconstruct(data, "ner", n_z=n_z, dtype="float64")
    t_ref = time.perf_counter() - t_start
    ref = ref_img.p0
    z = np.asarray(ref_img.z)
    if roi is None:
        if built_in and data.p0 is not None and data.dz is not None:  # the built-in tree has both
            roi = tree_roi(data.p0.shape[0], data.dz)
        else:
            roi = ((0.5 * n_z * dz, 0.0), 0.95 * n_z * dz)
    (zc, xc), diameter = roi
    mask = disc_mask((z, x), diameter, (zc, xc))
    rect = bounding_box(mask)
    ref_sharp = tenenbaum_sharpness(_normalised(ref, rect), mask)
    truth = truth_mask = None
    if data.p0 is not None and data.dz is not None:
        # the true p0 on its own depth grid: reconstructions are resampled onto it (rows
        # within the reconstructed depth), the ROI disc drawn on that grid
        z_truth = np.arange(data.p0.shape[0]) * data.dz
        keep = z_truth <= z[-1] * (1 + 1e-9)
        if keep.sum() >= 2:
            z_truth, truth = z_truth[keep], data.p0[keep]
            truth_mask = disc_mask((z_truth, x), diameter, (zc, xc))

    def vs_truth(img):
        if truth is None:
            return np.nan
        return correlation_coefficient(resample_depth(img, z, z_truth), truth, truth_mask)

    def score(img, **row):
        norm = _normalised(img, rect)
        sh = tenenbaum_sharpness(norm, mask)
        row.update(
            cc=correlation_coefficient(img, ref, mask),
            sharpness=sh,
            sharpness_rel=sh / ref_sharp if ref_sharp > 0 else np.nan,
            cc_vs_phantom=vs_truth(img),
        )
        return row

    rows = [score(ref, arrangement="full", interval=1, n_sensors=n_x, time_s=t_ref)]
    images: dict[str, np.ndarray | None] = {"reference": ref}
    sensors = {}
    if intervals is None:
        intervals = range(1, 33)
    from service.plans import Lattice, equiangular_mask, subgrid_mask

    lattice = Lattice(n_x, 1, dx)
    for s in intervals:
        s = int(s)
        if (n_sensors - 1) * s + 1 > n_x:
            continue
        sub = subgrid_mask(lattice, s, n_sensors)
        idx = np.asarray(sub.indices)[:, 0]
        t0 = time.perf_counter()
        img = reconstruct(PointDataset(alines=g[:, idx].T, positions=np.asarray(sub.positions, float)[:, :1],
                                       weights=np.asarray(sub.weights, float), dt=dt, c=c, grid=(x,)),
                          "nedner", n_z=n_z, dtype="float64").p0
        rows.append(score(img, arrangement="equispaced", interval=s, n_sensors=len(idx),
                          time_s=time.perf_counter() - t0))
        images[f"equispaced_{s}"] = img
        sensors[f"equispaced_{s}"] = x[idx]

    if include_equiangular:
        mask_eq = equiangular_mask(lattice, zc, n_sensors, poi=(xc, 0.0))
        pos = np.asarray(mask_eq.positions, dtype=float)[:, :1]
        w = np.asarray(mask_eq.weights, dtype=float)
        idx = np.asarray(mask_eq.indices)[:, 0]
        t0 = time.perf_counter()
        img = reconstruct(PointDataset(alines=g[:, idx].T, positions=pos, weights=w, dt=dt, c=c, grid=(x,)),
                          "nedner", n_z=n_z, dtype="float64").p0
        rows.append(score(img, arrangement="equiangular", interval=np.nan, n_sensors=len(idx),
                          time_s=time.perf_counter() - t0))
        images["equiangular"] = img
        sensors["equiangular"] = pos[:, 0]
        if model_based:  # the same 32 A-lines, model-based (TV + positivity, automatic λ)
            t0 = time.perf_counter()
            img = reconstruct(PointDataset(alines=g[:, idx].T, positions=pos, weights=w, dt=dt, c=c, grid=(x,)),
                              "tv", n_z=n_z, dtype="float64", iterations=tv_iterations).p0
            rows.append(score(img, arrangement="equiangular-tv", interval=np.nan, n_sensors=len(idx),
                              time_s=time.perf_counter() - t0))
            images["equiangular-tv"] = img
            sensors["equiangular-tv"] = pos[:, 0]
        # conventional: interpolate the 32 A-lines linearly to every line point, then NER
        order = np.argsort(pos[:, 0])
        xs, a = pos[order, 0], g[:, idx[order]]
        t0 = time.perf_counter()
        j = np.clip(np.searchsorted(xs, x) - 1, 0, len(xs) - 2)
        f = np.clip((x - xs[j]) / (xs[j + 1] - xs[j]), 0.0, 1.0)
        filled = a[:, j] * (1 - f) + a[:, j + 1] * f
        img = reconstruct(GridDataset(data=filled, dx=dx, dt=dt, c=c), "ner", n_z=n_z, dtype="float64").p0
        rows.append(score(img, arrangement="equiangular-interpolated", interval=np.nan, n_sensors=len(idx),
                          time_s=time.perf_counter() - t0))
        images["equiangular-interpolated"] = img
        sensors["equiangular-interpolated"] = pos[:, 0]
        weight_ratio = mask_eq.weight_ratio  # outer/inner (service.plans.weight_ratio), as every plan states it
    else:
        weight_ratio = np.nan

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
    params = {
        "source": data.source, "n_x": n_x, "n_t": n_t, "n_z": n_z, "dx_m": dx, "dt_s": dt, "c_m_per_s": c,
        "n_sensors": n_sensors, "snr_db": data.meta.get("snr_db") if built_in else None,
        "seed": seed if built_in else None, "roi_center_m": [zc, xc], "roi_diameter_m": diameter,
        "reference": "NER from every line point", "small": small,
    }
    images["phantom"] = data.p0
    return ExperimentResult(NAME, params, rows, summary,
                            curves={"interval": [r["interval"] for r in eqs], "cc": [r["cc"] for r in eqs],
                                    "sharpness_rel": [r["sharpness_rel"] for r in eqs]},
                            images={"recons": images, "sensors": sensors, "z": z, "x": x,
                                    "roi": (zc, xc, diameter)})


def plot(result: ExperimentResult, out_dir) -> list:
    """``limited-view-2d_cc.png`` (CC and sharpness vs interval, equiangular as lines)
    and ``limited-view-2d_images.png`` (reference, best equispaced, equiangular,
    interpolated, with the ROI and the sensors)."""
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
