"""`tv` everywhere a user reconstructs: the dispatch (progress names the iteration,
cancel, bad options), the API's request model and the CLI's flags."""
from __future__ import annotations

import argparse

import numpy as np
import pytest

from fpscan.service.pipeline import Cancelled, reconstruct
from fpscan.service.recon.dataset import PointDataset

C, DT = 1500.0, 20e-9
DZ = C * DT


def _points():
    rng = np.random.default_rng(2)
    pos = (np.arange(6)[:, None] - 2.5) * 2 * DZ
    return PointDataset(alines=rng.standard_normal((6, 12)), positions=pos, weights=None, dt=DT, c=C,
                        grid=(pos[:, 0],))


def test_dispatch_runs_tv_with_iteration_progress_and_cancel():
    seen = []
    rec = reconstruct(_points(), "tv", lam=0.01, iterations=3, n_z=6, dtype="float64",
                      progress=lambda f, s: seen.append(s))
    assert rec.params["method"] == "tv" and rec.params["lam"] == 0.01 and rec.params["iterations"] <= 3
    assert rec.params["positivity"] is True and rec.p0.min() >= 0
    assert "iteration 1/3" in seen
    calls = []

    def stop():
        calls.append(1)
        return len(calls) > 4

    with pytest.raises(Cancelled):
        reconstruct(_points(), "tv", iterations=50, n_z=6, should_stop=stop)


@pytest.mark.parametrize(("opts", "match"), [
    (dict(lam=-1.0), "lam"), (dict(lam=float("inf")), "lam"), (dict(iterations=0), "iterations"),
    (dict(nan=True), "NaN"), (dict(weights=np.ones(5)), "weights must have shape"),
])
def test_dispatch_rejects_bad_tv_input(opts, match):
    ds = _points()
    if opts.pop("nan", False):
        ds.alines[2, 3] = np.nan
    if "weights" in opts:
        ds.weights = opts.pop("weights")
    with pytest.raises(ValueError, match=match):
        reconstruct(ds, "tv", n_z=6, **opts)


def test_api_model_and_cli_take_lambda_and_iterations():
    from pydantic import ValidationError

    from fpscan.clients.cli import recon as cli_recon
    from fpscan.service.api.models import ReconRequest

    req = ReconRequest.model_validate({"dataset_id": "x", "method": "tv", "params": {"lam": 0.1, "iterations": 5}})
    assert req.params.lam == 0.1 and req.params.iterations == 5
    for bad in ({"lam": -1}, {"iterations": 0}):
        with pytest.raises(ValidationError):
            ReconRequest.model_validate({"dataset_id": "x", "method": "tv", "params": bad})
    parser = argparse.ArgumentParser()
    cli_recon.add_arguments(parser)
    args = parser.parse_args(["in.npy", "--method", "tv", "--lambda", "0.5", "--iterations", "7", "--no-positivity"])
    params = cli_recon._params(args)
    assert params["lam"] == 0.5 and params["iterations"] == 7 and params["positivity"] is False
