"""Fixtures of the web page's end-to-end tests: a real headless Chromium (Debian's
``chromium`` + ``chromium-driver``, driven by Selenium) with a fresh profile.

Skips (with the reason) only where the browser or its driver cannot be found or started;
the setup step ``scripts/test-setup.d/chromium.sh`` installs them where it can.
"""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest

from tests.waits import HANG_S
from tests.web.web_e2e_support import CHROMIUM_FLAGS, SCREENSHOTS


def _browser_paths() -> tuple[str, str]:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver")
    if not chromium or not driver:
        pytest.skip("headless Chromium not available: install Debian's chromium and chromium-driver "
                    "(scripts/test-setup.d/chromium.sh does it when run as root)")
    return chromium, driver


@pytest.fixture(scope="session")
def screenshots() -> Path:
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    return SCREENSHOTS


@pytest.fixture(scope="module")
def download_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("downloads")


@pytest.fixture(scope="module")
def start_chromium():
    """A factory of headless Chromiums, each with a fresh profile, all quit at the module's end:
    ``start_chromium(download_dir=None, extra_args=(), logs=("browser",))`` starts one with
    ``CHROMIUM_FLAGS`` and the command-line arguments ``extra_args``, downloads going to
    ``download_dir`` (when given), keeping the WebDriver logs ``logs`` (``"browser"``: the
    console; ``"performance"``: the DevTools events). Skips where it cannot start."""
    webdriver = pytest.importorskip("selenium.webdriver", reason="selenium not installed (pip install -e '.[test]')")
    from selenium.webdriver.chrome.service import Service

    started: list[tuple[object, str]] = []

    def start(download_dir: Path | None = None, extra_args=(), logs=("browser",)):
        chromium, driver_path = _browser_paths()
        os.environ.setdefault("SE_OFFLINE", "true")  # never let Selenium Manager download anything
        profile = tempfile.mkdtemp(prefix="fpscan-chromium-")
        opts = webdriver.ChromeOptions()
        opts.binary_location = chromium
        for flag in [*CHROMIUM_FLAGS, *extra_args]:
            opts.add_argument(flag)
        opts.add_argument(f"--user-data-dir={profile}")
        if download_dir is not None:
            opts.add_experimental_option("prefs", {
                "download.default_directory": str(download_dir),
                "download.prompt_for_download": False,
                "safebrowsing.enabled": False,
            })
        opts.set_capability("goog:loggingPrefs", dict.fromkeys(logs, "ALL"))
        try:
            drv = webdriver.Chrome(options=opts, service=Service(executable_path=driver_path))
        except Exception as exc:  # the browser cannot start here
            shutil.rmtree(profile, ignore_errors=True)
            pytest.skip(f"headless Chromium could not start: {exc}")
        started.append((drv, profile))
        if download_dir is not None:
            try:
                drv.execute_cdp_cmd("Browser.setDownloadBehavior",
                                    {"behavior": "allow", "downloadPath": str(download_dir)})
            except Exception:  # older drivers: the prefs above do it
                pass
        drv.set_page_load_timeout(HANG_S)  # hang guards (tests.waits), not speed expectations
        drv.set_script_timeout(HANG_S)
        return drv

    yield start
    for drv, profile in started:
        try:
            drv.quit()  # type: ignore[attr-defined]
        finally:
            shutil.rmtree(profile, ignore_errors=True)


@pytest.fixture(scope="module")
def browser(start_chromium, download_dir):
    """A headless Chromium with a fresh profile, downloads going to ``download_dir``."""
    return start_chromium(download_dir=download_dir)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if report.when == "call":
        item.web_call_failed = report.failed


@pytest.fixture(autouse=True)
def _evidence_on_failure(request):
    """After a failed web test: a screenshot and the browser's console log in
    test-artifacts/screenshots/FAILED-<test>.* for the reviewer."""
    yield
    if not getattr(request.node, "web_call_failed", False) or "browser" not in request.fixturenames:
        return
    drv = request.getfixturevalue("browser")
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    stem = SCREENSHOTS / f"FAILED-{request.node.name}"
    try:
        drv.save_screenshot(str(stem.with_suffix(".png")))
        lines = [f"{e.get('level')} {e.get('message')}" for e in drv.get_log("browser")]
        stem.with_suffix(".log").write_text("\n".join(lines) + "\n")
    except Exception:  # evidence is best effort
        pass
