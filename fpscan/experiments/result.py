"""The outcome of an experiment and how it is written: a JSON summary + table, a CSV
table, PNG plots (matplotlib, Agg backend)."""
from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Callable
    from types import ModuleType

__all__ = ["ExperimentResult", "setup_matplotlib", "write_experiment"]


def _jsonable(v: Any) -> Any:
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, np.ndarray):
        return _jsonable(v.tolist())
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating, float)):
        f = float(v)
        return f if math.isfinite(f) else None
    if isinstance(v, (np.bool_,)):
        return bool(v)
    return v


@dataclass
class ExperimentResult:
    """What an experiment produced.

    Attributes
    ----------
    name : experiment name (e.g. ``"limited-view-2d"``).
    params : every setting used (JSON-serialisable).
    table : one dict per row (same keys in every row) — written to CSV and JSON.
    summary : the headline numbers, with the paper's for comparison.
    curves : named 1-D arrays for plots and JSON (e.g. CC vs diameter).
    images : named arrays for the figures only (not written to JSON).
    """

    name: str
    params: dict
    table: list[dict]
    summary: dict
    curves: dict = field(default_factory=dict)
    images: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return _jsonable({"experiment": self.name, "params": self.params, "summary": self.summary,
                          "table": self.table, "curves": self.curves})


def setup_matplotlib() -> ModuleType:
    """Import pyplot with the non-interactive Agg backend."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def write_experiment(result: ExperimentResult, out_dir: str | Path,
                     plot: Callable[[ExperimentResult, Path], list[Path]] | None = None) -> list[Path]:
    """Write ``<name>.json``, ``<name>.csv`` and the plots into ``out_dir`` (created).

    Parameters
    ----------
    result : ExperimentResult
        The experiment's result (its ``name`` names the files; its ``table`` rows become the
        CSV's, their keys in order of first appearance the columns).
    out_dir : str or pathlib.Path
        The output folder.
    plot : callable, optional
        ``plot(result, out_dir)`` -> the PNG paths it wrote; None: no plots.

    Returns
    -------
    list of pathlib.Path
        Every path written: the JSON, the CSV, then the plots.

    Raises
    ------
    OSError
        The folder cannot be written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    jpath = out / f"{result.name}.json"
    jpath.write_text(json.dumps(result.to_json(), indent=2, allow_nan=False) + "\n")
    paths.append(jpath)
    cpath = out / f"{result.name}.csv"
    keys: list[str] = []
    for row in result.table:
        for k in row:
            if k not in keys:
                keys.append(k)
    with cpath.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        for row in result.table:
            w.writerow({k: _fmt(row.get(k)) for k in keys})
    paths.append(cpath)
    if plot is not None:
        paths.extend(plot(result, out))
    return paths


def _fmt(v: Any) -> Any:
    v = _jsonable(v)
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.6g}"
    return v
