"""An uploaded ``.npy`` array's axes, on a real server: k-Wave's time-last orders undeclared are
refused with 422 naming the readings they could have and the field that says which; with the
form field ``axes`` they are stored time first; ``GET /api/formats`` lists ``axes`` as npy's own."""
from __future__ import annotations

import io

import numpy as np
import pytest

N_Y, N_X, N_T = 6, 8, 40


def _npy(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


def _upload(api, a: np.ndarray, **form):
    return api.post("/api/datasets", data={"format": "npy", "dt": "8ns", "dx": "60um", **form},
                    files={"file": ("kw.npy", _npy(a), "application/octet-stream")})


TYX = np.random.default_rng(11).standard_normal((N_T, N_Y, N_X)).astype(np.float32)


@pytest.mark.parametrize("a, axes, shape, words", [
    (TYX.transpose(1, 2, 0), "y,x,t", [N_T, N_Y, N_X], ("(y, x, t)", "(t, y, x)", "axes")),
    (TYX[:, 0, :].T.copy(), "sensor,time", [N_T, N_X], ("(x, t)", "(t, x)", "sensor, time", "axes"))])
def test_time_last_upload_is_refused_undeclared_and_stored_time_first_declared(shared_api, a, axes, shape, words):
    r = _upload(shared_api, a)
    assert r.status_code == 422, r.text
    for w in words:
        assert w in r.json()["detail"], (w, r.text)
    r = _upload(shared_api, a, axes=axes)
    assert r.status_code == 201, r.text
    assert r.json()["shape"] == shape


def test_axes_that_do_not_fit_or_formats_that_know_their_layout_are_refused(shared_api):
    r = _upload(shared_api, TYX[:, 0, :].T.copy(), axes="y,x,t")
    assert r.status_code == 422 and "names 3 axes" in r.json()["detail"], r.text
    r = _upload(shared_api, TYX, axes="t,q")
    assert r.status_code == 422 and "axes must name" in r.json()["detail"], r.text
    formats = {f["name"]: {o["name"] for o in f["options"]} for f in shared_api.get("/api/formats").json()}
    assert "axes" in formats["npy"] and "axes" not in formats["kwave-hdf5"]
