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
    return PointDataset(alines=rng.standard_normal((6, 12)), positions=pos, weights=None, dt=DT, sound_speed=C,
                        grid=(pos[:, 0],))


def test_dispatch_runs_tv_with_iteration_progress_and_cancel():
    seen = []
    rec = reconstruct(_points(), "tv", lam=0.01, max_iter=3, n_z=6, dtype="float64",
                      progress=lambda f, s: seen.append(s))
    assert rec.params["method"] == "tv" and rec.params["lam"] == 0.01 and rec.params["iterations"] <= 3
    assert rec.params["positivity"] is True and rec.p0.min() >= 0
    assert "iteration 1/3" in seen
    calls = []

    def stop():
        calls.append(1)
        return len(calls) > 4

    with pytest.raises(Cancelled):
        reconstruct(_points(), "tv", max_iter=50, n_z=6, should_stop=stop)


@pytest.mark.parametrize(("opts", "match"), [
    (dict(lam=-1.0), "lam"), (dict(lam=float("inf")), "lam"), (dict(max_iter=0), "max_iter"),
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


def test_api_model_and_cli_take_lam_and_max_iter_and_their_old_names():
    from pydantic import TypeAdapter, ValidationError

    from fpscan.clients.cli import recon as cli_recon
    from fpscan.service.api.models import ReconRequest
    from fpscan.service.recon.methods.tv import Options

    request = TypeAdapter(ReconRequest)
    req = request.validate_python({"dataset_id": "x", "method": "tv", "params": {"lam": 0.1, "max_iter": 5}})
    assert isinstance(req.params, Options) and req.params.lam == 0.1 and req.params.max_iter == 5
    with pytest.warns(DeprecationWarning, match="option iterations is deprecated: use max_iter"):
        old = request.validate_python({"dataset_id": "x", "method": "tv", "params": {"iterations": 6}})
    assert old.params.max_iter == 6
    for bad in ({"lam": -1}, {"max_iter": 0}, {"max_iter": 5, "iterations": 5}):
        with pytest.raises(ValidationError):
            request.validate_python({"dataset_id": "x", "method": "tv", "params": bad})
    parser = argparse.ArgumentParser()
    cli_recon.add_arguments(parser)
    for flags in (["--lam", "0.5", "--max-iter", "7"], ["--lambda", "0.5", "--iterations", "7"]):  # the old ones warn
        args = parser.parse_args(["in.npy", "--method", "tv", *flags, "--no-positivity"])
        params = cli_recon._params(args)
        assert params["lam"] == 0.5 and params["max_iter"] == 7 and params["positivity"] is False
