"""The result view read at a glance, in a real headless Chromium against a real
``fpscan serve`` (no token): parameters with SI prefixes and units instead of raw floats,
MIPs that enlarge on click to their full size with readable axis text, and no "–"
placeholders for what does not apply to a job (an NER job's or an unmixing job's points).

Oracles: the job's own JSON from the server (httpx), the rendered element sizes and
visibility from the browser's DOM. Screenshots go to test-artifacts/screenshots/.
"""
from __future__ import annotations

import re

import pytest

from tests.web.test_web_page import el, shot, start_server, text
from tests.web.web_e2e_support import wait_for

httpx = pytest.importorskip("httpx")
np = pytest.importorskip("numpy")


#: a number as text (a table cell holds one or a list of them, perhaps with a unit)
NUMBER = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


def raw_numbers(value: str) -> list[str]:
    """The numbers in ``value`` printed raw: more than 6 digits before any exponent, as
    binary noise (0.00009999999999999999, 1.2000000000000002e-8) or a byte count in bytes
    (161695210) is."""
    tokens = value.replace(",", " ").split()
    return [t for t in tokens if NUMBER.match(t) and len(re.sub(r"\D", "", t.lower().split("e")[0])) > 6]


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    data = tmp_path_factory.mktemp("serve-readable")
    srv = start_server(data, {}, None)
    try:
        yield srv.url
    finally:
        srv.stop()


def _upload(base: str, path, dt: float, dx: float) -> str:
    with open(path, "rb") as fh:
        r = httpx.post(f"{base}/api/datasets", data={"format": "npy", "dt": repr(dt), "dx": repr(dx)},
                       files={"file": (path.name, fh, "application/octet-stream")}, timeout=60)
    assert r.status_code in (200, 201), r.text
    return r.json()["dataset_id"]


def _open_finished(browser, base: str, job_id: str) -> dict:
    browser.get(f"{base}/#/jobs/{job_id}")
    wait_for(lambda: el(browser, "result-id").get_attribute("title") == job_id
             and text(browser, "result-state") in ("succeeded", "failed"), "the job to finish", 0.3)
    job = httpx.get(f"{base}/api/jobs/{job_id}", timeout=30).json()
    assert text(browser, "result-state") == "succeeded", job
    return job


def _param_rows(browser) -> dict[str, str]:
    return browser.execute_script(
        "return Object.fromEntries([...document.querySelectorAll('#result-params tr')]"
        ".map(tr => [tr.cells[0].textContent, tr.cells[1].textContent]))")


def _shown(browser, element_id: str) -> bool:
    return el(browser, element_id).is_displayed()


def test_parameters_with_units_and_enlarged_mip(browser, base, screenshots, tmp_path):
    """An NER job on data whose spacings carry binary noise (dx 0.1 mm × 0.9999999999999999,
    dt 1.2000000000000002e-8 s): the table says 100 µm, 12 ns, 1500 m/s and the memory in
    KiB/MiB; no raw float anywhere in it. A click on the xy MIP opens it in the picture
    dialog, wider than the thumbnail (its full 600 px); NER has no sensor points to count,
    so "Points used" is not shown (no placeholder)."""
    path = tmp_path / "grid.npy"
    np.save(path, np.random.default_rng(5).standard_normal((96, 12, 16)).astype(np.float32))
    dx, dt = 0.1e-3 * 0.9999999999999999, 1.2000000000000002e-8
    ds = _upload(base, path, dt, dx)
    r = httpx.post(f"{base}/api/reconstructions", json={"dataset_id": ds, "method": "ner"}, timeout=30)
    assert r.status_code == 202, r.text
    job = _open_finished(browser, base, r.json()["id"])
    assert job["params"]["shape"]["dx"] != 1e-4  # the noise is really there on the wire

    rows = wait_for(lambda: (lambda r: r if "used.dx" in r else None)(_param_rows(browser)), "the parameters")
    print(rows)
    assert rows["shape.dx"] == "100 µm" and rows["used.dx"] == "100 µm" and rows["used.dy"] == "100 µm", rows
    assert rows["shape.dt"] == "12 ns" and rows["used.dt"] == "12 ns", rows
    assert rows["used.dz"] == "100 µm" and rows["used.sound_speed"] == "1500 m/s", rows  # dz = the pitch, its noise too
    mem = job["params"]["memory_estimate"]
    unit, size = ("MiB", mem / 2**20) if mem >= 2**20 else ("KiB", mem / 2**10)
    assert rows["memory_estimate"] == f"{float(f'{size:.3g}'):g} {unit}", (rows["memory_estimate"], mem)
    raw = {k: v for k, v in rows.items() if raw_numbers(v)}
    assert not raw, raw
    assert not any(v in ("–", "null", "undefined", "") for v in rows.values()), rows
    # what does not apply is not shown, and no placeholder is
    assert not _shown(browser, "result-points") and _shown(browser, "result-shape")
    stats = browser.execute_script(
        "return [...document.querySelectorAll('#result-recon dl.stats')].filter(d => d.offsetParent)"
        ".map(d => d.innerText).join('\\n')")
    assert "Points used" not in stats and "–" not in stats, stats
    shot(browser, screenshots, "readable-ner-parameters")

    thumb = el(browser, "result-mip-xy")
    wait_for(lambda: browser.execute_script("return arguments[0].complete && arguments[0].naturalWidth", thumb), "the xy MIP")
    thumb_w = thumb.rect["width"]
    assert not browser.execute_script("return document.getElementById('picture-dialog').open")
    thumb.click()
    wait_for(lambda: browser.execute_script("return document.getElementById('picture-dialog').open"),
             "the picture dialog")
    big = el(browser, "picture-dialog-img")
    wait_for(lambda: browser.execute_script("return arguments[0].complete && arguments[0].naturalWidth", big), "the enlarged MIP")
    natural = browser.execute_script("return arguments[0].naturalWidth", big)
    assert big.is_displayed() and big.rect["width"] > 1.5 * thumb_w, (big.rect, thumb_w)
    assert big.rect["width"] == pytest.approx(natural, abs=1)  # full size: one image pixel per CSS pixel
    assert "xy" in text(browser, "picture-dialog-caption")
    shot(browser, screenshots, "readable-mip-enlarged")
    el(browser, "picture-dialog-close").click()
    wait_for(lambda: not browser.execute_script("return document.getElementById('picture-dialog').open"),
             "the picture dialog to close")


def test_unmix_job_hides_what_does_not_apply(browser, base, screenshots, tmp_path):
    """An unmixing job (two wavelengths, fixed c): its wavelengths in nm, no "Points used"
    and no autofocus panel (neither applies), no "–" in its statistics."""
    n, dx, dt, n_t = 16, 100e-6, 20e-9, 96
    ids = []
    for k in range(2):
        path = tmp_path / f"w{k}.npy"
        np.save(path, np.random.default_rng(10 + k).standard_normal((n_t, n, n)).astype(np.float32))
        ids.append(_upload(base, path, dt, dx))
    r = httpx.post(f"{base}/api/reconstructions", timeout=30, json={
        "dataset_ids": ids, "wavelengths": [750e-9, 850e-9], "method": "ner", "unmix": {}})
    assert r.status_code == 202, r.text
    _open_finished(browser, base, r.json()["id"])
    wait_for(lambda: _shown(browser, "result-unmix"), "the unmixing panel")
    assert text(browser, "result-unmix-wavelengths") == "750 nm, 850 nm"
    assert not _shown(browser, "result-points") and not _shown(browser, "result-autofocus")
    stats = browser.execute_script(
        "return [...document.querySelectorAll('#result-recon dl.stats')].filter(d => d.offsetParent)"
        ".map(d => d.innerText).join('\\n')")
    assert "Points used" not in stats and "–" not in stats and "Volume shape" in stats, stats
    rows = _param_rows(browser)
    assert rows.get("wavelengths") == "750 nm, 850 nm", rows
    raw = {k: v for k, v in rows.items() if raw_numbers(v)}
    assert not raw, raw
    shot(browser, screenshots, "readable-unmix-result")
