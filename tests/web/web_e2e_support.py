"""Helpers of the web page's end-to-end tests (processes, ports, waits, the browser's
command line). A module of its own so both conftest.py and the tests import it by a
unique name."""
from __future__ import annotations

import time
from pathlib import Path

from tests.waits import HANG_S

REPO_ROOT = Path(__file__).resolve().parents[2]
SCREENSHOTS = REPO_ROOT / "test-artifacts" / "screenshots"

CHROMIUM_FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--window-size=1400,1100", "--disable-dev-shm-usage",
]


def wait_for(predicate, what: str, interval: float = 0.1):
    """Poll ``predicate`` until it returns a truthy value (the event ``what``); fail only
    after ``tests.waits.HANG_S`` s, a hang: a loaded machine makes a wait longer, never
    a failure."""
    timeout = HANG_S
    deadline = time.monotonic() + timeout
    last_exc = None
    while time.monotonic() < deadline:
        try:
            value = predicate()
            if value:
                return value
        except Exception as exc:  # reported below
            last_exc = exc
        time.sleep(interval)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}" + (f" (last error: {last_exc!r})" if last_exc else ""))


def open_page(browser, url: str) -> None:
    """Load ``url`` as a new document, even when the browser shows the same page at
    another ``#/`` route (a hash change alone would keep that page's state and timers)."""
    browser.get("about:blank")
    browser.get(url)


def preview_settled(browser) -> bool:
    """Whether the plan preview shows the form's parameters: no preview scheduled or in
    flight (the panel is not aria-busy) and the last one succeeded."""
    return bool(browser.execute_script(
        "return !document.querySelector('.preview-panel').hasAttribute('aria-busy')"
        " && document.getElementById('plan-preview-state').textContent.trim().startsWith('Preview up to date')"))


def has_subcommand(name: str) -> bool:
    """Whether this build has ``fpscan <name>`` (its module in ``fpscan.clients.cli``)."""
    import importlib.util

    return importlib.util.find_spec(f"fpscan.clients.cli.{name}") is not None
