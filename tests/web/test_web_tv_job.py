"""k-Wave ``.mat`` files and a ``tv`` job in the web page, in a real headless Chromium
against a real ``fpscan serve`` (token configured).

What a lab does in its first week: uploads its k-Wave output (Octave's MAT v5 and MATLAB's
v7.3) from the page and reconstructs it; follows a model-based job on its own page (the
iteration, the stopping rule against its tolerance, the time left) and reads how it ended
in the result's summary, the raw parameters folded away.

Oracles: the same file reconstructed by the library in this process (the volume), the
job's own JSON from the server (the summary's numbers). Screenshots of the running and
the finished tv job go to test-artifacts/screenshots/ (``tv-job-running``, ``tv-job-done``).
"""
from __future__ import annotations

import re

import pytest

from tests.storage.mat_files import write_mat73
from tests.web.test_web_page import el, shot, start_server, submit_token_if_asked, text, wait_job_shown
from tests.web.web_e2e_support import open_page, wait_for

httpx = pytest.importorskip("httpx")
np = pytest.importorskip("numpy")
h5py = pytest.importorskip("h5py")

TOKEN = "web-tv-token-1701"

pytestmark = pytest.mark.timeout(600)  # the suite's: waits end on events (tests.waits)


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    data = tmp_path_factory.mktemp("serve-tv")
    srv = start_server(data, {}, TOKEN)
    try:
        yield srv
    finally:
        srv.stop()


@pytest.fixture(scope="module")
def server(served):
    return served.url


@pytest.fixture(scope="module")
def api(server):
    with httpx.Client(base_url=server, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=60) as c:
        yield c


@pytest.fixture(scope="module")
def mat_files(shared_data, tmp_path_factory):
    """Octave's MAT v5 (``-v7``) of k-Wave's 2-D simulation and the same arrays as MATLAB's v7.3."""
    import scipy.io

    v5 = shared_data / "kwave_mat" / "kwave2d_line_sensor_v7.mat"
    arrays = {k: v for k, v in scipy.io.loadmat(v5).items() if not k.startswith("__")}
    return {"v5": v5, "v73": write_mat73(tmp_path_factory.mktemp("mat") / "sensor_data_v73.mat", arrays)}


def _upload_from_the_page(browser, path, method: str) -> str:
    """Upload ``path`` with the page's form (format k-Wave MAT-file, no spacings typed: the
    file has them) and reconstruct it with ``method``; returns the job the page opens."""
    from selenium.webdriver.support.ui import Select

    el(browser, "nav-jobs").click()
    wait_for(lambda: el(browser, "view-jobs").is_displayed(), "the jobs view")
    if not el(browser, "upload-panel").get_attribute("open"):
        browser.find_element("css selector", "#upload-panel summary").click()
    wait_for(lambda: "kwave-mat" in browser.execute_script(
        "return [...document.getElementById('upload-format').options].map(o => o.value)"), "the kwave-mat choice")
    el(browser, "upload-file").send_keys(str(path))
    Select(el(browser, "upload-format")).select_by_value("kwave-mat")
    Select(el(browser, "upload-method")).select_by_value(method)
    before = el(browser, "result-id").get_attribute("title")
    el(browser, "upload-start").click()
    wait_for(lambda: text(browser, "result-kind") == "recon" and el(browser, "result-id").get_attribute("title") not in
             (before, None, ""), "the upload's job to open")
    return el(browser, "result-id").get_attribute("title")


def test_kwave_mat_uploaded_from_the_page_reconstructs_as_the_library_does(browser, server, api, mat_files, tmp_path):
    """Octave's MAT v5 and the v7.3 of the same arrays, uploaded from the page: detected and
    read as k-Wave's (sensor, time) layout with the file's dt and dx; each NER volume equals
    the library's of the same file."""
    from fpscan.service.pipeline import reconstruct
    from fpscan.service.storage.loader import load_dataset

    open_page(browser, server)
    submit_token_if_asked(browser, TOKEN)
    want = reconstruct(load_dataset(mat_files["v5"]), "ner").p0  # float32, the server's default too
    for name in ("v5", "v73"):
        job_id = _upload_from_the_page(browser, mat_files[name], "ner")
        assert wait_job_shown(browser, job_id, ("succeeded", "failed"), f"the {name} job to end") == "succeeded", \
            api.get(f"/api/jobs/{job_id}").json()
        (tmp_path / f"{name}.h5").write_bytes(api.get(f"/api/reconstructions/{job_id}/volume.h5").content)
        with h5py.File(tmp_path / f"{name}.h5", "r") as f:
            np.testing.assert_array_equal(f["p0"][...], want, err_msg=name)
        job = api.get(f"/api/jobs/{job_id}").json()
        assert job["params"]["result"]["params_used"]["dt"] == pytest.approx(1e-8)


def test_tv_job_page_running_and_done(browser, served, server, api, mat_files, screenshots):
    """A tv job without a stopping rule (tol 0) on its page while it runs: a progress bar, the
    iteration and the stopping rule's value against its tolerance, the time left; cancelled
    from the page. Then tv with its defaults, uploaded from the page: once done, its summary
    leads (method, converged, iterations, λ automatic, residual against the noise, grid,
    time) with the numbers the server's JSON holds, and the raw parameters are folded away."""
    open_page(browser, server)
    submit_token_if_asked(browser, TOKEN)
    with open(mat_files["v73"], "rb") as fh:
        r = api.post("/api/datasets", data={"format": "kwave-mat"}, files={"file": ("k.mat", fh, "application/x-matlab-data")})
    assert r.status_code == 201, r.text
    r = api.post("/api/reconstructions", json={"dataset_id": r.json()["dataset_id"], "method": "tv",
                                               "params": {"tol": 0, "max_iter": 5000}})
    assert r.status_code == 202, r.text
    running = r.json()["id"]
    open_page(browser, f"{server}/#/jobs/{running}")
    eta = re.compile(r"^\d+(\.\d)? s$|^\d+ min \d+ s$|^\d+ h \d+ min $")
    wait_for(lambda: el(browser, "result-progress").is_displayed()
             and text(browser, "result-progress-stage").startswith("iteration")
             and "no early stop" in text(browser, "result-progress-stage")
             and eta.match(text(browser, "result-progress-eta")), "the running tv job's iteration and time left")
    stage = text(browser, "result-progress-stage")
    assert re.match(r"iteration \d+/5000, image change \S+ \(tol 0: no early stop\)$", stage), stage
    assert not el(browser, "result-summary").is_displayed()  # nothing to sum up yet
    assert 0 < float(el(browser, "result-progress-bar").get_attribute("value")) < 1
    shot(browser, screenshots, "tv-job-running")
    el(browser, "result-cancel").click()
    assert wait_job_shown(browser, running, ("cancelled",), "the cancel") == "cancelled"
    assert not el(browser, "result-progress").is_displayed()

    done = _upload_from_the_page(browser, mat_files["v5"], "tv")
    assert wait_job_shown(browser, done, ("succeeded", "failed"), "the tv job to end") == "succeeded"
    used = api.get(f"/api/jobs/{done}").json()["params"]["result"]["params_used"]
    wait_for(lambda: el(browser, "result-summary").is_displayed(), "the result's summary")
    outcome = text(browser, "summary-outcome")
    n = used["iterations"]
    assert outcome.startswith(f"converged after {n} iterations" if used["converged"] else "not converged"), outcome
    assert text(browser, "summary-method").startswith("tv")
    assert text(browser, "summary-lambda").endswith("(automatic)") and used["lam_auto"] is True
    assert "% of the data, noise" in text(browser, "summary-residual")
    assert text(browser, "summary-grid").startswith(" × ".join(map(str, api.get(f"/api/jobs/{done}").json()
                                                                        ["params"]["result"]["shape"])))
    assert text(browser, "summary-time")
    # the same outcome, one line, in the server's log ("log" as a lab reads it)
    line = wait_for(lambda: next((ln for ln in served.log_tail(200_000).splitlines() if f"recon done job={done}" in ln),
                                 None), "the job's line in the server's log")
    assert f"tv: {outcome.split(' (')[0]}" in line, line
    # the raw parameters are there, folded
    assert el(browser, "result-params-box").get_attribute("open") is None
    assert int(text(browser, "result-params-count")) > 20
    assert not el(browser, "result-params").is_displayed()
    wait_for(lambda: browser.execute_script("const i = document.getElementById('result-mip-xz');"
                                            "return i.complete && i.naturalWidth > 0"), "the xz MIP")
    shot(browser, screenshots, "tv-job-done")
