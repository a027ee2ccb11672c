"""Work is admitted, not only memory, and options that do not apply are refused
at the door.

- Every method estimates its work (``Method.estimate_work``: seconds on the reference 2
  cores, from its grid); a request over the server's ``work_limit_s`` is refused with 422
  saying the estimate and the limit; tv's image may not be deeper than the record can hear
  (``dz = 0.1`` and ``n_z = 65536`` once took 23 minutes and 26 s an iteration).
- ``kwave`` with ``sound_speed: "auto"`` is refused at the door with the words the worker
  (the library's ``reconstruct``) uses, not accepted and failed later.

A real ``fpscan serve`` for the HTTP part; the estimates' agreement with measured run times
is ``benchmarks/bench_work_estimate.py`` (docs/performance.md).
"""
from __future__ import annotations

import io

import numpy as np
import pytest

from fpscan.service.jobs.admission import AdmissionError, admit_work, estimate_work, input_shape
from fpscan.service.pipeline import reconstruct
from fpscan.service.recon.checks import OptionError
from fpscan.service.recon.dataset import GridDataset
from tests.service.service_servers import Server

N_T, N, DT, DX = 64, 12, 2e-8, 1e-4


def test_every_method_estimates_its_work_and_tv_follows_its_grid():
    from fpscan.service.recon.methods import METHODS
    from fpscan.service.recon.methods.tv import grid as tv_grid_of

    shape = {"n_t": 512, "n_x": 128, "n_y": 128, "dt": 8e-9, "sound_speed": 1500.0, "dx": 6e-5, "t0": 0.0,
             "n_points": 1653}
    seconds = {name: estimate_work(shape, {"method": name}) for name in METHODS}
    assert all(0 < s < 3600 for s in seconds.values()), seconds
    assert seconds["tv"] > 20 * seconds["nedner"], seconds  # iterations of operator pairs against one inversion
    # tv's work follows the grid its warm start makes of the options: the default grid (isotropic at
    # the band the 60 µm pitch resolves, `fpscan.service.recon.methods.tv.grid`) asked for explicitly is the
    # same work; the same depth in half the rows is less
    dz, n_z = tv_grid_of(512, 8e-9, 1500.0, dx=6e-5, n_x=128, n_y=128)
    assert (dz, n_z) == (6e-5, 103)
    assert estimate_work(shape, {"method": "tv", "dz": dz, "n_z": n_z}) == seconds["tv"]
    assert estimate_work(shape, {"method": "tv", "dz": 2 * dz, "n_z": n_z // 2 + 1}) < seconds["tv"]
    longer = estimate_work(shape, {"method": "ner", "n_z": 2048})
    assert longer > 2 * seconds["ner"]


@pytest.mark.parametrize("options", [{"dz": 0.1}, {"n_z": 65536}])
def test_tv_refuses_an_image_deeper_than_the_record(options):
    shape = {"n_t": 256, "n_x": 16, "n_y": 16, "dt": 4e-8, "sound_speed": 1500.0, "dx": 1e-4, "t0": 0.0, "n_points": 256}
    with pytest.raises(OptionError, match="deeper than the record can hear"):
        estimate_work(shape, {"method": "tv", **options})


def test_the_work_refusal_says_the_estimate_and_the_limit():
    with pytest.raises(AdmissionError) as info:
        admit_work(2 * 86400.0, 8 * 3600.0)
    text = str(info.value)
    assert "2 days of work" in text and "work limit of 8 h" in text and "28800 s" in text, text


def test_kwave_refuses_a_record_not_starting_at_zero_in_the_worker_s_words():
    from fpscan.service.recon.methods.kwave import check_start

    ds = GridDataset(np.zeros((32, 4, 4)), dx=DX, dt=DT, sound_speed=1500.0, dy=DX, t0=1e-6)
    with pytest.raises(ValueError) as worker:
        reconstruct(ds, "kwave")
    with pytest.raises(ValueError) as door:
        estimate_work(input_shape(ds), {"method": "kwave"})
    assert str(door.value) == str(worker.value)
    check_start(0.0)


def _npy() -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(5).standard_normal((N_T, N, N)).astype(np.float32))
    return buf.getvalue()


@pytest.fixture(scope="module")
def work_server(tmp_path_factory):
    # tv's own wall-time cap raised to a week: then only the work limit (a minute here, for this
    # small dataset) bounds it
    srv = Server(tmp_path_factory.mktemp("work") / "data",
                 env={"FPSCAN_WORK_LIMIT_S": "60", "FPSCAN_TV_TIME_LIMIT_S": str(7 * 86400)}).start()
    yield srv
    srv.stop()


@pytest.mark.timeout(300)
def test_over_limit_work_and_unfit_options_are_refused_at_the_door(work_server):
    with work_server.client() as c:
        r = c.post("/api/datasets", data={"format": "npy", "dt": str(DT), "dx": str(DX)},
                   files={"file": ("d.npy", _npy())})
        assert r.status_code == 201, r.text
        ds = r.json()["dataset_id"]

        def ask(method: str, params: dict):
            return c.post("/api/reconstructions", json={"dataset_id": ds, "method": method, "params": params})

        r = ask("tv", {"max_iter": 100000, "time_limit": 7 * 86400, "tol": 0})
        assert r.status_code == 422, r.text
        detail = r.json()["detail"]
        assert "of work by its estimate" in detail and "work limit of 60 s" in detail, detail
        print(f"work: tv of 100000 iterations on {N_T} x {N}^2: 422 {detail!r}")
        for options in ({"dz": 0.1}, {"n_z": 65536}):
            r = ask("tv", options)
            assert r.status_code == 422 and "deeper than the record can hear" in r.json()["detail"], r.text
            print(f"work: tv {options}: 422 {r.json()['detail']!r}")
        r = ask("ner", {})
        assert r.status_code == 202, r.text
        assert 0 < r.json()["params"]["work_estimate_s"] < 1, r.json()["params"]
        # kwave cannot search the speed of sound: refused now, in the worker's own words
        r = ask("kwave", {"sound_speed": "auto"})
        assert r.status_code == 422, r.text
        with pytest.raises(ValueError) as worker:
            reconstruct(GridDataset(np.zeros((N_T, N, N)), dx=DX, dt=DT, sound_speed=1500.0, dy=DX), "kwave", sound_speed="auto")
        assert r.json()["detail"] == str(worker.value), (r.json(), str(worker.value))
