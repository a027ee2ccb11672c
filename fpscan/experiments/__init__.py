"""The paper's experiments (§4, §6, §7), runnable by name and written as JSON + CSV + PNG.

- ``limited-view-2d`` (:mod:`.limited_view`, paper §6)
- ``sparse-masks-3d`` (:mod:`.sparse_masks`, paper §7)
- ``nufft-vs-interpolation`` (:mod:`.nufft_vs_interp`, paper §4)
- ``vessels`` (:mod:`.vessels`: a thin vessel tree from a sparse, noisy 3-D scan;
  NER on every point, NEDNER and tv on an equi-steradian mask)

``run_experiment(name, out_dir, data=path, small=...)`` runs one and writes
``<name>.json``, ``<name>.csv`` and its PNG plots. Built on :mod:`fpscan.service.recon`,
:mod:`fpscan.service.plans` and :mod:`fpscan.service.metrics`.

A package of its own beside the clients, outside the server's runtime package: it imports the
library (``fpscan.service``'s library, ``fpscan.physics``, ``fpscan.constants``), and nothing of
fpscan imports it but the ``fpscan evaluate`` command, inside its ``run`` (the import contracts in
``pyproject.toml``; docs/architecture.md).
"""
from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

from fpscan.experiments.dense import DenseDataset, add_noise, load_dense
from fpscan.experiments.result import ExperimentResult, write_experiment

#: experiment name -> module implementing ``run(data=None, *, small=False, ...)`` and ``plot``.
EXPERIMENTS = {
    "limited-view-2d": "fpscan.experiments.limited_view",
    "sparse-masks-3d": "fpscan.experiments.sparse_masks",
    "nufft-vs-interpolation": "fpscan.experiments.nufft_vs_interp",
    "vessels": "fpscan.experiments.vessels",
}


def run_experiment(name: str, out_dir: str | Path | None = None, *, data: str | Path | DenseDataset | None = None,
                   small: bool = False, **options: Any) -> tuple[ExperimentResult, list[Path]]:
    """Run experiment ``name`` and (if ``out_dir``) write its table and plots.

    Parameters
    ----------
    name : one of :data:`EXPERIMENTS`.
    out_dir : output folder (created); None: write nothing.
    data : an HDF5 file (see :func:`load_dense`) or a :class:`DenseDataset`; default the
        experiment's built-in simulation.
    small : the small, fast version (tests; with ``data``: the first 512 (3-D: 384)
        samples of the central 256 (3-D: 64) lattice points per lateral axis).
    options : passed to the experiment's ``run``.

    Returns
    -------
    (result, written paths).

    Raises
    ------
    ValueError for an unknown experiment or unusable data.
    """
    if name not in EXPERIMENTS:
        raise ValueError(f"unknown experiment {name!r}; choose one of {', '.join(EXPERIMENTS)}")
    module = importlib.import_module(EXPERIMENTS[name])
    if data is not None and not isinstance(data, DenseDataset):
        data = load_dense(data)
    if data is not None and small:
        data = data.crop(n_t=512 if data.ndim == 2 else 384, lateral=256 if data.ndim == 2 else 64)
    result = module.run(data, small=small, **options)
    paths = write_experiment(result, out_dir, module.plot) if out_dir is not None else []
    return result, paths


__all__ = ["EXPERIMENTS", "DenseDataset", "ExperimentResult", "add_noise", "load_dense", "run_experiment",
           "write_experiment"]
