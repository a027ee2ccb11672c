"""End-to-end tests of the web page in a real headless Chromium against a real
``fpscan serve`` (token configured) and a simulated scanner from ``fpscan sim`` on a pty.

What the user does, step by step: signs in on the login view (the token is kept for the tab); a plan is previewed while the
parameters change and saved; a scan is started and watched to 100 % with the live
preview changing; the result is opened, reconstructed and its volume downloaded.

Oracles are independent of the page: the same requests made with httpx (the server's own
numbers and reasons), the scan file and the volume read with h5py, pixel data of the
images taken from the browser. Screenshots of each view go to test-artifacts/screenshots/.
"""
from __future__ import annotations

import base64
import hashlib
import io
import json
import time
from pathlib import Path

import pytest

from fpscan.clients.processes import Service, simulator, start_service
from tests.clients.clients_servers import QUIET
from tests.waits import HANG_S
from tests.web.web_e2e_support import REPO_ROOT, has_subcommand, open_page, preview_settled, wait_for

httpx = pytest.importorskip("httpx")

TOKEN = "web-e2e-token-4711"
# A 6 mm aperture over the simulator's built-in phantom (balls at 1.5-4.5 mm depth).
LATTICE = {"n_x": 40, "n_y": 40, "pitch": 1.5e-4}
DEPTH_MM = 3.6
N_POINTS = 120
PRF_HZ = 25.0  # simulator and plan: ~5 s for the ~130-point scan, time for several live previews

pytestmark = [pytest.mark.timeout(600),  # the suite's: waits end on events (tests.waits)
              pytest.mark.long(80)]


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """``fpscan sim`` (analytic balls) on a pty; yields its device path (None where this
    build has no ``fpscan sim``: the scan steps then skip and say so)."""
    if not has_subcommand("sim"):
        yield None
        return
    folder = tmp_path_factory.mktemp("sim")
    with simulator("--prf", str(PRF_HZ), "--seed", "1", log_path=folder / "sim.log") as (device, _proc):
        yield device


def start_server(data: Path, devices: dict, token: str | None) -> Service:
    """``fpscan serve`` (with the web page) on a free 127.0.0.1 port, its log in
    ``data/serve.log``."""
    if not has_subcommand("serve"):
        pytest.skip("this build has no `fpscan serve`")
    return start_service(data, token=token, devices=devices, env={**QUIET, "FPSCAN_PREVIEW_INTERVAL_S": "0.5"},
                         log_path=data / "serve.log", timeout=HANG_S)


@pytest.fixture(scope="module")
def server(sim, tmp_path_factory):
    """``fpscan serve`` on 127.0.0.1 with a token and the simulated scanner as ``sim1``."""
    data = tmp_path_factory.mktemp("serve")
    srv = start_server(data, {"sim1": sim} if sim else {}, TOKEN)
    try:
        yield srv.url
    finally:
        srv.stop()
        # the server's log beside the screenshots, for a reviewer of a failed run
        (REPO_ROOT / "test-artifacts").mkdir(exist_ok=True)
        (REPO_ROOT / "test-artifacts" / "web-serve.log").write_bytes((data / "serve.log").read_bytes())


@pytest.fixture(scope="module")
def api(server):
    with httpx.Client(base_url=server, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30) as c:
        yield c


@pytest.fixture(scope="module")
def state():
    """What one step hands to the next (plan id, scan job id)."""
    return {}


# ----------------------------------------------------------------------------- helpers
def el(browser, element_id):
    return browser.find_element("id", element_id)


def text(browser, element_id) -> str:
    return browser.execute_script("return document.getElementById(arguments[0]).textContent", element_id).strip()


def set_value(browser, element_id, value) -> None:
    """Type a new value into an input, as a user would (fires input events)."""
    from selenium.webdriver.common.keys import Keys

    box = el(browser, element_id)
    box.send_keys(Keys.CONTROL, "a")
    box.send_keys(Keys.DELETE)
    box.send_keys(str(value))


def image_digest(browser, element_id) -> str | None:
    """sha256 of the pixels the browser shows in an <img> (None until it has loaded)."""
    data_url = browser.execute_script(
        """const img = document.getElementById(arguments[0]);
           if (!img.complete || !img.naturalWidth) return null;
           const c = document.createElement('canvas');
           c.width = img.naturalWidth; c.height = img.naturalHeight;
           c.getContext('2d').drawImage(img, 0, 0);
           return c.toDataURL('image/png');""", element_id)
    if not data_url:
        return None
    return hashlib.sha256(base64.b64decode(data_url.split(",", 1)[1])).hexdigest()


def choose(browser, select_id: str, value: str) -> None:
    """Pick ``value`` in a <select> once it is offered (the page may be rebuilding the
    list: retried until the choice sticks)."""
    from selenium.webdriver.support.ui import Select

    def pick():
        sel = Select(el(browser, select_id))
        if value not in [o.get_attribute("value") for o in sel.options]:
            return False
        sel.select_by_value(value)
        return el(browser, select_id).get_attribute("value") == value

    wait_for(pick, f"{value!r} to be chosen in #{select_id}")


def wait_job_shown(browser, job_id: str, states, what: str) -> str:
    """Wait until the result view shows job ``job_id`` itself (its id, not the previous
    job's, which a hash-only navigation leaves on screen until the page has routed) in one
    of ``states``; returns that state."""
    wait_for(lambda: el(browser, "result-id").get_attribute("title") == job_id
             and text(browser, "result-state") in states, what, 0.3)
    return text(browser, "result-state")


def png_pixels_as_browser_png(browser, png_base64: str) -> bytes:
    """The PNG the browser's canvas makes of a given PNG (for pixel-exact comparison)."""
    data_url = browser.execute_async_script(
        """const done = arguments[arguments.length - 1];
           const img = new Image();
           img.onload = () => { const c = document.createElement('canvas');
             c.width = img.naturalWidth; c.height = img.naturalHeight;
             c.getContext('2d').drawImage(img, 0, 0); done(c.toDataURL('image/png')); };
           img.onerror = () => done(null);
           img.src = 'data:image/png;base64,' + arguments[0];""", png_base64)
    assert data_url, "the browser could not decode the PNG"
    return base64.b64decode(data_url.split(",", 1)[1])


def shot(browser, screenshots: Path, name: str) -> None:
    """A full-page screenshot (Chrome DevTools ``Page.captureScreenshot`` beyond the
    viewport), or the viewport where that is not available."""
    try:
        size = browser.execute_script(
            "return [document.documentElement.scrollWidth, document.documentElement.scrollHeight]")
        shot_ = browser.execute_cdp_cmd("Page.captureScreenshot", {
            "format": "png", "captureBeyondViewport": True,
            "clip": {"x": 0, "y": 0, "width": size[0], "height": size[1], "scale": 1}})
        (screenshots / f"{name}.png").write_bytes(base64.b64decode(shot_["data"]))
    except Exception:  # fall back to the viewport
        browser.save_screenshot(str(screenshots / f"{name}.png"))


def plan_request(n_points: int) -> dict:
    return {"kind": "equisteradian", "lattice": LATTICE,
            "params": {"depth": DEPTH_MM * 1e-3, "n_points": n_points},
            "acquisition": {"n_t": 256, "dt": 2e-8, "averages": 1, "wavelengths": [7.5e-7],
                            "prf": PRF_HZ, "sound_speed": 1500.0}}


def fill_plan_form(browser, n_points: int) -> None:
    # the plan view shows once the page knows whether it needs a token (GET /api/auth) and
    # has the mask kinds: until then its fields cannot take keys
    wait_for(lambda: el(browser, "view-plan").is_displayed() and el(browser, "lat-nx").is_enabled(), "the plan form")
    set_value(browser, "lat-nx", LATTICE["n_x"])
    set_value(browser, "lat-ny", LATTICE["n_y"])
    set_value(browser, "lat-pitch", LATTICE["pitch"] * 1e6)
    choose(browser, "mask-kind", "equisteradian")  # offered once /api/plans/kinds is loaded
    set_value(browser, "mask-depth", DEPTH_MM)
    set_value(browser, "acq-nt", 256)
    set_value(browser, "acq-dt", 20)
    set_value(browser, "acq-prf", int(PRF_HZ))
    set_value(browser, "mask-n-points", n_points)


def login_shown(browser) -> bool:
    return browser.execute_script("return !document.getElementById('view-login').hidden")


def submit_token_if_asked(browser, token=TOKEN) -> bool:
    """Sign in on the page's login view when the page asks for a token (False when it
    does not): waits for the page's sign-in check (``body[data-auth-checked]``, set once
    GET /api/auth has answered), not for a time."""
    wait_for(lambda: browser.execute_script("return document.body.dataset.authChecked || ''"),
             "the page's sign-in check")
    if not login_shown(browser):
        return False
    set_value(browser, "login-token", token)
    el(browser, "login-submit").click()
    wait_for(lambda: not login_shown(browser), "the login view to give way to the page")
    return True


def refused_requests(browser) -> list:
    """The page's requests answered 401 so far (the browser's own record:
    Resource Timing ``responseStatus``)."""
    return browser.execute_script(
        "return performance.getEntriesByType('resource').filter(e => e.responseStatus === 401).map(e => e.name)")


# ----------------------------------------------------------------------------- tests
def token_prompts(browser) -> int:
    return int(browser.execute_script("return document.body.dataset.tokenPrompts || '0'"))


def test_plan_view_preview_errors_token_and_save(browser, server, api, screenshots, state):
    open_page(browser, server + "/#/plan")
    # The server needs a token: the page opens on its login view (not a dialog over a page
    # whose requests failed), before any request that needs the token.
    wait_for(lambda: login_shown(browser), "the login view")
    assert not el(browser, "view-plan").is_displayed()
    shot(browser, screenshots, "login-view")
    # a wrong token is refused on the login view, with the reason
    set_value(browser, "login-token", "not-the-token")
    el(browser, "login-submit").click()
    wait_for(lambda: "refused" in text(browser, "login-error"), "the refusal on the login view")
    assert login_shown(browser) and browser.execute_script("return sessionStorage.getItem('fpscan.token')") is None
    assert submit_token_if_asked(browser), "the login view went away"
    assert browser.execute_script("return sessionStorage.getItem('fpscan.token')") == TOKEN
    wait_for(lambda: preview_settled(browser), "the first preview")
    assert refused_requests(browser) == [], "a request of the page was refused (401)"
    fill_plan_form(browser, N_POINTS)

    # The preview follows the parameters: the server's own numbers for the same request.
    oracle = api.post("/api/plans/preview", json=plan_request(N_POINTS))
    assert oracle.status_code == 200, oracle.text
    expected = oracle.json()
    wait_for(lambda: text(browser, "plan-points").split()[0] == str(expected["points"]),
             f"the page to show {expected['points']} points")
    first = hashlib.sha256(png_pixels_as_browser_png(browser, expected["preview_png_base64"])).hexdigest()
    wait_for(lambda: image_digest(browser, "plan-preview") == first, "the server's preview image, pixel for pixel")
    if expected["weight_ratio"] is not None:
        assert float(text(browser, "plan-ratio")) == pytest.approx(expected["weight_ratio"], rel=5e-3)
    assert text(browser, "plan-time") not in ("", "–")
    shot(browser, screenshots, "plan-view")

    more = 2 * N_POINTS
    expected2 = api.post("/api/plans/preview", json=plan_request(more)).json()
    assert expected2["points"] != expected["points"]
    set_value(browser, "mask-n-points", more)
    wait_for(lambda: text(browser, "plan-points").split()[0] == str(expected2["points"]),
             "the point count to follow the parameter")
    second = hashlib.sha256(png_pixels_as_browser_png(browser, expected2["preview_png_base64"])).hexdigest()
    assert second != first
    wait_for(lambda: image_digest(browser, "plan-preview") == second, "the preview image to change to the server's")

    # Bad input: the server's reason is shown, word for word.
    bad = api.post("/api/plans/preview", json=plan_request(0))
    assert 400 <= bad.status_code < 500
    reason = bad.json()["detail"]
    set_value(browser, "mask-n-points", 0)
    wait_for(lambda: text(browser, "plan-preview-state").startswith("No preview"), "the error to show")
    assert reason in text(browser, "plan-preview-state")
    assert el(browser, "error").is_displayed() and reason in text(browser, "error-text")
    shot(browser, screenshots, "plan-view-error")
    # a number the server refuses is worded for the field it came from and its unit, not the
    # command line's "write the unit, e.g. 8ns" behind the request's path
    set_value(browser, "mask-n-points", N_POINTS)
    set_value(browser, "acq-dt", 8e9)  # ns: 8 s
    wait_for(lambda: text(browser, "plan-preview-state").startswith("No preview: dt in ns: 8000000000 ns is "
                                                                  "implausible"), "the dt field's reason")
    shown = text(browser, "plan-preview-state")
    assert "write the unit" not in shown and "equisteradian" not in shown and "(expected 100 ps to 1 µs)" in shown, shown
    set_value(browser, "acq-dt", 20)

    # Save (a mutating route): the token given for the preview is used, nothing is asked again.
    set_value(browser, "mask-n-points", N_POINTS)
    wait_for(lambda: text(browser, "plan-points").split()[0] == str(expected["points"]), "the preview to recover")
    assert token_prompts(browser) == 1
    el(browser, "plan-save").click()
    plan_id = wait_for(lambda: el(browser, "plan-saved").get_attribute("data-plan-id"), "the saved plan id")
    saved = api.get(f"/api/plans/{plan_id}")
    assert saved.status_code == 200, saved.text
    assert saved.json()["n_points"] == expected["points"]
    assert token_prompts(browser) == 1
    state["plan_id"] = plan_id
    state["n_points"] = expected["points"]


def test_scan_view_progress_reaches_100_and_live_preview_changes(browser, sim, server, api, screenshots, state,
                                                                tmp_path):
    if "plan_id" not in state:
        pytest.skip("needs the plan saved by the plan-view test")
    if sim is None:
        pytest.skip("this build has no `fpscan sim` (simulated scanner)")
    el(browser, "nav-scan").click()
    choose(browser, "scan-plan", state["plan_id"])
    choose(browser, "scan-scanner", "sim1")
    time.sleep(0.3)  # let a list refresh in flight land, then check the choice held
    choose(browser, "scan-plan", state["plan_id"])
    el(browser, "scan-start").click()

    job_id = wait_for(lambda: el(browser, "scan-job").get_attribute("title"), "the scan job id")
    versions: dict[str, str] = {}

    def seen_versions() -> dict[str, str]:
        """Keep every live preview version the page shows (its xy pixels)."""
        v = el(browser, "scan-mip-xy").get_attribute("data-version")
        if v and v not in versions:
            digest = image_digest(browser, "scan-mip-xy")
            if digest:
                versions[v] = digest
        return versions

    # a preview of part of the points, whatever the machine's speed: the scan is held
    # (paused over the API) after a few points until the page shows their preview
    wait_for(lambda: (api.get(f"/api/jobs/{job_id}").json()["progress"].get("points_done") or 0) >= 2,
             "the first points")
    assert api.post(f"/api/scans/{job_id}/pause").status_code == 200
    wait_for(seen_versions, "a live preview of the paused scan")
    assert api.post(f"/api/scans/{job_id}/resume").status_code == 200
    wait_for(lambda: text(browser, "scan-state") == "running", "the page to show running again")
    shot(browser, screenshots, "scan-view-running")
    wait_for(lambda: seen_versions() and text(browser, "scan-state") in ("succeeded", "failed", "cancelled"), "the scan to end", 0.15)
    assert text(browser, "scan-state") == "succeeded", api.get(f"/api/jobs/{job_id}").text
    # progress came over Server-Sent Events (not only from polling)
    assert int(browser.execute_script("return document.body.dataset.sseEvents || '0'")) >= 3
    wait_for(lambda: text(browser, "scan-progress-label") == "100 %", "progress 100 %")
    assert el(browser, "scan-progress").get_attribute("value") in ("1", "1.0")
    n = state["n_points"]
    assert text(browser, "scan-points") == f"{n} / {n}"
    # the last refresh (every point) lands before the job ends: the page shows it
    final = str(api.get(f"/api/scans/{job_id}/preview").json()["version"])
    wait_for(lambda: final in seen_versions(), f"the last live preview (version {final})")
    shot(browser, screenshots, "scan-view-done")
    assert token_prompts(browser) == 1, "the token was asked again"
    assert len(versions) >= 2, f"saw live preview versions {list(versions)}"
    assert len(set(versions.values())) >= 2, "the live preview image never changed"

    # The scan file on the server holds every point of the plan.
    h5py = pytest.importorskip("h5py")
    r = api.get(f"/api/scans/{job_id}/file")
    assert r.status_code == 200
    path = tmp_path / "scan.h5"
    path.write_bytes(r.content)
    with h5py.File(path, "r") as f:
        assert f is not None  # opens as HDF5
    state["scan_job_id"] = job_id


def test_result_view_reconstruct_slices_and_download_volume(browser, server, api, screenshots, state, download_dir):
    from selenium.webdriver.support.ui import Select

    if "scan_job_id" not in state:
        pytest.skip("needs the scan of the scan-view test")
    scan_id = state["scan_job_id"]
    el(browser, "nav-jobs").click()
    row = wait_for(lambda: browser.find_element("css selector", f'tr[data-job-id="{scan_id}"]'), "the scan in the job list")
    assert row.find_element("css selector", ".c-state").text.strip() == "succeeded"
    row.find_element("css selector", "a.c-open").click()
    wait_for(lambda: el(browser, "result").is_displayed() and text(browser, "result-kind") == "scan", "the scan's result view")
    links = {a.text: a.get_attribute("href") for a in browser.find_elements("css selector", "#result-downloads a")}
    assert any("Scan file" in k for k in links) and any("IPASC" in k for k in links), links
    shot(browser, screenshots, "jobs-scan-result")

    # "unmix" on a one-wavelength scan: the server's reason is shown, no job is started
    Select(el(browser, "recon-method")).select_by_value("nedner")
    el(browser, "recon-unmix").click()
    el(browser, "recon-start").click()
    wait_for(lambda: el(browser, "error").is_displayed() and "at least two wavelengths" in text(browser, "error-text"), "the unmixing refusal")
    assert text(browser, "result-kind") == "scan"
    el(browser, "recon-unmix").click()  # off again
    el(browser, "error-close").click()

    Select(el(browser, "recon-method")).select_by_value("nedner")
    el(browser, "recon-start").click()
    wait_for(lambda: text(browser, "result-kind") == "recon", "the reconstruction job to open")
    recon_id = el(browser, "result-id").get_attribute("title")
    state = wait_job_shown(browser, recon_id, ("succeeded", "failed"), "the reconstruction to finish")
    assert state == "succeeded", api.get(f"/api/jobs/{recon_id}").text
    for plane in ("xy", "xz", "yz"):
        oracle = api.get(f"/api/reconstructions/{recon_id}/mip/{plane}.png")
        assert oracle.status_code == 200
        want = hashlib.sha256(png_pixels_as_browser_png(browser, base64.b64encode(oracle.content).decode())).hexdigest()
        wait_for(lambda plane=plane, want=want: image_digest(browser, f"result-mip-{plane}") == want, f"the {plane} MIP's pixels")
    # The parameters used are listed.
    params = text(browser, "result-params")
    assert "nedner" in params or "method" in params

    # Depth-slice slider: a different slice shows a different image.
    slider = el(browser, "result-slice")
    top = int(slider.get_attribute("max"))
    assert top > 0, "the slider has no depth range"
    first = wait_for(lambda: image_digest(browser, "result-slice-img"), "the first depth slice")
    browser.execute_script("const s = arguments[0]; s.value = s.max; s.dispatchEvent(new Event('input'));", slider)
    wait_for(lambda: (el(browser, "result-slice-img").get_attribute("data-src") or "").endswith(f"index={top}"), "the last slice")
    assert text(browser, "result-slice-value").startswith(f"{top} of")
    dz = api.get(f"/api/jobs/{recon_id}").json()["params"]["result"]["params_used"]["dz"]
    assert text(browser, "result-slice-depth") == f"(z = {top * dz * 1e3:.3f} mm)"  # the depth, not only the index
    last = api.get(f"/api/reconstructions/{recon_id}/slice.png", params={"index": top})
    assert last.status_code == 200
    want = hashlib.sha256(png_pixels_as_browser_png(browser, base64.b64encode(last.content).decode())).hexdigest()
    wait_for(lambda: image_digest(browser, "result-slice-img") == want, "the last slice's pixels")
    assert want != first
    shot(browser, screenshots, "jobs-recon-result")

    # Download the volume through the page: byte for byte what the API serves, and HDF5.
    link = next(a for a in browser.find_elements("css selector", "#result-downloads a") if a.text.startswith("Volume"))
    link.click()
    got = wait_for(lambda: [p for p in download_dir.iterdir() if p.suffix == ".h5" and p.name.startswith("volume")], "the downloaded volume")
    oracle = api.get(f"/api/reconstructions/{recon_id}/volume.h5")
    wait_for(lambda: got[0].stat().st_size == len(oracle.content), "the download to complete")
    assert got[0].read_bytes() == oracle.content
    h5py = pytest.importorskip("h5py")
    with h5py.File(got[0], "r") as f:
        assert len(f.keys()) > 0

    # the jobs table names what was reconstructed: the scan and its plan's mask
    plan = api.get(f"/api/plans/{api.get(f'/api/jobs/{scan_id}').json()['params']['plan_id']}/plan.json").json()
    n, total = len(plan["points"]["indices"]), plan["lattice"]["n_x"] * plan["lattice"].get("n_y", 1)
    words = (f"full {plan['lattice']['n_x']}×{plan['lattice']['n_y']}" if n == total
             else f"{plan['mask']['kind']}, {n} of {total} points")
    el(browser, "nav-jobs").click()
    row = wait_for(lambda: browser.find_element("css selector", f'tr[data-job-id="{recon_id}"]'), "the reconstruction in the job list")
    wait_for(lambda: row.find_element("css selector", ".c-what").text == f"nedner of scan {scan_id[:8]} ({words})",
             "the reconstruction's label")

    # the table pages (a page of one job here): "Older jobs" shows the next page, "Newest jobs" the first
    def rows():
        return [tr.get_attribute("data-job-id") for tr in browser.find_elements("css selector", "#jobs-body tr")]

    newest = [j["id"] for j in api.get("/api/jobs", params={"limit": 2}).json()]
    browser.execute_script("document.getElementById('jobs-table').dataset.page = '1';")
    el(browser, "jobs-refresh").click()
    wait_for(lambda: rows() == newest[:1] and el(browser, "jobs-older").is_displayed(), "a page of one job")
    assert not el(browser, "jobs-newest").is_displayed()
    el(browser, "jobs-older").click()
    wait_for(lambda: rows() == newest[1:2] and el(browser, "jobs-newest").is_displayed(), "the next page")
    el(browser, "jobs-newest").click()
    wait_for(lambda: rows() == newest[:1], "the newest page again")
    browser.execute_script("document.getElementById('jobs-table').dataset.page = '200';")
    el(browser, "jobs-refresh").click()

    # the scan's view lists its reconstructions, filtered by the server (GET /api/jobs?scan_job_id=)
    row = wait_for(lambda: browser.find_element("css selector", f'tr[data-job-id="{scan_id}"]'), "the scan in the job list")
    row.find_element("css selector", "a.c-open").click()
    wait_for(lambda: any(a.get_attribute("href").endswith("#/jobs/" + recon_id)
                         for a in browser.find_elements("css selector", "#scan-recons a")),
             "the reconstruction among the scan's")


def test_result_view_offers_the_model_based_method_and_its_parameters(browser, server, api, screenshots, state):
    """Choosing ``tv`` shows its λ and iteration fields (hidden for the other methods)
    with positivity on; the job the page starts carries them; the page cancels it."""
    from selenium.webdriver.support.ui import Select

    if "scan_job_id" not in state:
        pytest.skip("needs the scan of the scan-view test")
    el(browser, "nav-jobs").click()
    row = wait_for(lambda: browser.find_element("css selector", f'tr[data-job-id="{state["scan_job_id"]}"]'),
                   "the scan in the job list")
    row.find_element("css selector", "a.c-open").click()
    wait_for(lambda: el(browser, "result").is_displayed() and text(browser, "result-kind") == "scan",
             "the scan's result view")
    Select(el(browser, "recon-method")).select_by_value("nedner")
    assert not el(browser, "recon-lam").is_displayed() and not el(browser, "recon-max-iter").is_displayed()
    Select(el(browser, "recon-method")).select_by_value("tv")
    wait_for(lambda: el(browser, "recon-lam").is_displayed(), "the λ field")
    assert el(browser, "recon-max-iter").is_displayed() and el(browser, "recon-positivity").is_selected()
    set_value(browser, "recon-lam", 0.002)
    set_value(browser, "recon-max-iter", 7)
    shot(browser, screenshots, "jobs-recon-tv-form")
    before = el(browser, "result-id").get_attribute("title")
    # c = 2500 m/s: the server's reason (the rule of the CLI and the library), no job;
    # accepted once "another medium" is ticked
    set_value(browser, "recon-c", 2500)
    el(browser, "recon-start").click()
    wait_for(lambda: el(browser, "error").is_displayed() and "sound speed in m/s: 2500 m/s is implausible" in text(browser, "error-text")
             and "tick “another medium”" in text(browser, "error-text"), "the refusal of c = 2500 m/s")
    assert el(browser, "result-id").get_attribute("title") == before
    el(browser, "error-close").click()
    el(browser, "recon-force").click()
    el(browser, "recon-start").click()
    wait_for(lambda: text(browser, "result-kind") == "recon" and el(browser, "result-id").get_attribute("title") != before, "the tv job to open")
    job_id = el(browser, "result-id").get_attribute("title")
    job = api.get(f"/api/jobs/{job_id}").json()
    assert job["params"]["method"] == "tv", job
    sent = job["params"]["params"]
    assert sent["lam"] == 0.002 and sent["max_iter"] == 7 and sent["positivity"] is True, sent
    assert sent["sound_speed"] == 2500 and sent["force"] is True, sent  # stored under the person's name
    browser.execute_script("document.getElementById('recon-c').value = '';"
                           "document.getElementById('recon-force').checked = false;")  # as later tests expect
    if el(browser, "result-cancel").is_displayed():  # a 7-iteration solve is not needed here
        el(browser, "result-cancel").click()
    wait_job_shown(browser, job_id, ("cancelled", "succeeded"), "the tv job to end")


def test_upload_a_data_file_and_reconstruct_it(browser, server, api, screenshots, tmp_path):
    """A k-Wave-layout NumPy file uploaded from the page with spacings typed in µm/ns:
    the reconstruction's volume has the grid those spacings give (SI on the wire)."""
    np = pytest.importorskip("numpy")
    h5py = pytest.importorskip("h5py")
    from selenium.webdriver.support.ui import Select

    n_t, n_y, n_x = 96, 12, 16
    data = np.random.default_rng(7).standard_normal((n_t, n_y, n_x)).astype(np.float32)
    path = tmp_path / "sensor_data.npy"
    np.save(path, data)

    el(browser, "nav-jobs").click()
    wait_for(lambda: el(browser, "view-jobs").is_displayed(), "the jobs view")
    # both method choices are the server's methods (GET /api/reconstructions/methods), and
    # the reconstruct form starts from each method's own defaults, showing its options only
    listed = api.get("/api/reconstructions/methods").json()
    names = [m["name"] for m in listed]
    for select in ("upload-method", "recon-method"):
        wait_for(lambda s=select: browser.execute_script(
            "return [...document.getElementById(arguments[0]).options].map(o => o.value)", s) == names, f"the {select} choices")
    for m in listed:
        opts = {o["name"]: o["default"] for o in m["options"]}
        form = browser.execute_script(
            "const s = document.getElementById('recon-method'); s.value = arguments[0];"
            "s.dispatchEvent(new Event('change'));"
            "return [document.getElementById('recon-positivity').checked].concat("
            "['recon-positivity-label', 'recon-lam-label', 'recon-max-iter-label']"
            ".map(i => !document.getElementById(i).hidden))", m["name"])
        assert form == [bool(opts.get("positivity")), "positivity" in opts, "lam" in opts, "max_iter" in opts], m
    # the format choices are the server's (GET /api/datasets/formats: the registry of formats), titles too
    formats = api.get("/api/datasets/formats").json()
    wait_for(lambda: browser.execute_script(
        "return [...document.getElementById('upload-format').options].map(o => [o.value, o.textContent])")
        == [[f["name"], f["title"]] for f in formats], "the upload-format choices")
    assert "npy" in [f["name"] for f in formats] and "dataset" not in [f["name"] for f in formats]
    browser.find_element("css selector", "#upload-panel summary").click()
    el(browser, "upload-file").send_keys(str(path))
    # the form shows the chosen format's load options only (GET /api/formats: its typed model)
    taken = {f["name"]: {o["name"] for o in f["options"]} for f in api.get("/api/formats").json() if f["upload"]}
    shown = ("return [...document.querySelectorAll('#upload-form [data-load-option]')]"
             ".filter(l => !l.hidden).map(l => l.dataset.loadOption)")
    for name in ("kwave-hdf5", "fpscan", "npy"):
        Select(el(browser, "upload-format")).select_by_value(name)
        assert set(browser.execute_script(shown)) == taken[name] & {"dt", "dx", "dy", "key", "axes"}, name
    assert taken["npy"] == {"dt", "dx", "dy", "axes"} and "key" in taken["kwave-hdf5"]
    set_value(browser, "upload-dt", 20)      # ns
    set_value(browser, "upload-dx", 100)     # µm; dy left empty = dx
    # the "another medium" labels name the plausible speeds of the registry's speed option
    speed = next(o for o in listed[0]["options"] if o["name"] == "sound_speed")["value_schema"]["anyOf"][0]
    plausible = f"{speed['minimum']:g}–{speed['maximum']:g} m/s"
    wait_for(lambda: all(plausible in browser.execute_script(
        "return document.getElementById(arguments[0]).parentElement.textContent", i)
        for i in ("upload-force", "recon-force", "acq-force")), "the plausible speeds in the force labels")
    # c = 2500 m/s is refused with the server's reason (the rule of the CLI and the library)
    # until "another medium" is ticked
    set_value(browser, "upload-c", 2500)
    Select(el(browser, "upload-method")).select_by_value("ner")
    before = el(browser, "result-id").get_attribute("title")
    el(browser, "upload-start").click()
    wait_for(lambda: "sound speed in m/s: 2500 m/s" in text(browser, "upload-state"), "the server's reason for c")
    assert "1000 to 2000" in text(browser, "upload-state")
    el(browser, "upload-force").click()
    el(browser, "upload-start").click()
    wait_for(lambda: text(browser, "result-kind") == "recon" and el(browser, "result-id").get_attribute("title") != before, "the upload's reconstruction job to open")
    browser.execute_script("document.getElementById('upload-force').checked = false;")  # as later tests expect
    recon_id = el(browser, "result-id").get_attribute("title")
    state = wait_job_shown(browser, recon_id, ("succeeded", "failed"), "the reconstruction to finish")
    job = api.get(f"/api/jobs/{recon_id}").json()
    assert state == "succeeded", job
    assert job["params"]["dataset_id"] and job["params"]["method"] == "ner"
    assert job["params"]["params"]["force"] is True, job
    shot(browser, screenshots, "jobs-upload-result")
    vol = tmp_path / "volume.h5"
    vol.write_bytes(api.get(f"/api/reconstructions/{recon_id}/volume.h5").content)
    with h5py.File(vol, "r") as f:
        x, y = f["x"][...], f["y"][...]
        assert f["p0"].shape[1:] == (n_y, n_x)
    assert np.diff(x) == pytest.approx(np.full(n_x - 1, 100e-6), rel=1e-9)
    assert np.diff(y) == pytest.approx(np.full(n_y - 1, 100e-6), rel=1e-9)
    # the same volume in every export format of the server's registry (OME-TIFF, zipped OME-Zarr
    # for napari / ImageJ ...): one link each, titled by the format, that the server answers
    exports = {f["title"] + (", zipped" if f["folder"] else "") for f in api.get("/api/formats").json()
               if f["export_from"] == "result" and f["name"] != "result"}
    assert any("OME-TIFF" in t for t in exports) and any("OME-Zarr" in t for t in exports), exports
    links = wait_for(lambda: {a.text: a.get_attribute("href") for a in
                              browser.find_elements("css selector", "#result-downloads a")
                              if a.text in exports} or None, "the export download links")
    assert set(links) == exports, links
    for href in links.values():
        assert api.get(href.split(server, 1)[-1]).status_code == 200, href
    # the job list deletes the finished job (after the confirm dialog): row, record and files gone
    row = f'#view-jobs tr[data-job-id="{recon_id}"]'
    delete = wait_for(lambda: next((b for b in browser.find_elements("css selector", row + " .c-delete")
                                    if b.is_displayed()), None), "the job's Delete button")
    browser.execute_script("window.confirm = () => true;")
    delete.click()
    wait_for(lambda: not browser.find_elements("css selector", row), "the deleted job's row to go")
    assert api.get(f"/api/jobs/{recon_id}").status_code == 404
    assert api.get(f"/api/reconstructions/{recon_id}/volume.h5").status_code == 404
    assert el(browser, "result").is_displayed() is False


def test_unmix_result_shows_so2_map_and_autofocus_curve(browser, server, api, screenshots, tmp_path):
    """An unmixing job with c = 'auto' (two uploaded per-wavelength ball datasets): its
    result view shows the masked sO2 picture the server rendered (same pixels) and the
    autofocus curve (one SVG point per evaluated c, the chosen c as in the job)."""
    np = pytest.importorskip("numpy")
    from fpscan.physics import Ball, ball_alines, spectra

    n, dx, dt, n_t, wls = 24, 100e-6, 20e-9, 120, [750e-9, 850e-9]
    x = (np.arange(n) - (n - 1) / 2) * dx
    yy, xx = np.meshgrid(x, x, indexing="ij")
    pos = np.stack([xx.ravel(), yy.ravel()], axis=1)
    ids = []
    for k, w in enumerate(wls):
        amp = float(spectra.absorption(w, 0.8, spectra.BLOOD_THB)[0])
        data = ball_alines(pos, [Ball(0.0, 0.0, 1.0e-3, 200e-6, amp)], dt, n_t, 1500.0).T.reshape(n_t, n, n)
        path = tmp_path / f"w{k}.npy"
        np.save(path, data.astype(np.float32))
        with open(path, "rb") as fh:
            r = api.post("/api/datasets", data={"format": "npy", "dt": str(dt), "dx": str(dx)},
                         files={"file": (path.name, fh, "application/octet-stream")})
        assert r.status_code in (200, 201), r.text
        ids.append(r.json()["dataset_id"])
    r = api.post("/api/reconstructions", json={"dataset_ids": ids, "wavelengths": wls, "method": "ner",
                                               "params": {"sound_speed": "auto", "sound_speed_range": [1450, 1550]}, "unmix": {}})
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    browser.get(f"{server}/#/jobs/{job_id}")
    submit_token_if_asked(browser)
    state = wait_job_shown(browser, job_id, ("succeeded", "failed"), "the unmixing job to finish")
    job = api.get(f"/api/jobs/{job_id}").json()
    assert state == "succeeded", job
    result = job.get("result") or job["params"]["result"]
    wait_for(lambda: el(browser, "result-unmix").is_displayed() and el(browser, "result-autofocus").is_displayed(), "the unmixing and autofocus panels")
    oracle = api.get(f"/api/reconstructions/{job_id}/so2.png")
    assert oracle.status_code == 200
    want = hashlib.sha256(png_pixels_as_browser_png(browser, base64.b64encode(oracle.content).decode())).hexdigest()
    wait_for(lambda: image_digest(browser, "result-so2") == want, "the sO2 picture")
    af = result["autofocus"]
    points = browser.execute_script(
        "return document.querySelectorAll('#result-af-curve circle').length")
    assert points == len(af["sound_speed_values"]) == af["evaluations"]
    assert text(browser, "result-af-c") == str(float(f"{af['sound_speed']:.5g}")).removesuffix(".0")
    assert any(ch.isdigit() for ch in text(browser, "result-af-time")), text(browser, "result-af-time")  # search time
    assert text(browser, "result-af-evals") == str(af["evaluations"])
    assert "750 nm" in text(browser, "result-unmix-wavelengths")
    links = {a.text for a in browser.find_elements("css selector", "#result-downloads a")}
    assert any("Unmixing" in t for t in links) and any("sO2 map" in t for t in links), links
    shot(browser, screenshots, "jobs-unmix-result")


def test_two_wavelength_scan_reconstructs_the_chosen_wavelength(browser, sim, server, api, screenshots):
    """A finished two-wavelength scan offers its wavelengths (and "all") in the reconstruct
    form; the chosen one reaches the job (``wavelength``) and the volume records it, and
    "all" lists one volume per wavelength among the downloads."""
    if sim is None:
        pytest.skip("this build has no `fpscan sim` (simulated scanner)")
    h5py = pytest.importorskip("h5py")
    request = {"lattice": LATTICE, "points": [[i, j] for j in range(18, 22) for i in range(18, 22)],
               "acquisition": {"n_t": 256, "dt": 2e-8, "wavelengths": [7.5e-7, 8.5e-7], "prf": PRF_HZ}}
    plan = api.post("/api/plans", json=request)
    assert plan.status_code in (200, 201), plan.text
    r = api.post("/api/scans", json={"plan_id": plan.json()["id"], "scanner_id": "sim1"})
    assert r.status_code == 202, r.text
    scan_id = r.json()["id"]
    wait_for(lambda: api.get(f"/api/jobs/{scan_id}").json()["state"] in ("succeeded", "failed", "cancelled"),
             "the two-wavelength scan", 0.3)
    assert api.get(f"/api/jobs/{scan_id}").json()["state"] == "succeeded"
    browser.get(f"{server}/#/jobs/{scan_id}")
    submit_token_if_asked(browser)
    wait_for(lambda: el(browser, "result").is_displayed() and el(browser, "recon-wavelength").is_displayed(),
             "the scan's wavelengths in the reconstruct form")
    offered = browser.execute_script(
        "return [...document.getElementById('recon-wavelength').options].map((o) => o.textContent)")
    assert offered == ["750 nm", "850 nm", "all (one volume each)"]
    shot(browser, screenshots, "jobs-scan-two-wavelengths")
    made = []
    for choice in ("1", "all"):
        browser.get(f"{server}/#/jobs/{scan_id}")
        wait_for(lambda: el(browser, "recon-wavelength").is_displayed()
                 and el(browser, "result-id").get_attribute("title") == scan_id, "the scan's result view")
        choose(browser, "recon-method", "nedner")
        choose(browser, "recon-wavelength", choice)
        el(browser, "recon-start").click()
        wait_for(lambda: text(browser, "result-kind") == "recon", "the reconstruction job to open")
        recon_id = el(browser, "result-id").get_attribute("title")
        wait_job_shown(browser, recon_id, ("succeeded", "failed"), "the reconstruction")
        job = api.get(f"/api/jobs/{recon_id}").json()
        assert job["state"] == "succeeded", job
        assert job["params"]["wavelength"] == (1 if choice == "1" else "all")
        made.append(recon_id)
    vol = api.get(f"/api/reconstructions/{made[0]}/volume.h5")
    with h5py.File(io.BytesIO(vol.content), "r") as f:
        used = json.loads(f.attrs["params"])
    assert used["wavelength_index"] == 1 and used["wavelength_nm"] == pytest.approx(850)
    wait_for(lambda: sum("wavelength" in a.text for a in browser.find_elements("css selector", "#result-downloads a"))
             == 2, "one volume per wavelength among the downloads")
    shot(browser, screenshots, "jobs-recon-all-wavelengths")


def test_scan_controls_pause_resume_abort(browser, sim, server, api, screenshots, state):
    if sim is None:
        pytest.skip("this build has no `fpscan sim` (simulated scanner)")
    request = plan_request(900)
    request["acquisition"]["wavelengths"] = [7.5e-7, 8.5e-7]  # the live preview shows the chosen one
    plan = api.post("/api/plans", json=request)
    assert plan.status_code in (200, 201), plan.text
    plan_id = plan.json()["id"]
    el(browser, "nav-scan").click()
    el(browser, "scan-refresh").click()
    choose(browser, "scan-plan", plan_id)
    choose(browser, "scan-scanner", "sim1")
    time.sleep(0.3)
    choose(browser, "scan-plan", plan_id)
    choose(browser, "scan-preview-wavelength", "1")
    offered = browser.execute_script(
        "return [...document.getElementById('scan-preview-wavelength').options].map((o) => o.textContent)")
    assert offered == ["750 nm", "850 nm"]
    wait_for(lambda: el(browser, "scan-start").is_enabled(), "Start to be enabled")
    el(browser, "scan-start").click()
    job_id = wait_for(lambda: (lambda t: t if t and t != state.get("scan_job_id") else None)(
        el(browser, "scan-job").get_attribute("title")), "the new scan job")

    def api_state():
        return api.get(f"/api/jobs/{job_id}").json()

    assert api_state()["params"].get("preview_wavelength") == 1

    wait_for(lambda: text(browser, "scan-state") == "running" and (api_state()["progress"].get("points_done") or 0) > 0, "the scan to run")
    el(browser, "scan-pause").click()
    wait_for(lambda: text(browser, "scan-state") == "paused", "the page to show paused")
    assert api_state()["state"] == "paused"
    assert el(browser, "scan-resume").is_enabled() and not el(browser, "scan-pause").is_enabled()
    # A reload re-attaches to the scan (its id is in the URL) and shows where it stands.
    assert browser.current_url.endswith(f"#/scan/{job_id}")
    browser.refresh()
    wait_for(lambda: text(browser, "scan-state") == "paused" and el(browser, "scan-resume").is_enabled(),
             "the reloaded page to show the paused scan")
    wait_for(lambda: text(browser, "scan-points").startswith(f"{api_state()['progress']['points_done']} / "),
             "the reloaded page to show the points done so far")
    held = api_state()["progress"]["points_done"]
    shot(browser, screenshots, "scan-view-paused")
    el(browser, "scan-resume").click()
    wait_for(lambda: text(browser, "scan-state") == "running", "the page to show running again")
    wait_for(lambda: api_state()["progress"]["points_done"] > held, "the scan to move on after resume")
    el(browser, "scan-abort").click()
    final = wait_for(lambda: (lambda s: s if s in ("cancelled", "failed", "succeeded") else None)(text(browser, "scan-state")), "the abort to end the scan")
    assert final == api_state()["state"] == "cancelled"
    assert el(browser, "scan-start").is_enabled() and not el(browser, "scan-abort").is_enabled()
    assert token_prompts(browser) == 0, "the token was asked again after the reload"


def test_wrong_token_is_refused_with_the_servers_reason(browser, server, api, screenshots):
    oracle = httpx.post(server + "/api/plans", json=plan_request(N_POINTS),
                        headers={"Authorization": "Bearer not-the-token"}, timeout=30)
    assert oracle.status_code == 401
    reason = oracle.json()["detail"]
    open_page(browser, server + "/#/plan")
    # the form as loaded (the server's example values) is previewed with the good token;
    # then a wrong one is stored and the save is refused (no typing: every change would
    # preview, and a preview needs the token too). The wait is for the load's last
    # preview: one still to be sent would meet the wrong token and hide the form.
    wait_for(lambda: el(browser, "view-plan").is_displayed() and el(browser, "plan-save").is_enabled()
             and preview_settled(browser), "the preview")
    browser.execute_script("sessionStorage.setItem('fpscan.token', 'not-the-token')")  # changed on the server
    before = token_prompts(browser)
    el(browser, "plan-save").click()
    wait_for(lambda: login_shown(browser), "the login view after a refused token")
    assert token_prompts(browser) == before + 1
    assert reason in text(browser, "login-error")
    shot(browser, screenshots, "login-view-refused")
    # signing in again carries the refused request out (the plan is saved)
    assert submit_token_if_asked(browser)
    plan_id = wait_for(lambda: el(browser, "plan-saved").get_attribute("data-plan-id"), "the saved plan id")
    assert api.get(f"/api/plans/{plan_id}").status_code == 200
    # "Sign out" forgets the token and shows the login view
    el(browser, "token-button").click()
    wait_for(lambda: login_shown(browser), "the login view after signing out")
    assert browser.execute_script("return sessionStorage.getItem('fpscan.token')") is None
    assert submit_token_if_asked(browser)


def test_without_a_token_nothing_is_asked_and_plain_links_download(browser, tmp_path, download_dir):
    """A server with no token configured: the page never asks for one; saving, uploading
    and the plain download link work as they are."""
    np = pytest.importorskip("numpy")
    data = tmp_path / "serve"
    data.mkdir()
    srv = start_server(data, {}, None)
    base = srv.url
    try:
        browser.get(base + "/#/plan")
        fill_plan_form(browser, N_POINTS)
        wait_for(lambda: preview_settled(browser), "the preview")
        el(browser, "plan-save").click()
        plan_id = wait_for(lambda: el(browser, "plan-saved").get_attribute("data-plan-id"), "the saved plan")
        assert httpx.get(f"{base}/api/plans/{plan_id}", timeout=10).status_code == 200

        path = tmp_path / "tiny.npy"
        np.save(path, np.random.default_rng(3).standard_normal((64, 8, 8)).astype(np.float32))
        el(browser, "nav-jobs").click()
        browser.find_element("css selector", "#upload-panel summary").click()
        el(browser, "upload-file").send_keys(str(path))
        set_value(browser, "upload-dt", 20)
        set_value(browser, "upload-dx", 100)
        el(browser, "upload-start").click()
        wait_for(lambda: text(browser, "result-kind") == "recon" and text(browser, "result-state") == "succeeded", "the upload's reconstruction", 0.3)
        recon_id = el(browser, "result-id").get_attribute("title")
        assert browser.execute_script("return sessionStorage.getItem('fpscan.token')") is None
        assert token_prompts(browser) == 0
        link = wait_for(lambda: next((a for a in browser.find_elements("css selector", "#result-downloads a")
                                      if a.text.startswith("Volume")), None), "the volume link")
        link.click()
        oracle = httpx.get(f"{base}/api/reconstructions/{recon_id}/volume.h5", timeout=30).content
        # the file name is the server's (Content-Disposition wins over the link's download name)
        names = [f"volume-{recon_id}.h5", f"{recon_id}.h5"]
        wait_for(lambda: any((download_dir / n).exists() and (download_dir / n).read_bytes() == oracle for n in names), "the plain link's download, byte for byte")
    finally:
        srv.stop()


def test_keyboard_navigation_and_state_without_colour(browser, server, screenshots, state):
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys

    browser.get("about:blank")
    browser.get(server + "/#/plan")
    if wait_for(lambda: (login_shown(browser) and "login") or el(browser, "view-plan").is_displayed(),
                "the plan view or the login view") == "login":  # the tab holds no token (a test before failed)
        submit_token_if_asked(browser)
        # load the page again, signed in: Tab would otherwise start where the login field was
        browser.get("about:blank")
        browser.get(server + "/#/plan")
    wait_for(lambda: el(browser, "view-plan").is_displayed(), "the plan view")
    # Tab from the top of the page reaches the navigation; Enter on "Scan" switches view.
    for _ in range(12):
        ActionChains(browser).send_keys(Keys.TAB).perform()
        if browser.switch_to.active_element.get_attribute("id") == "nav-scan":
            break
    assert browser.switch_to.active_element.get_attribute("id") == "nav-scan"
    ActionChains(browser).send_keys(Keys.ENTER).perform()
    wait_for(lambda: el(browser, "view-scan").is_displayed(), "the scan view")
    assert el(browser, "nav-scan").get_attribute("aria-current") == "page"
    # Every form control has an accessible label.
    unlabeled = browser.execute_script(
        """return [...document.querySelectorAll('input, select')].filter(e =>
             e.type !== 'hidden' && !(e.labels && e.labels.length) && !e.getAttribute('aria-label')
           ).map(e => e.id);""")
    assert unlabeled == []
    # Job states carry a word and a symbol, not colour alone.
    el(browser, "nav-jobs").click()
    wait_for(lambda: el(browser, "view-jobs").is_displayed(), "the jobs view")
    states = browser.execute_script(
        """return [...document.querySelectorAll('#jobs-body .state')].map(e =>
             [e.textContent, getComputedStyle(e, '::before').content]);""")
    if "scan_job_id" in state:
        wait_for(lambda: len(browser.find_elements("css selector", "#jobs-body .state")) >= 2, "the job list")
        states = browser.execute_script(
            """return [...document.querySelectorAll('#jobs-body .state')].map(e =>
                 [e.textContent, getComputedStyle(e, '::before').content]);""")
        assert len(states) >= 2
    for word, symbol in states:
        assert word in ("queued", "running", "paused", "succeeded", "failed", "cancelled")
        assert symbol not in ("none", "normal", "")
    shot(browser, screenshots, "jobs-view")


def test_plan_form_offers_exactly_the_servers_kinds_and_parameters(browser, server, api, screenshots):
    """The form is built from GET /api/plans/kinds (which the API tests hold equal to the
    OpenAPI request schema and to `fpscan plan`'s flags): every kind, every parameter."""
    listed = api.get("/api/plans/kinds").json()
    want = {k["kind"]: [f["name"] for f in k["fields"]] for k in listed}
    assert "equispaced" in want
    # the oracle first, while the page sends no previews of its own (plan requests queue)
    expected = api.post("/api/plans/preview", json={
        "kind": "equispaced", "lattice": {"n_x": 64, "n_y": 64, "pitch": 60e-6}, "params": {"interval": 3},
        "acquisition": {"n_t": 256, "dt": 8e-9, "prf": 50}}).json()
    assert "points" in expected, expected
    browser.get(server + "/#/plan")
    # previews need the token: keep it for the session, as the tests before this one left it
    browser.execute_script("sessionStorage.setItem('fpscan.token', arguments[0])", TOKEN)
    browser.refresh()
    wait_for(lambda: len(browser.execute_script(
        "return document.getElementById('mask-kind').options")) == len(want), "the mask kinds")
    offered = browser.execute_script(
        "return [...document.getElementById('mask-kind').options].map(o => o.value)")
    assert offered == list(want)
    for kind in want:
        choose(browser, "mask-kind", kind)
        wait_for(lambda k=kind: browser.execute_script(
            "return [...document.querySelectorAll('#mask-params [name]')].map(e => e.name)") == want[k], f"the {kind} parameters")
    choose(browser, "mask-kind", "equispaced")
    set_value(browser, "mask-interval", 3)
    set_value(browser, "lat-nx", 64)
    set_value(browser, "lat-ny", 64)
    set_value(browser, "lat-pitch", 60)
    set_value(browser, "acq-nt", 256)
    set_value(browser, "acq-dt", 8)
    wait_for(lambda: text(browser, "plan-points").split()[0] == str(expected["points"]),
             "the equispaced preview's point count")
    shot(browser, screenshots, "plan-view-equispaced")
