"""Experiment ``nufft-vs-interpolation`` (paper §4): NER-NUFFT vs FFT + interpolation.

A thin absorbing layer of finite width (Gaussian in depth, FWHM 2.5·c·dt, off the
sample grid; lateral ends blurred by 2.5 pitches — the paper's 0.1 µm chrome USAF chart
seen by a band-limited system) on a 2-D grid of 70 µm, dt = 8 ns, is simulated with the
exact forward model and reconstructed with ``ner`` (NUFFT in ω), ``linear`` and
``nearest`` (FFT on the regular ω grid + interpolation) and ``kwave-linear`` (k-Wave's
kspaceLineRecon with '*linear', the paper's FFT comparison). The same measures on the
true p0 are the ``truth`` row. Measured per method:

- axial resolution: FWHM of a Lorentz fit to 8 depth samples around the maximum
  (paper's procedure) over 49 central columns — mean ± std;
- lateral resolution: FWHM of arctan edge-spread fits across both ends of the layer;
- peak amplitude relative to the true (band-limited) p0 on the same grid;
- peak side-lobe level of the depth profile (fraction of the peak);
- run time (best of ``repeats``).

With ``data`` (any 2-D or 3-D dense dataset) the brightest reconstructed point is
analysed instead: axial and lateral Lorentz (line-spread) fits, peak, side lobes, time.
Paper (USAF chart, NER-NUFFT vs FFT linear): axial FWHM 23.23 ± 0.56 µm vs
62.34 ± 0.62 µm; lateral 33.44 ± 7.95 µm vs 40.82 ± 7.34 µm.
"""
from __future__ import annotations

import functools
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fpscan.constants import C_DEFAULT
from fpscan.experiments.dense import DenseDataset
from fpscan.experiments.phantoms import layer_phantom
from fpscan.experiments.result import ExperimentResult, setup_matplotlib
from fpscan.physics.axes import centred_axis
from fpscan.service.metrics import fit_edge_spread, fit_lorentz, side_lobe_level
from fpscan.service.pipeline import reconstruct

__all__ = ["NAME", "METHODS", "PAPER", "simulate_layer", "depth_sweep", "run", "plot"]

NAME = "nufft-vs-interpolation"
METHODS = ("ner", "linear", "nearest", "kwave-linear")
PAPER = {"axial_fwhm_um": {"ner": 23.23, "linear": 62.34}, "axial_fwhm_std_um": {"ner": 0.56, "linear": 0.62},
         "lateral_fwhm_um": {"ner": 33.44, "linear": 40.82}, "lateral_fwhm_std_um": {"ner": 7.95, "linear": 7.34}}


def simulate_layer(*, small: bool, depth: float | None = None) -> DenseDataset:
    """Built-in dataset: a thin layer under a line of sensors, through the forward model.

    256 (small: 128) line points of 70 µm, dt = 8 ns, c = 1500 m/s, 512 (small: 256) samples;
    a layer of FWHM thickness 2.5·c·dt centred 0.37 samples off the grid at ``depth``, half
    the aperture wide, lateral edges blurred by 2.5 pitches.

    Parameters
    ----------
    small : bool
        The small version (tests).
    depth : float, optional
        The layer's depth, m (default 2 mm; small: 1 mm), moved to 0.37 samples off the grid.

    Returns
    -------
    DenseDataset
        ``data`` ``(n_t, n_x)`` (clean), ``p0`` the layer (dz = c·dt), ``meta`` with
        ``layer_depth_m`` and ``layer_width_m``.

    Raises
    ------
    ValueError
        The layer is outside the recorded window.
    """
    from fpscan.service.recon import forward_grid

    n_x, n_t, dx, dt, c = (128, 256, 70e-6, 8e-9, C_DEFAULT) if small else (256, 512, 70e-6, 8e-9, C_DEFAULT)
    dz = c * dt
    if depth is None:
        depth = 1e-3 if small else 2e-3
    depth = (depth // dz + 0.37) * dz
    n_z = int(depth / dz) + 24
    if n_z > n_t:
        raise ValueError(f"layer depth {depth:g} m is beyond the recorded window ({n_t} samples)")
    width = 0.5 * n_x * dx
    p0 = layer_phantom(n_z, n_x, dz, dx, depth=depth, width=width, thickness=2.5 * dz, edge=2.5 * dx)
    data = forward_grid(p0, dx, dz, dt, n_t, c)
    return DenseDataset(data=data, dx=dx, dt=dt, sound_speed=c, p0=p0, dz=dz, source="thin layer (built in)",
                        meta={"layer_depth_m": depth, "layer_width_m": width})


def _timed(fn: Callable[[], np.ndarray], repeats: int) -> tuple[np.ndarray, float]:
    t0 = time.perf_counter()
    out = fn()
    best = time.perf_counter() - t0
    for _ in range(1, repeats):  # the best of max(1, repeats) calls
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return out, best


def _reconstruct(method: str, data: DenseDataset, n_z: int) -> np.ndarray:
    """p0 rows ``0..n_z-1`` (spacing c·dt) of a float64 reconstruction on k-Wave's grid, n_t rows of
    c·dt (:func:`fpscan.service.pipeline.reconstruct`): the pipeline's ``method`` or, for
    ``"kwave-<interp>"``, its ``kwave`` method (k-Wave's kspaceLineRecon /
    kspacePlaneRecon) with that interpolation (``'*linear'`` for ``kwave-linear``)."""
    if method.startswith("kwave-"):
        interp = {"linear": "*linear", "nearest": "*nearest"}.get(method[6:], method[6:])
        return reconstruct(data, "kwave", interp=interp, dtype="float64").p0[:n_z]
    # every method on k-Wave's output grid, n_t rows of c·dt, then the rows analysed: asking
    # the FFT + interpolation methods for fewer rows (n_z < n_t) puts their k_z grid off the
    # ω grid and worsens their gain error.
    return reconstruct(data, method, dz=data.sound_speed * data.dt, n_z=data.n_t, dtype="float64").p0[:n_z]


def _axial_lateral(p: np.ndarray, z: np.ndarray, x: np.ndarray, cols: np.ndarray, zs: slice, kz: int, width: float,
                   dx: float) -> tuple[list[float], list[float], list[float], list[float], np.ndarray]:
    fw, sl, pk = [], [], []
    for j in cols:
        prof = p[zs, j]
        fw.append(fit_lorentz(z[zs], prof, window=8).fwhm)
        sl.append(side_lobe_level(prof))
        pk.append(prof.max())
    lat = p[kz - 2: kz + 3].max(axis=0)
    edges = []
    for e in (-width / 2, width / 2):
        sel = np.abs(x - e) <= 8 * dx
        edges.append(fit_edge_spread(x[sel], lat[sel]).fwhm)
    return fw, sl, pk, edges, lat


def depth_sweep(*, small: bool, methods: Sequence[str] = METHODS,
                fractions: Sequence[float] = (0.15, 0.35, 0.55, 0.75, 0.9)) -> dict:
    """Peak amplitude and axial FWHM of the built-in layer against its depth, per method.

    The layer is placed at ``fractions`` of the recorded depth window n_t·c·dt (the
    interpolation methods' gain error grows with depth; docs/results.md, §4).

    Parameters
    ----------
    small : bool
        The small version (tests).
    methods : sequence of str, optional
        The methods compared (default :data:`METHODS`).
    fractions : sequence of float, optional
        The layer depths as fractions of the recorded window.

    Returns
    -------
    dict
        ``{"depth_m": [...], "peak[<m>]": [...], "axial_fwhm_um[<m>]": [...]}``: per depth, the
        layer's depth in m and, per method ``m``, its peak relative to the true layer and its
        axial FWHM in µm.
    """
    n_t = 256 if small else 512
    dz = C_DEFAULT * 8e-9
    out: dict = {"depth_m": []}
    for f in fractions:
        ds = simulate_layer(small=small, depth=f * n_t * dz)
        res = run(ds, small=small, methods=methods, repeats=1, n_columns=9, _layer=True)
        out["depth_m"].append(ds.meta["layer_depth_m"])
        for r in res.table:
            out.setdefault(f"peak[{r['method']}]", []).append(r["peak"])
            out.setdefault(f"axial_fwhm_um[{r['method']}]", []).append(r["axial_fwhm_um"])
    return out


def run(data: DenseDataset | None = None, *, small: bool = False, methods: Sequence[str] = METHODS, repeats: int | None = None,
        n_columns: int = 49, sweep: bool = True, _layer: bool = False) -> ExperimentResult:
    """Run the §4 comparison.

    Parameters
    ----------
    data : a dense 2-D or 3-D dataset; default the built-in thin layer.
    small : smaller built-in phantom (tests).
    methods : ``reconstruct_grid`` methods and/or ``"kwave-linear"``/``"kwave-nearest"``
        (k-Wave's own FFT reconstruction, the paper's comparison).
    repeats : timing repetitions (best of); default 1 (small) or 3.
    n_columns : central columns used for the axial fits (paper: 49).
    sweep : also run :func:`depth_sweep` (built-in layer only) into ``curves``.

    Returns
    -------
    ExperimentResult; one table row per method (plus ``truth``, the same measures on the
    true p0, for the built-in layer): ``method``, ``axial_fwhm_um``,
    ``axial_fwhm_std_um``, ``lateral_fwhm_um``, ``lateral_fwhm_std_um``, ``peak``
    (relative to the true p0; absolute for ``data`` without p0), ``side_lobe``,
    ``time_s``.

    Raises
    ------
    ValueError for an unknown method (from the reconstruction) or an unusable dataset.
    """
    if repeats is None:
        repeats = 1 if small else 3
    built_in = data is None or _layer
    if data is None:
        data = simulate_layer(small=small)
    g = data.data
    dx, dt, c = data.dx, data.dt, data.sound_speed
    dz = c * dt
    n_z = data.depth_rows(8)
    recons, times = {}, {}
    for m in methods:
        recons[m], times[m] = _timed(functools.partial(_reconstruct, m, data, n_z), repeats)
    z = np.arange(n_z) * dz
    x = centred_axis(g.shape[-1], dx)
    rows: list[dict[str, Any]] = []
    profiles: dict[str, Any] = {}
    if built_in and data.p0 is not None:  # the built-in phantom has its ground truth
        truth = data.p0[:n_z]
        depth = data.meta["layer_depth_m"]
        width = data.meta["layer_width_m"]
        kz = round(depth / dz)
        j0 = g.shape[1] // 2 - n_columns // 2
        cols = np.arange(j0, j0 + n_columns)
        zs = slice(max(0, kz - 20), kz + 21)
        fw, sl, pk, edges, lat = _axial_lateral(truth, z, x, cols, zs, kz, width, dx)
        true_peak = float(np.mean(pk))
        profiles["truth"] = {"axial": truth[zs, g.shape[1] // 2], "lateral": lat}
        for m, p in [("truth", truth)] + [(m, recons[m]) for m in methods]:
            fw, sl, pk, edges, lat = _axial_lateral(p, z, x, cols, zs, kz, width, dx)
            rows.append({"method": m, "axial_fwhm_um": 1e6 * np.mean(fw), "axial_fwhm_std_um": 1e6 * np.std(fw),
                         "lateral_fwhm_um": 1e6 * np.mean(edges), "lateral_fwhm_std_um": 1e6 * np.std(edges),
                         "peak": float(np.mean(pk)) / true_peak, "side_lobe": float(np.mean(sl)),
                         "time_s": times.get(m, np.nan)})
            profiles[m] = {"axial": p[zs, g.shape[1] // 2], "lateral": lat}
        profiles["z"] = z[zs]
        profiles["x"] = x
        target = {"layer_depth_m": depth, "layer_width_m": width}
    else:
        ref = recons["ner"] if "ner" in recons else recons[methods[0]]
        k = np.unravel_index(int(np.argmax(ref)), ref.shape)
        kz = k[0]
        zs = slice(max(0, kz - 20), min(ref.shape[0], kz + 21))
        xs = slice(max(0, k[-1] - 12), min(ref.shape[-1], k[-1] + 13))
        for m in methods:
            p = recons[m]
            col = p[(zs,) + k[1:]]
            row = p[(kz,) + k[1:-1] + (xs,)]
            rec = {"method": m, "axial_fwhm_um": np.nan, "axial_fwhm_std_um": 0.0, "lateral_fwhm_um": np.nan,
                   "lateral_fwhm_std_um": 0.0, "peak": float(col.max()), "side_lobe": np.nan, "time_s": times[m]}
            try:
                rec["axial_fwhm_um"] = 1e6 * fit_lorentz(z[zs], col, window=8).fwhm
                rec["side_lobe"] = side_lobe_level(col)
                rec["lateral_fwhm_um"] = 1e6 * fit_lorentz(x[xs], row, window=8).fwhm
            except ValueError:
                pass
            rows.append(rec)
            profiles[m] = {"axial": col, "lateral": p[(kz,) + k[1:-1] + (slice(None),)]}
        profiles["z"] = z[zs]
        profiles["x"] = x
        target = {"brightest_point_index": [int(v) for v in k], "depth_m": float(z[kz])}
    by = {r["method"]: r for r in rows}
    summary = {"target": target, "paper": PAPER}
    for m in methods:
        summary[f"axial_fwhm_um[{m}]"] = by[m]["axial_fwhm_um"]
        summary[f"lateral_fwhm_um[{m}]"] = by[m]["lateral_fwhm_um"]
        summary[f"peak[{m}]"] = by[m]["peak"]
        summary[f"time_s[{m}]"] = by[m]["time_s"]
    for other in ("linear", "kwave-linear"):
        if "ner" in by and other in by:
            summary[f"axial_improvement_pct[{other} vs ner]"] = 100 * (by[other]["axial_fwhm_um"] / by["ner"]["axial_fwhm_um"] - 1)
            summary[f"lateral_improvement_pct[{other} vs ner]"] = 100 * (by[other]["lateral_fwhm_um"] / by["ner"]["lateral_fwhm_um"] - 1)
            summary[f"time_ratio[{other} / ner]"] = by[other]["time_s"] / by["ner"]["time_s"]
    params = {"source": data.source, "shape": list(g.shape), "dx_m": dx, "dt_s": dt, "sound_speed": c,
              "n_z": n_z, "dz_m": dz, "methods": list(methods), "repeats": repeats, "n_columns": n_columns,
              "lorentz_window": 8, "small": small}
    curves = depth_sweep(small=small, methods=methods) if (sweep and built_in and not _layer) else {}
    return ExperimentResult(NAME, params, rows, summary, curves=curves,
                            images={"profiles": profiles, "built_in": built_in})


def plot(result: ExperimentResult, out_dir: str | Path) -> list[Path]:
    """Plot the §4 comparison: ``nufft-vs-interpolation_profiles.png``.

    Axial and lateral profiles per method (with the true p0 for the built-in layer), run
    times, and (built-in layer) peak and axial FWHM vs depth.

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
    prof = result.images["profiles"]
    methods = result.params["methods"]
    sweep = result.curves.get("depth_m")
    fig, ax = plt.subplots(1, 5 if sweep else 3, figsize=(25 if sweep else 15, 4))
    z = prof["z"] * 1e6
    for m in methods:
        r = next(r for r in result.table if r["method"] == m)
        if m not in prof:
            continue
        ax[0].plot(z, prof[m]["axial"], ".-", label=f"{m}: FWHM {r['axial_fwhm_um']:.1f} µm")
        ax[1].plot(prof["x"] * 1e3, prof[m]["lateral"], "-", label=f"{m}: {r['lateral_fwhm_um']:.1f} µm")
    if "truth" in prof:
        ax[0].plot(z, prof["truth"]["axial"], "k:", label="true p0")
        ax[1].plot(prof["x"] * 1e3, prof["truth"]["lateral"], "k:", label="true p0")
    ax[0].set(xlabel="depth (µm)", ylabel="p0", title="axial line-spread profile (centre column)")
    ax[1].set(xlabel="x (mm)", ylabel="max over layer rows", title="lateral profile / edges")
    times = [next(r for r in result.table if r["method"] == m)["time_s"] for m in methods]
    ax[2].bar(methods, times)
    ax[2].set(ylabel="run time (s)", title=f"reconstruction time (best of {result.params['repeats']})")
    if sweep:
        dmm = np.asarray(sweep) * 1e3
        for m in methods:
            ax[3].plot(dmm, result.curves[f"peak[{m}]"], "o-", label=m)
        ax[3].set(xlabel="layer depth (mm)", ylabel="peak / true peak", title="amplitude vs depth")
        for m in ["truth", *methods]:
            key = f"axial_fwhm_um[{m}]"
            if key in result.curves:
                ax[4].plot(dmm, result.curves[key], "k:" if m == "truth" else "o-", label=m)
        ax[4].set(xlabel="layer depth (mm)", ylabel="axial FWHM (µm)", title="axial line spread vs depth")
    for a in list(ax[:2]) + (list(ax[3:]) if sweep else []):
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    fig.tight_layout()
    p = Path(out_dir) / f"{NAME}_profiles.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return [p]
