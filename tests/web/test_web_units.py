"""One unit style in every form of the web page, in a real headless Chromium against a real
``fpscan serve`` with a simulated scanner (``fpscan sim`` on a pty): each length, time,
frequency and speed field shows its unit after it, reads a bare number in that unit and any
other unit written out ("60 µm", "0.06 mm", "60um", "0.02 µs", "1.5 km/s"), and the server
reads the text with the one parser of every door (``fpscan.driver.units.parse_quantity``).

Oracles: the server's own answers over httpx (the plan id the same request in SI numbers
gets, a job's stored parameters, a dataset's spacings) and the parser's own refusal words.
"""
from __future__ import annotations

import pytest

from fpscan.clients.processes import simulator
from tests.web.test_web_page import choose, el, set_value, shot, start_server, text
from tests.web.web_e2e_support import has_subcommand, open_page, preview_settled, wait_for

httpx = pytest.importorskip("httpx")

pytestmark = [pytest.mark.timeout(600), pytest.mark.long(60)]

#: the plan of the plan-form test, in SI numbers (the oracle's request)
LATTICE = {"n_x": 40, "n_y": 40, "pitch": 1.5e-4}
PARAMS = {"depth": 3.6e-3, "n_points": 120}
ACQUISITION = {"n_t": 256, "dt": 2e-8, "averages": 1, "wavelengths": [7.5e-7], "prf": 25.0, "sound_speed": 1500.0}


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """``fpscan serve`` (no token) with ``fpscan sim`` as scanner ``sim1`` (firing at the plan's PRF)."""
    if not has_subcommand("sim"):
        pytest.skip("this build has no `fpscan sim` (simulated scanner)")
    folder = tmp_path_factory.mktemp("units")
    with simulator("--seed", "1", log_path=folder / "sim.log") as (device, _proc):
        srv = start_server(folder, {"sim1": device}, None)
        try:
            yield srv.url
        finally:
            srv.stop()


@pytest.fixture(scope="module")
def api(base):
    with httpx.Client(base_url=base, timeout=30) as c:
        yield c


def unit_of(browser, field_id: str) -> str:
    """The unit the page shows after a field."""
    return browser.execute_script(
        "const u = document.getElementById(arguments[0]).parentElement.querySelector('.unit');"
        "return u ? u.textContent : null", field_id)


def test_plan_form_reads_units_and_saves_the_plan_si_numbers_give(browser, base, api, screenshots):
    """Every quantity of the plan form typed in another unit than the one it shows: the page
    previews and saves the plan the same request in SI numbers gets (its id: the same numbers
    to the last bit, as ``fpscan plan --pitch 0.15mm`` gives). A unit of another dimension
    and an implausible value are refused with the parser's and the plausibility rule's words."""
    open_page(browser, base + "/#/plan")
    wait_for(lambda: preview_settled(browser), "the first preview")
    choose(browser, "mask-kind", "equisteradian")
    wait_for(lambda: el(browser, "mask-depth").is_displayed(), "the equi-steradian parameters")
    shows = {f: unit_of(browser, f) for f in ("lat-pitch", "acq-dt", "acq-prf", "acq-wl", "acq-c", "mask-depth")}
    assert shows == {"lat-pitch": "µm", "acq-dt": "ns", "acq-prf": "Hz", "acq-wl": "nm", "acq-c": "m/s",
                     "mask-depth": "mm"}, shows
    set_value(browser, "lat-nx", LATTICE["n_x"])
    set_value(browser, "lat-ny", LATTICE["n_y"])
    set_value(browser, "lat-pitch", "0.15 mm")
    set_value(browser, "mask-depth", "3600 µm")
    set_value(browser, "mask-n-points", PARAMS["n_points"])
    set_value(browser, "acq-nt", ACQUISITION["n_t"])
    set_value(browser, "acq-dt", "0.02 µs")
    set_value(browser, "acq-prf", "25Hz")
    set_value(browser, "acq-wl", "0.75 µm")
    set_value(browser, "acq-c", "1.5 km/s")
    oracle = api.post("/api/plans", json={"kind": "equisteradian", "lattice": LATTICE, "params": PARAMS,
                                          "acquisition": ACQUISITION})
    assert oracle.status_code in (200, 201), oracle.text
    want = oracle.json()
    wait_for(lambda: preview_settled(browser) and text(browser, "plan-points").split()[0] == str(want["n_points"]),
             f"the preview of {want['n_points']} points")
    shot(browser, screenshots, "units-plan-form")
    el(browser, "plan-save").click()
    plan_id = wait_for(lambda: el(browser, "plan-saved").get_attribute("data-plan-id"), "the saved plan id")
    assert plan_id == want["id"], (api.get(f"/api/plans/{plan_id}/plan.json").json(), want)

    # a unit of another dimension: the parser's words, naming the field
    set_value(browser, "lat-pitch", "60 kg")
    wait_for(lambda: "'60 kg' is not a length" in text(browser, "plan-preview-state"), "the refusal of 60 kg")
    assert "pitch" in text(browser, "plan-preview-state"), text(browser, "plan-preview-state")
    # a unit mistake: the plausibility rule's words in the field's unit, with the command line's suggestion
    set_value(browser, "lat-pitch", "60 mm")
    wait_for(lambda: text(browser, "plan-preview-state").startswith("No preview: pitch in µm: 60000 µm is implausible"),
             "the refusal of a 60 mm pitch")
    shown = text(browser, "plan-preview-state")
    assert "did you mean 60 µm (60um)?" in shown and "Numbers without a unit" not in shown, shown
    shot(browser, screenshots, "units-plan-form-refused")
    set_value(browser, "lat-pitch", "150")  # a bare number: the unit shown, µm
    wait_for(lambda: preview_settled(browser) and text(browser, "plan-points").split()[0] == str(want["n_points"]),
             "the preview of a bare 150 (µm)")


def _scan(api) -> str:
    """A finished scan of a small full lattice on the simulated scanner (over the API)."""
    plan = api.post("/api/plans", json={"kind": "full", "lattice": {"n_x": 8, "n_y": 8, "pitch": 1.5e-4},
                                        "acquisition": {"n_t": 128, "dt": 2e-8, "prf": 200.0}})
    assert plan.status_code in (200, 201), plan.text
    r = api.post("/api/scans", json={"plan_id": plan.json()["id"], "scanner_id": "sim1"})
    assert r.status_code == 202, r.text
    scan_id = r.json()["id"]
    wait_for(lambda: api.get(f"/api/jobs/{scan_id}").json()["state"] in ("succeeded", "failed", "cancelled"),
             "the scan to end", 0.3)
    assert api.get(f"/api/jobs/{scan_id}").json()["state"] == "succeeded"
    return scan_id


def test_reconstruction_form_takes_dz_in_micrometres(browser, base, api, screenshots):
    """The reconstruct form's ``dz`` shows µm (its options model's display unit), not m: "60 µm",
    "0.06 mm" and a bare 60 each give the job dz = 6e-5 m; a unit of another dimension is
    refused with the parser's words and no job is made."""
    scan_id = _scan(api)
    for typed in ("60 µm", "0.06 mm", "60"):
        open_page(browser, f"{base}/#/jobs/{scan_id}")
        wait_for(lambda: el(browser, "result-id").get_attribute("title") == scan_id
                 and el(browser, "result-scan").is_displayed(), "the scan's reconstruct form")
        choose(browser, "recon-method", "nedner")
        wait_for(lambda: el(browser, "recon-dz").is_displayed(), "the dz field")
        assert unit_of(browser, "recon-dz") == "µm"
        assert "(m)" not in text(browser, "recon-dz-label"), text(browser, "recon-dz-label")
        set_value(browser, "recon-dz", typed)
        el(browser, "recon-start").click()
        wait_for(lambda: text(browser, "result-kind") == "recon"
                 and el(browser, "result-id").get_attribute("title") != scan_id, f"the job of dz {typed!r}")
        job_id = el(browser, "result-id").get_attribute("title")
        job = api.get(f"/api/jobs/{job_id}").json()
        assert job["params"]["method"] == "nedner" and job["params"]["params"]["dz"] == 6e-5, (typed, job["params"])
        api.post(f"/api/jobs/{job_id}/cancel")  # its result is not needed here

    open_page(browser, f"{base}/#/jobs/{scan_id}")
    wait_for(lambda: el(browser, "result-id").get_attribute("title") == scan_id
             and el(browser, "result-scan").is_displayed(), "the scan's reconstruct form")
    choose(browser, "recon-method", "nedner")
    jobs_before = len(api.get("/api/jobs", params={"kind": "recon"}).json())
    set_value(browser, "recon-dz", "60 kg")
    el(browser, "recon-start").click()
    wait_for(lambda: el(browser, "error").is_displayed() and "'60 kg' is not a length" in text(browser, "error-text"),
             "the refusal of dz 60 kg")
    assert "dz" in text(browser, "error-text") and text(browser, "result-kind") == "scan"
    assert len(api.get("/api/jobs", params={"kind": "recon"}).json()) == jobs_before
    shot(browser, screenshots, "units-recon-form-refused")


def test_only_the_plan_view_previews_so_no_preview_clears_another_view_s_error(browser, base, screenshots):
    """A page opened on the jobs view makes no plan preview once its mask kinds are built:
    a preview's answer clears the error banner, so one finishing after a refusal in the
    reconstruct form would hide that refusal. Opening the plan view then previews."""
    open_page(browser, f"{base}/#/jobs")
    # buildMaskSelect fills the kinds and, on the old page, schedules its preview in the same task
    wait_for(lambda: browser.execute_script("return document.getElementById('mask-kind').options.length") > 0,
             "the mask kinds")
    previews = ("return performance.getEntriesByType('resource')"
                ".filter(e => e.name.includes('/api/plans/preview')).length")
    busy = "return document.querySelector('.preview-panel').hasAttribute('aria-busy')"
    assert not browser.execute_script(busy) and browser.execute_script(previews) == 0
    el(browser, "nav-plan").click()
    wait_for(lambda: preview_settled(browser), "the plan view's preview")
    assert browser.execute_script(previews) >= 1


def test_upload_form_reads_spacings_and_sound_speed_with_units(browser, base, api, screenshots, tmp_path):
    """The upload's dt and dx show ns and µm (their load options' display unit) and read
    "0.02 µs", "0.1 mm"; the sound speed reads "1.5 km/s": the dataset its job reads has
    2e-8 s, 1e-4 m and 1500 m/s."""
    np = pytest.importorskip("numpy")
    from selenium.webdriver.support.ui import Select

    path = tmp_path / "sensor_data.npy"
    np.save(path, np.random.default_rng(3).standard_normal((96, 12, 16)).astype(np.float32))
    open_page(browser, f"{base}/#/jobs")
    wait_for(lambda: el(browser, "view-jobs").is_displayed(), "the jobs view")
    browser.find_element("css selector", "#upload-panel summary").click()
    choose(browser, "upload-format", "npy")
    wait_for(lambda: unit_of(browser, "upload-dt") == "ns", "the dt field's unit")
    assert (unit_of(browser, "upload-dx"), unit_of(browser, "upload-dy"), unit_of(browser, "upload-c")) == ("µm", "µm", "m/s")
    el(browser, "upload-file").send_keys(str(path))
    set_value(browser, "upload-dt", "0.02 µs")
    set_value(browser, "upload-dx", "0.1 mm")
    set_value(browser, "upload-c", "1.5 km/s")
    Select(el(browser, "upload-method")).select_by_value("ner")
    before = el(browser, "result-id").get_attribute("title")
    el(browser, "upload-start").click()
    wait_for(lambda: text(browser, "result-kind") == "recon" and el(browser, "result-id").get_attribute("title") != before,
             "the upload's reconstruction job")
    job = api.get(f"/api/jobs/{el(browser, 'result-id').get_attribute('title')}").json()
    shape = job["params"]["shape"]  # the stored dataset's sampling (fpscan.service.jobs.admission.input_shape)
    assert (shape["dt"], shape["dx"], shape["sound_speed"]) == (2e-8, 1e-4, 1500.0), shape
    api.post(f"/api/jobs/{job['id']}/cancel")  # its result is not needed here
    shot(browser, screenshots, "units-upload-form")
