"""What a browser makes of the server's headers, in a real headless Chromium that can reach
nothing but this machine (every other host goes to a proxy on a closed loopback port):

- ``/docs`` shows Swagger UI with every operation of the schema, from the server's own files;
- a page of another origin (a second loopback server, another port) that frames the web page
  or ``/docs`` gets nothing: Chromium refuses the frames (``frame-ancestors 'none'``);
- the web page works end to end under its Content-Security-Policy (signed in from the address
  ``fpscan serve`` prints with the token it made, a plan previewed, a file uploaded and its
  reconstruction's pictures shown), without one violation of the policy.

Oracles: the browser's own records (Chrome DevTools Protocol frame tree, the network requests
of its performance log, every ``securitypolicyviolation`` event and the console), the schema's
operations counted from ``/openapi.json`` with httpx, the server's log line.
"""
from __future__ import annotations

import http.server
import io
import json
import re
import secrets
import threading

import pytest

from fpscan.clients.processes import Process, clean_env, fpscan_argv, free_port, start_service
from tests.waits import HANG_S
from tests.web.web_e2e_support import (
    SCREENSHOTS,
    has_subcommand,
    open_page,
    preview_settled,
    wait_for,
)

httpx = pytest.importorskip("httpx")

pytestmark = [pytest.mark.timeout(600), pytest.mark.long(60)]

TOKEN = secrets.token_urlsafe(32)

#: collects every CSP violation of every document the browser opens (Chrome DevTools Protocol
#: ``Page.addScriptToEvaluateOnNewDocument``: it runs before the page's own scripts)
VIOLATIONS_SCRIPT = ("window.__violations = [];"
                     "document.addEventListener('securitypolicyviolation', (e) => window.__violations.push("
                     "e.effectiveDirective + ' ' + e.blockedURI));")


@pytest.fixture(scope="module")
def browser(start_chromium):
    """Headless Chromium (this module's own: other hosts unreachable, the network recorded):
    every request to a host other than loopback goes to a proxy on a closed port and fails."""
    drv = start_chromium(extra_args=[f"--proxy-server=http://127.0.0.1:{free_port()}",  # nothing listens there
                                     "--proxy-bypass-list=127.0.0.1"],  # loopback alone goes direct
                         logs=("browser", "performance"))
    drv.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": VIOLATIONS_SCRIPT})
    return drv


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    if not has_subcommand("serve"):
        pytest.skip("this build has no `fpscan serve`")
    data = tmp_path_factory.mktemp("policy")
    srv = start_service(data / "data", token=TOKEN, env={"FPSCAN_WARM_UP": "false"}, log_path=data / "serve.log",
                        timeout=HANG_S)
    yield srv
    srv.stop()


def requested_urls(browser) -> list[str]:
    """Every URL the browser asked for since the last call (its performance log)."""
    out = []
    for entry in browser.get_log("performance"):
        message = json.loads(entry["message"])["message"]
        if message["method"] == "Network.requestWillBeSent":
            out.append(message["params"]["request"]["url"])
    return out


def policy_messages(browser) -> list[str]:
    """The console's lines about the Content Security Policy since the last call."""
    return [e["message"] for e in browser.get_log("browser") if "Content Security Policy" in e["message"]]


def shot(browser, name: str) -> None:
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    browser.save_screenshot(str(SCREENSHOTS / f"{name}.png"))


def test_docs_shows_every_operation_with_no_other_host_reachable(browser, server):
    schema = httpx.get(server.url + "/openapi.json", timeout=30).json()
    operations = {f"{method.upper()} {path}" for path, item in schema["paths"].items() for method in item
                  if method in ("get", "put", "post", "delete", "patch", "head", "options")}
    assert len(operations) > 20
    requested_urls(browser), policy_messages(browser)  # this test's records only
    open_page(browser, server.url + "/docs")
    wait_for(lambda: browser.execute_script("return document.readyState") == "complete", "the page's scripts")
    assert browser.execute_script("return typeof SwaggerUIBundle") == "function", "Swagger UI's script did not load"
    shown = ("return [...document.querySelectorAll('.opblock')].map((b) =>"
             " b.querySelector('.opblock-summary-method').textContent + ' '"
             " + b.querySelector('.opblock-summary-path').dataset.path)")
    wait_for(lambda: set(browser.execute_script(shown)) == operations, f"the {len(operations)} operations of the schema")
    shot(browser, "docs-offline")
    origin = server.url + "/"
    foreign = [u for u in requested_urls(browser) if not u.startswith((origin, "data:", "blob:"))]
    assert not foreign, foreign
    assert browser.execute_script("return window.__violations") == []
    assert policy_messages(browser) == []


class _FramingPages(http.server.BaseHTTPRequestHandler):
    """Another origin's site: ``/`` frames the fpscan server's page and ``/docs`` and, as a
    control, a page of its own (``/inner``); each frame counts its load event."""

    target = ""

    def do_GET(self):
        if self.path == "/inner":
            body = b"<!doctype html><title>inner</title><p id=inner>framed</p>"
        else:
            frames = "".join(f'<iframe name="{name}" src="{src}" onload="window.loads = (window.loads || 0) + 1">'
                             "</iframe>" for name, src in (("page", self.target + "/#/jobs"),
                                                          ("docs", self.target + "/docs"), ("own", "/inner")))
            body = f"<!doctype html><title>another site</title>{frames}".encode()
        self.send_response(200)
        self.send_header("Content-Type", "text/html")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args):
        pass


def _frames(tree: dict) -> dict[str, dict]:
    return {child["frame"].get("name", ""): child["frame"] for child in tree["frameTree"].get("childFrames", [])}


def test_a_page_of_another_origin_cannot_frame_the_page_or_the_docs(browser, server):
    handler = type("Pages", (_FramingPages,), {"target": server.url})
    site = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=site.serve_forever, daemon=True).start()
    try:
        other = f"http://127.0.0.1:{site.server_address[1]}"
        assert other != server.url
        policy_messages(browser)
        open_page(browser, other + "/")
        wait_for(lambda: browser.execute_script("return window.loads") == 3, "the three frames' load events")
        frames = _frames(browser.execute_cdp_cmd("Page.getFrameTree", {}))
        assert frames["own"]["url"] == other + "/inner", frames["own"]  # framing works here: the control
        for name, src in (("page", server.url + "/#/jobs"), ("docs", server.url + "/docs")):
            assert frames[name]["url"].startswith("chrome-error:"), (name, frames[name])
            assert frames[name].get("unreachableUrl") == src, (name, frames[name])
        refusals = [m for m in policy_messages(browser) if "frame-ancestors 'none'" in m]
        assert len(refusals) == 2, refusals
        shot(browser, "framed-by-another-origin")
    finally:
        site.shutdown()
        site.server_close()


def test_the_page_signs_in_from_the_printed_address_and_runs_under_its_policy(browser, tmp_path):
    """``fpscan serve`` with no token: the address it prints opens the page signed in (no
    login view; the token gone from the address bar), and the page plans, uploads, reconstructs
    and shows the result's pictures (fetched with the token, shown from ``blob:`` URLs) without
    a violation of its policy."""
    np = pytest.importorskip("numpy")
    if not has_subcommand("serve"):
        pytest.skip("this build has no `fpscan serve`")
    port = free_port()
    log = tmp_path / "serve.log"
    proc = Process(fpscan_argv("serve", "--port", str(port)), log_path=log,
                   env=clean_env(FPSCAN_DATA_DIR=str(tmp_path / "data"), FPSCAN_WARM_UP="false"))
    try:
        def started():
            assert proc.poll() is None, proc.log_tail()
            try:
                httpx.get(f"http://127.0.0.1:{port}/api/auth", timeout=5)
            except httpx.TransportError:
                return False
            return True

        wait_for(started, "the server")
        printed = re.search(r"open (http://127\.0\.0\.1:\d+/#token=(\S+)) ;", log.read_text(errors="replace"))
        assert printed, proc.log_tail()
        address, token = printed.groups()
        requested_urls(browser), policy_messages(browser)
        open_page(browser, address)
        wait_for(lambda: browser.execute_script("return document.body.dataset.authChecked || ''"), "the sign-in check")
        assert browser.execute_script("return document.body.dataset.authChecked") == "open"
        assert browser.execute_script("return document.body.dataset.tokenPrompts || '0'") == "0"
        assert browser.execute_script("return sessionStorage.getItem('fpscan.token')") == token
        assert browser.current_url == f"http://127.0.0.1:{port}/#/plan"  # replaced: not in the history either
        wait_for(lambda: preview_settled(browser), "the plan preview")  # a data: picture

        path = tmp_path / "tiny.npy"
        buf = io.BytesIO()
        np.save(buf, np.random.default_rng(5).standard_normal((64, 8, 8)).astype(np.float32))
        path.write_bytes(buf.getvalue())
        browser.find_element("id", "nav-jobs").click()
        browser.find_element("css selector", "#upload-panel summary").click()
        browser.find_element("id", "upload-file").send_keys(str(path))
        browser.find_element("id", "upload-dt").send_keys("20")
        browser.find_element("id", "upload-dx").send_keys("100")
        browser.find_element("id", "upload-start").click()
        wait_for(lambda: browser.execute_script(
            "return document.getElementById('result-state').textContent.trim()") == "succeeded",
            "the upload's reconstruction", 0.3)
        wait_for(lambda: browser.execute_script(
            "const i = document.getElementById('result-mip-xy'); return i.complete && i.naturalWidth > 0"
            " && i.src.startsWith('blob:')"), "the xy MIP, fetched with the token")
        shot(browser, "page-under-policy")
        assert browser.execute_script("return window.__violations") == []
        assert policy_messages(browser) == []
        origin = f"http://127.0.0.1:{port}/"
        foreign = [u for u in requested_urls(browser) if not u.startswith((origin, "data:", "blob:"))]
        assert not foreign, foreign
    finally:
        proc.stop()
