"""`fpscan evaluate`: run the paper's experiments and write plots (PNG) and tables
(JSON + CSV).

Experiments (``fpscan.experiments``, loaded only inside :func:`run`: this module's is the one
import of the experiments the import contracts allow): ``limited-view-2d`` (paper §6),
``sparse-masks-3d`` (§7), ``nufft-vs-interpolation`` (§4), ``vessels`` (a thin vessel
tree from a sparse, noisy 3-D scan: NER, NEDNER, tv; built-in phantom only), or ``all``. ``--data`` gives
a dense dataset (HDF5 with ``sensor_data/clean``, e.g. the k-Wave reference files, or an
fpscan scan file covering its whole lattice) instead of the built-in simulation;
``--small`` runs the fast, reduced version.

    fpscan evaluate all --out docs/results        # what docs/results.md shows
    fpscan evaluate limited-view-2d --data $FPSCAN_SHARED/data/kwave2d_points.h5 --small
"""
from __future__ import annotations

import argparse
import math

from fpscan.clients.cli.common import UsageError

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (`fpscan --help` starts faster)
if TYPE_CHECKING:
    from fpscan.experiments import ExperimentResult

__all__ = ["COMMAND", "HELP", "NAMES", "add_arguments", "run"]

COMMAND = "evaluate"
HELP = ("run the paper's experiments (limited-view-2d, sparse-masks-3d, nufft-vs-interpolation) and vessels "
        "-> PNG plots, JSON/CSV tables")

NAMES = ("limited-view-2d", "sparse-masks-3d", "nufft-vs-interpolation", "vessels")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare this sub-command's options on ``parser`` (an ``argparse`` sub-parser).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser, changed in place.
    """
    parser.add_argument("experiment", choices=NAMES + ("all",), help="which experiment (or all)")
    parser.add_argument("--data", default=None, metavar="FILE",
                        help="dense dataset instead of the built-in phantom: HDF5 with sensor_data/clean and dt_s/dx_m "
                             "attributes (e.g. the k-Wave files), or an fpscan scan file covering its whole lattice")
    parser.add_argument("--dataset", default=None, metavar="KEY",
                        help="HDF5 dataset inside --data holding the sensor data (e.g. sensor_data/noisy30dB; "
                             "default sensor_data/clean)")
    parser.add_argument("--out", default="evaluate-output", metavar="DIR",
                        help="output folder (default: evaluate-output)")
    parser.add_argument("--small", action="store_true", help="small, fast version (a few seconds each)")
    parser.add_argument("--no-model-based", dest="model_based", action="store_false",
                        help="leave out the model-based (tv) rows of limited-view-2d and sparse-masks-3d "
                             "(iterative: minutes in 2-D, far longer for the full-size 3-D case on a small machine)")
    from fpscan.clients.cli.common import default_dtype

    parser.epilog = ("Precision: every reconstruction of the experiments is float64 (they measure resolution "
                     f"and errors); fpscan recon and the server default to {default_dtype()} (--dtype).")


def _headline(result: ExperimentResult) -> str:
    s = result.summary
    name = result.name
    if name == "limited-view-2d":
        return (f"CC in ROI: equiangular {s['cc_equiangular']:.3f}, best equispaced {s['cc_best_equispaced']:.3f} "
                f"(interval {s['best_interval']}), interpolated {s['cc_interpolated']:.3f} "
                f"[paper 0.913 / 0.849 / 0.7348]"
                + (f"; equiangular tv {s['cc_equiangular_tv']:.3f}" if math.isfinite(s.get("cc_equiangular_tv", math.nan))
                   else ""))
    if name == "sparse-masks-3d":
        parts = [f"equi-steradian {s['cc_equisteradian']:.3f}"]
        if math.isfinite(s.get("cc_equisteradian_tv", math.nan)):  # the tv row was run
            parts.append(f"equi-steradian tv {s['cc_equisteradian_tv']:.3f}")
        parts += [f"{k[3:].replace('_', ' ')} {v:.3f}" for k, v in s.items() if k.startswith("cc_interval_")]
        return (f"CC of xy-MIP at {s['eval_diameter_m'] * 1e3:.2f} mm: " + ", ".join(parts)
                + " [paper at 7.2 mm: 0.960 vs 0.947 (interval 4) / 0.944 (interval 5)]")
    rows = {r["method"]: r for r in result.table}
    if name == "vessels":
        return "CC with p0: " + ", ".join(
            f"{m} {r['cc']:.3f} ({r['sensors']} A-lines, weakest branch {r['min_branch_contrast']:.2f} of its contrast)"
            for m, r in rows.items())
    return "axial FWHM: " + ", ".join(f"{m} {r['axial_fwhm_um']:.1f} µm" for m, r in rows.items()) + \
        " [paper: NUFFT 23 µm vs FFT 62 µm]"


def run(args: argparse.Namespace) -> int:
    """Run this sub-command with the parsed ``args``; return the exit status.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line (:func:`add_arguments`).

    Returns
    -------
    int
        The exit status: 0 on success (refused input and failures raise: :func:`fpscan.clients.cli.main`
        reports them and sets the status).
    """
    from pathlib import Path

    from fpscan.experiments import run_experiment

    if args.dataset is not None and args.data is None:
        raise UsageError("--dataset names a dataset inside --data FILE; give --data")
    names = NAMES if args.experiment == "all" else (args.experiment,)
    data = None
    if args.data is not None:
        from fpscan.experiments import load_dense

        data = load_dense(args.data, key=args.dataset)  # ValueError with the reason for a missing or unusable file
    out = Path(args.out)
    for name in names:
        ndim = None if data is None else data.ndim
        wrong_dim = ndim is not None and (
            (name == "limited-view-2d" and ndim != 2) or (name == "sparse-masks-3d" and ndim != 3)
            or name == "vessels")  # vessels: its built-in phantom only (the oracle)
        if wrong_dim and args.experiment == "all":
            print(f"{name}: skipped " + ("(built-in phantom only)" if name == "vessels" else f"({ndim}-D data)"))
            continue
        opts = {"model_based": args.model_based} if name in ("limited-view-2d", "sparse-masks-3d", "vessels") else {}
        result, paths = run_experiment(name, out, data=data, small=args.small, **opts)
        print(f"{name}: {_headline(result)}")
        for p in paths:
            print(f"  wrote {p}")
    return 0
