"""The web page's disk-use section in a real headless Chromium against a real
``fpscan serve`` (no token: a loopback-only server): it shows the data folder's disk use by
part with the uploaded datasets' size as the server counts it, lists the datasets, and its
delete button removes one (files gone, the server's list and disk use agree)."""
from __future__ import annotations

import io

import pytest

from tests.web.web_e2e_support import has_subcommand, wait_for

httpx = pytest.importorskip("httpx")
np = pytest.importorskip("numpy")



def _text(browser, css: str) -> str:
    return browser.execute_script("const e = document.querySelector(arguments[0]); return e ? e.textContent : null",
                                  css) or ""


def _npy(seed: int, n_t: int) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(seed).standard_normal((n_t, 16, 16)).astype(np.float32))
    return buf.getvalue()


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    if not has_subcommand("serve"):
        pytest.skip("this build has no `fpscan serve`")
    from fpscan.clients.processes import start_service
    from tests.clients.clients_servers import QUIET

    data = tmp_path_factory.mktemp("storage")
    srv = start_service(data, token=None, devices={}, env=QUIET, log_path=data / "serve.log", timeout=60)
    try:
        yield srv.url, data
    finally:
        srv.stop()


def test_disk_use_panel_shows_dataset_sizes_and_delete_removes_one(browser, base, screenshots):
    url, data = base
    ids = []
    for seed, n_t in ((1, 64), (2, 256)):
        r = httpx.post(f"{url}/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
                       files={"file": (f"web-{seed}.npy", _npy(seed, n_t), "application/octet-stream")}, timeout=60)
        assert r.status_code == 201, r.text
        ids.append(r.json()["dataset_id"])
    listed = {d["dataset_id"]: d for d in httpx.get(f"{url}/api/datasets", timeout=10).json()}
    disk = httpx.get(f"{url}/api/health", timeout=10).json()["disk"]
    # the server's count is what is on disk
    on_disk = sum(p.stat().st_size for p in (data / "datasets").rglob("*") if p.is_file())
    assert disk["datasets_bytes"] == on_disk == sum(d["size_bytes"] for d in listed.values())

    browser.get(url + "/#/jobs")
    wait_for(lambda: browser.execute_script(
        "return document.querySelectorAll('#storage-datasets tbody tr').length") == 2, "the two datasets listed")
    row = "#storage-parts tr[data-part='datasets']"
    assert browser.execute_script(f"return document.querySelector(\"{row}\").dataset.bytes") == str(on_disk)
    shown = _text(browser, f"{row} td")
    assert shown.endswith("KiB") and abs(float(shown.split()[0]) * 1024 - on_disk) / on_disk < 0.01, shown
    for did, d in listed.items():
        tr = f"#storage-datasets tr[data-dataset-id='{did}']"
        assert d["name"] in _text(browser, tr), _text(browser, tr)
        size = _text(browser, f"{tr} td:nth-child(4)")
        assert abs(float(size.split()[0]) * 1024 - d["size_bytes"]) / d["size_bytes"] < 0.01, size
    assert {"results", "scans", "free"} <= set(browser.execute_script(
        "return [...document.querySelectorAll('#storage-parts tr[data-part]')].map(r => r.dataset.part)"))

    browser.execute_script("document.getElementById('storage').scrollIntoView()")
    browser.save_screenshot(str(screenshots / "jobs-disk-use.png"))

    # delete the larger one with its button (the page asks first)
    victim = ids[1]
    browser.find_element("css selector", f"#storage-datasets tr[data-dataset-id='{victim}'] button").click()
    wait_for(lambda: browser.switch_to.alert, "the confirmation").accept()
    wait_for(lambda: browser.execute_script(
        "return document.querySelectorAll('#storage-datasets tbody tr').length") == 1, "the dataset removed")
    assert not (data / "datasets" / victim).exists()
    assert [d["dataset_id"] for d in httpx.get(f"{url}/api/datasets", timeout=10).json()] == [ids[0]]
    left = httpx.get(f"{url}/api/health", timeout=10).json()["disk"]["datasets_bytes"]
    assert left == listed[ids[0]]["size_bytes"]
    wait_for(lambda: browser.execute_script(f"return document.querySelector(\"{row}\").dataset.bytes") == str(left), "the disk use updated")
    assert "Deleted dataset" in _text(browser, "#storage-state")
