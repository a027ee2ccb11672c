"""The plan view on a busy server, in a real headless Chromium against a real
``fpscan serve``: a preview the server refuses with 429 (every plan-request slot taken,
as by the previews of earlier keystrokes on a loaded machine) is asked again when the
server says to (Retry-After), with the form's latest parameters and no new input, so the
page ends up showing the server's preview of what the form holds."""
from __future__ import annotations

import socket

import pytest

from tests.waits import HANG_S
from tests.web.web_e2e_support import has_subcommand, open_page, preview_settled, wait_for

httpx = pytest.importorskip("httpx")

#: the service's plan-request slots: 1 running + 8 waiting (fpscan.service.api.context.default_slots)
PLAN_SLOTS = 9


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    if not has_subcommand("serve"):
        pytest.skip("this build has no `fpscan serve`")
    from fpscan.clients.processes import start_service
    from tests.clients.clients_servers import QUIET

    data = tmp_path_factory.mktemp("busy")
    # stalled bodies keep their slots until the test lets them go (not until a body timeout)
    srv = start_service(data, token=None, devices={}, env={**QUIET, "FPSCAN_BODY_TIMEOUT_S": "600"},
                        log_path=data / "serve.log", timeout=HANG_S)
    try:
        yield srv.url, srv.port
    finally:
        srv.stop()


def _text(browser, element_id: str) -> str:
    return browser.execute_script("return document.getElementById(arguments[0]).textContent", element_id).strip()


def test_a_refused_preview_is_asked_again_once_the_server_has_room(browser, base, screenshots):
    from selenium.webdriver.common.keys import Keys

    url, port = base
    open_page(browser, url + "/#/plan")
    wait_for(lambda: preview_settled(browser), "the first preview")
    # every plan-request slot taken by a request whose body never comes
    head = (b"POST /api/plans/preview HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            b"Content-Length: 100000\r\n\r\n{")
    stalled = []
    try:
        for _ in range(PLAN_SLOTS):
            sock = socket.create_connection(("127.0.0.1", port), timeout=HANG_S)
            sock.sendall(head)
            stalled.append(sock)
        body = browser.execute_script("return planBody()")  # what the page sends
        wait_for(lambda: httpx.post(f"{url}/api/plans/preview", json=body, timeout=HANG_S).status_code == 429, "the server to refuse plan requests (slots full)")
        box = browser.find_element("id", "lat-nx")  # a new parameter: its preview is refused
        box.send_keys(Keys.CONTROL, "a")
        box.send_keys(Keys.DELETE)
        box.send_keys("33")
        wait_for(lambda: "too many plan requests" in _text(browser, "plan-preview-state"),
                 "the page to show the server's refusal")
        body = browser.execute_script("return planBody()")
        assert body["lattice"]["n_x"] == 33, body
    finally:
        for sock in stalled:  # the server has room again
            sock.close()
    # no new input: the page asks again by itself and shows the server's preview of the form
    oracle = wait_for(lambda: (r := httpx.post(f"{url}/api/plans/preview", json=body, timeout=HANG_S)).status_code
                      != 429 and r, "the server to have room")
    assert oracle.status_code == 200, oracle.text
    points = str(oracle.json()["points"])
    wait_for(lambda: preview_settled(browser) and _text(browser, "plan-points").split()[0] == points, f"the preview of {points} points")
    browser.save_screenshot(str(screenshots / "plan-view-after-busy.png"))
