"""Experiment ``vessels`` (docs/results.md): a thin vessel tree from a sparse, noisy 3-D scan.

FP scanners image vasculature, so this is the model-based method's main case. The vessel
phantom (:func:`.phantoms.vessel_phantom`: a trunk forking three times, tubes 4, 3, 2 and
1 voxels wide, mostly parallel to the sensor plane) on a cubic grid of 50 µm voxels is
simulated with the exact forward model (`fpscan.service.recon.forward_grid`, every lattice
point), white noise ``snr_db`` below the data's RMS is added, and p0 is reconstructed by
the one dispatch (:func:`fpscan.service.pipeline.reconstruct`) with

- ``ner``: every lattice point (full data, the reference a dense scan gives);
- ``nedner``: an equi-steradian mask of ``fraction`` of the lattice around a point of
  interest at the tree's depth (:func:`fpscan.service.plans.equisteradian_mask`, its area weights);
- ``tv``: the same sparse A-lines, default settings (automatic λ, its stopping rule).

Measured per method against the true p0: CC over the volume, the least-squares amplitude
(argmin_a ‖img − a p0‖), the lowest contrast of a branch 2 voxels or wider (centre line
over a shell 3-8 voxels beyond its surface, relative to the true p0's own contrast measured
the same way), run time, and for tv its iterations, operator pairs and whether it converged.
The figure ``vessels_mips.png`` shows the depth MIPs (xy) and the lateral MIPs (xz) of the
true p0 and the three reconstructions side by side, each on its own grey scale.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from fpscan.constants import C_DEFAULT
from fpscan.experiments.dense import DenseDataset
from fpscan.experiments.phantoms import vessel_phantom, vessel_tree
from fpscan.experiments.result import ExperimentResult, setup_matplotlib
from fpscan.physics.axes import centred_axis
from fpscan.service.metrics import correlation_coefficient
from fpscan.service.pipeline import reconstruct

__all__ = ["NAME", "METHODS", "simulate_vessels", "branch_contrasts", "run", "plot"]

NAME = "vessels"
METHODS = ("ner", "nedner", "tv")


def simulate_vessels(*, small: bool, snr_db: float = 30.0, seed: int = 0) -> DenseDataset:
    """Built-in dataset: the vessel tree, every lattice point recorded, with noise.

    48 x 96 x 96 (small: 24 x 40 x 40) voxels of 50 µm, dt = dx / c (c = 1500 m/s), every
    lattice point recorded for the time a sound wave crosses the volume's diagonal, white
    noise ``snr_db`` below the data's RMS (seeded).

    Parameters
    ----------
    small : bool
        The small version (tests).
    snr_db : float, optional
        Noise level in dB (default 30).
    seed : int, optional
        Seed of the noise.

    Returns
    -------
    DenseDataset
        ``data`` ``(n_t, n_x, n_x)`` with noise, ``p0`` (z, y, x) the truth (dz = dx).
    """
    from fpscan.service.recon import forward_grid

    n_z, n_x = (24, 40) if small else (48, 96)
    dx = 50e-6
    c = C_DEFAULT
    dt = dx / c
    p0 = vessel_phantom((n_z, n_x, n_x))
    n_t = int(np.hypot(n_z, n_x / np.sqrt(2))) + 8
    clean = forward_grid(p0, dx, dx, dt, n_t, c)
    rms = float(np.sqrt(np.mean(clean**2)))
    noise = np.random.default_rng(seed).standard_normal(clean.shape) * rms / 10 ** (snr_db / 20)
    return DenseDataset(data=clean + noise, dx=dx, dt=dt, sound_speed=c, p0=p0, dz=dx,
                        source=f"vessel tree (built in), {snr_db:g} dB", meta={"snr_db": snr_db})


def branch_contrasts(img: np.ndarray, truth: np.ndarray) -> list[dict]:
    """Contrast of every vessel branch 2 voxels or wider in ``img``, relative to the truth's.

    A branch's contrast: the mean along the middle of its centre line (points 40-160 of 200:
    away from its forks) minus the mean over a shell 3-8 voxels beyond its surface, away from
    every vessel; the same measure on ``truth`` is the reference.

    Parameters
    ----------
    img : ndarray
        A reconstruction on the phantom's grid, ``(n_z, n_y, n_x)`` (or ``(n_z, n_x)``).
    truth : ndarray
        The true p0 on the same grid.

    Returns
    -------
    list of dict
        One per branch: ``width`` (voxels), ``contrast``, ``true_contrast``, ``relative``
        (their ratio).
    """
    shape = img.shape
    grids = np.meshgrid(*[np.arange(n, dtype=float) if i == 0 else np.arange(n) - (n - 1) / 2
                          for i, n in enumerate(shape)], indexing="ij")
    near = np.zeros(shape, bool)
    lines = []
    for start, end, width in vessel_tree(shape):
        pts = start[None, :] + np.linspace(0.0, 1.0, 200)[:, None] * (end - start)[None, :]
        d = np.full(shape, np.inf)
        for p in pts:
            np.minimum(d, np.sqrt(sum((g - c) ** 2 for g, c in zip(grids, p))), out=d)
        near |= d <= width / 2 + 2
        lines.append((pts, d, width))
    out = []
    for pts, d, width in lines:
        if width < 2:
            continue
        inner = pts[40:160]
        idx = tuple(np.rint(inner[:, i] + (0 if i == 0 else (shape[i] - 1) / 2)).astype(int)
                    for i in range(len(shape)))
        ring = (d >= width / 2 + 3) & (d <= width / 2 + 8) & ~near
        got = float(np.mean(img[idx]) - np.mean(img[ring]))
        true = float(np.mean(truth[idx]) - np.mean(truth[ring]))
        out.append({"width": width, "contrast": got, "true_contrast": true, "relative": got / true})
    return out


def run(data: DenseDataset | None = None, *, small: bool = False, fraction: float = 0.1,
        snr_db: float = 30.0, model_based: bool = True) -> ExperimentResult:
    """Run the experiment on the built-in vessel tree.

    NER on every lattice point, NEDNER and tv on a sparse equi-steradian mask (float32).

    Parameters
    ----------
    data : DenseDataset, optional
        Must be None: the oracle is the phantom.
    small : bool, optional
        The small phantom (tests).
    fraction : float, optional
        Share of the lattice in the sparse equi-steradian mask, in (0, 1] (default 0.1).
    snr_db : float, optional
        Noise level of the data, dB (default 30).
    model_based : bool, optional
        False leaves the tv row out.

    Returns
    -------
    ExperimentResult
        Table: one row per method (``method``, ``sensors``, ``cc``, ``amplitude``,
        ``min_branch_contrast``, ``seconds``; tv also ``iterations``, ``operator_pairs``,
        ``converged``, ``lam``); summary: each method's CC; images: MIPs.

    Raises
    ------
    ValueError
        ``data`` given, or ``fraction`` outside (0, 1].
    """
    from fpscan.service.plans import Lattice, equisteradian_mask
    from fpscan.service.recon.dataset import GridDataset, PointDataset

    if data is not None:
        raise ValueError("the vessels experiment runs on its built-in phantom (its oracle); --data is not taken")
    if not 0 < fraction <= 1:
        raise ValueError(f"fraction must be in (0, 1], got {fraction!r}")
    ds = simulate_vessels(small=small, snr_db=snr_db)
    truth = np.asarray(ds.p0)
    n_z, n, _ = truth.shape
    x = centred_axis(n, ds.dx)
    poi_depth = 0.55 * n_z * ds.dx  # the trunk's depth
    mask = equisteradian_mask(Lattice(n, n, ds.dx), poi_depth, round(fraction * n * n))
    ix, iy = np.asarray(mask.indices).T
    sparse = PointDataset(alines=ds.data[:, iy, ix].T, positions=np.asarray(mask.positions, float)[:, :2],
                          weights=np.asarray(mask.weights, float), dt=ds.dt, sound_speed=ds.sound_speed, grid=(x, x))
    inputs: dict[str, GridDataset | PointDataset] = {"ner": ds, "nedner": sparse, "tv": sparse}
    rows, mips = [], {"truth": (truth.max(axis=0), truth.max(axis=1))}
    for method in METHODS if model_based else METHODS[:2]:
        t0 = time.perf_counter()
        rec = reconstruct(inputs[method], method, n_z=n_z, dz=ds.dx, dtype="float32")
        seconds = time.perf_counter() - t0
        img = np.asarray(rec.p0, dtype=np.float64)
        contrasts = branch_contrasts(img, truth)
        row = {"method": method, "sensors": len(iy) if method != "ner" else n * n,
               "cc": correlation_coefficient(img, truth),
               "amplitude": float(np.vdot(img, truth) / np.vdot(truth, truth)),
               "min_branch_contrast": min(c["relative"] for c in contrasts), "seconds": seconds}
        if method == "tv":
            p = rec.params
            row.update(iterations=p["iterations"], operator_pairs=p["operator_pairs"], converged=p["converged"],
                       lam=p["lam"])
        rows.append(row)
        mips[method] = (img.max(axis=0), img.max(axis=1))
    summary = {f"cc_{r['method']}": r["cc"] for r in rows}
    params = {"shape": list(truth.shape), "pitch_m": ds.dx, "dt_s": ds.dt, "sound_speed": ds.sound_speed, "snr_db": snr_db,
              "fraction": fraction, "sensors": int(len(iy)), "lattice_points": n * n, "poi_depth_m": poi_depth,
              "dtype": "float32"}
    return ExperimentResult(NAME, params, rows, summary, images={"mips": mips, "x": x, "z": ds.dx * np.arange(n_z)})


def plot(result: ExperimentResult, out_dir: str | Path) -> list[Path]:
    """Plot ``vessels_mips.png``: depth MIPs (top row, x-y) and lateral MIPs (bottom row, x-z) of
    the true p0 and each method's reconstruction.

    Parameters
    ----------
    result : ExperimentResult
        The result of `run`.
    out_dir : str or pathlib.Path
        An existing folder.

    Returns
    -------
    list of pathlib.Path
        The one PNG file.
    """
    plt = setup_matplotlib()
    mips = result.images["mips"]
    x = result.images["x"] * 1e3
    z = result.images["z"] * 1e3
    rows = {r["method"]: r for r in result.table}
    names = list(mips)
    fig, axs = plt.subplots(2, len(names), figsize=(3.2 * len(names), 5.2), squeeze=False,
                            gridspec_kw={"height_ratios": [x[-1] - x[0], 0.9 * (z[-1] - z[0])]})
    for j, name in enumerate(names):
        xy, xz = mips[name]
        for i, (im, ext) in enumerate(((xy, [x[0], x[-1], x[-1], x[0]]), (xz, [x[0], x[-1], z[-1], z[0]]))):
            axs[i, j].imshow(im, extent=ext, cmap="gray", vmin=0, vmax=max(float(np.percentile(im, 99.9)), 1e-30),
                             aspect="equal")
            axs[i, j].tick_params(labelsize=7)
        title = "true p0" if name == "truth" else (
            f"{name} ({rows[name]['sensors']} A-lines)\nCC {rows[name]['cc']:.3f}, "
            f"amplitude {rows[name]['amplitude']:.2f}")
        axs[0, j].set_title(title, fontsize=8)
        axs[1, j].set_xlabel("x (mm)", fontsize=7)
    axs[0, 0].set_ylabel("y (mm)", fontsize=7)
    axs[1, 0].set_ylabel("z (mm)", fontsize=7)
    p = result.params
    fig.suptitle(f"vessel tree {p['shape'][0]} x {p['shape'][1]} x {p['shape'][2]} voxels of "
                 f"{p['pitch_m'] * 1e6:.0f} µm, {p['snr_db']:g} dB noise; sparse: equi-steradian "
                 f"{p['sensors']} of {p['lattice_points']} points", fontsize=9)
    fig.tight_layout()
    path = Path(out_dir) / f"{NAME}_mips.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]
