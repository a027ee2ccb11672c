"""What a browser and a stranger get from a real ``fpscan serve`` on 127.0.0.1: the headers a
browser obeys on every answer (no framing by another site, scripts from the server only), an API
reference page that fetches nothing from elsewhere, wrong tokens throttled per client address,
weak tokens refused at start, and a token made and printed when none is given.

Oracles: the raw HTTP answers (status, headers, bodies) of real servers, from two loopback
addresses (127.0.0.1 and 127.0.0.2: two clients of different addresses); the server's exit
status and its one line of stderr; the HTML of the reference pages parsed with the standard
library's ``html.parser``. The pages in a real browser: tests/web/test_web_policy.py.
"""
from __future__ import annotations

import re
import secrets
import subprocess
import time
from html.parser import HTMLParser

import httpx
import pytest

from fpscan.clients.processes import Process, clean_env, fpscan_argv, free_port, start_service
from fpscan.service.api.access import FREE_FAILURES
from fpscan.service.settings import MIN_TOKEN_BITS, token_entropy_bits
from tests.clients.clients_servers import has_command
from tests.waits import HANG_S

pytestmark = [pytest.mark.skipif(not has_command("serve"), reason="`fpscan serve` not available"),
              pytest.mark.long(30)]

#: a token as the README makes it: 32 random bytes, base64url
TOKEN = secrets.token_urlsafe(32)


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """``fpscan serve`` with the web page and a strong token (its default rules: no weak token
    allowed)."""
    data = tmp_path_factory.mktemp("policy") / "data"
    srv = start_service(data, token=TOKEN, env={"FPSCAN_WARM_UP": "false"}, timeout=HANG_S)
    yield srv
    srv.stop()


class _Refs(HTMLParser):
    """The URLs a page loads (``src`` and ``href`` of every element) and its inline scripts."""

    def __init__(self) -> None:
        super().__init__()
        self.urls: list[str] = []
        self.inline_scripts = 0
        self._in_script = False

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        self.urls += [attrs[k] for k in ("src", "href") if attrs.get(k)]
        self._in_script = tag == "script" and not attrs.get("src")

    def handle_data(self, data):
        if self._in_script and data.strip():
            self.inline_scripts += 1

    def handle_endtag(self, tag):
        self._in_script = False


def test_every_answer_forbids_framing_and_foreign_scripts(server):
    """The page, its static files, the reference page and its files, the API (a refusal
    too) all carry ``X-Frame-Options: DENY`` and a CSP with ``frame-ancestors 'none'`` and
    scripts from the server only (OWASP Clickjacking Defense Cheat Sheet)."""
    auth = {"Authorization": f"Bearer {TOKEN}"}
    paths = [("/", {}), ("/index.html", {}), ("/app.js", {}), ("/style.css", {}), ("/docs", {}),
             ("/docs/assets/swagger-ui-bundle.js", {}), ("/docs/assets/swagger-init.js", {}), ("/openapi.json", {}),
             ("/api/auth", {}), ("/api/jobs", auth), ("/api/jobs", {})]
    with httpx.Client(base_url=server.url, timeout=30) as c:
        for path, headers in paths:
            r = c.get(path, headers=headers)
            assert r.status_code == (401 if path == "/api/jobs" and not headers else 200), (path, r.status_code)
            assert r.headers.get("x-frame-options") == "DENY", (path, dict(r.headers))
            policy = {d.split()[0]: d.split()[1:] for d in r.headers.get("content-security-policy", "").split(";")
                      if d.strip()}
            assert policy.get("frame-ancestors") == ["'none'"], (path, policy)
            assert policy.get("script-src") == ["'self'"], (path, policy)
            assert r.headers.get("x-content-type-options") == "nosniff", path


def test_the_reference_page_loads_only_the_servers_own_files(server):
    """``/docs`` names no other host (no CDN: nothing fetched at run time) and holds no inline
    script (the policy forbids it); every file it names is served. FastAPI's ReDoc page (a CDN's
    script) is gone."""
    with httpx.Client(base_url=server.url, timeout=30) as c:
        html = c.get("/docs").text
        refs = _Refs()
        refs.feed(html)
        assert len(refs.urls) == 4, refs.urls  # icon, style, Swagger UI, its start
        assert not [u for u in refs.urls if "//" in u or ":" in u], refs.urls
        assert refs.inline_scripts == 0, html
        for url in refs.urls:
            r = c.get(url)
            assert r.status_code == 200 and len(r.content) > 100, (url, r.status_code)
        bundle = c.get("/docs/assets/swagger-ui-bundle.js").text
        assert "SwaggerUIBundle" in bundle and "/openapi.json" in c.get("/docs/assets/swagger-init.js").text
        assert c.get("/redoc").status_code == 404


def _get(url: str, token: str | None, source: str = "127.0.0.1", path: str = "/api/jobs") -> httpx.Response:
    """One request from the loopback address ``source`` (127.0.0.0/8 is all this machine)."""
    transport = httpx.HTTPTransport(local_address=source)
    headers = {"Authorization": f"Bearer {token}"} if token is not None else {}
    with httpx.Client(transport=transport, timeout=30) as c:
        return c.get(url + path, headers=headers)


def test_wrong_tokens_make_their_address_wait_and_no_other(server):
    """After FREE_FAILURES wrong tokens from one address its next wrong one starts a wait:
    meanwhile a wrong token of that address is answered 429 with ``Retry-After`` (held until
    its wait is over, and counted: the wait grows), while the right token is answered at once
    from every address, the waiting one included (GET /api/auth too). The same wrong token
    that is refused with 429 here was 401 before: nothing but the count of failures changed."""
    url = server.url
    wrong = secrets.token_urlsafe(32)
    for i in range(FREE_FAILURES + 1):
        r = _get(url, wrong)
        assert r.status_code == 401 and r.json()["detail"] == "invalid bearer token", (i, r.status_code, r.text)
    refused = _get(url, wrong)
    assert refused.status_code == 429, (refused.status_code, refused.text)
    assert "too many wrong tokens" in refused.json()["detail"]
    first_wait = int(refused.headers["retry-after"])
    assert first_wait >= 1
    # the right token from the waiting address: answered, not throttled
    assert _get(url, TOKEN).status_code == 200, "the right token is answered from the waiting address too"
    assert _get(url, TOKEN, path="/api/auth").json() == {"token_required": True, "authenticated": True}
    assert _get(url, None, path="/api/auth").json() == {"token_required": True, "authenticated": False}
    assert _get(url, None).status_code == 401  # no token sent: nothing to throttle
    # a further wrong guess from the waiting address is still refused, and its wait has grown
    # (each wrong token counts, so the waits only grow: a guess that came after its wait was over
    # is a 401 and starts the next, longer one, whatever the machine's load)
    for _ in range(4):
        again = _get(url, wrong)
        if again.status_code == 429:
            break
        assert again.status_code == 401, again.text
    assert again.status_code == 429 and int(again.headers["retry-after"]) > first_wait, again.headers
    # another address: the right token at once, and its own wrong token is a plain 401
    assert _get(url, TOKEN, source="127.0.0.2").status_code == 200
    assert _get(url, wrong, source="127.0.0.2").status_code == 401
    assert _get(url, TOKEN, source="127.0.0.2", path="/api/health").status_code == 200  # health's lane too
    assert _get(url, TOKEN).status_code == 200


def _serve(tmp_path, *argv: str, **env: str) -> subprocess.CompletedProcess:
    """``fpscan serve`` on a free port, in the foreground, until it exits by itself."""
    return subprocess.run([*fpscan_argv("serve", "--port", str(free_port()), "--no-web"), *argv],
                          env=clean_env(FPSCAN_DATA_DIR=str(tmp_path / "data"), FPSCAN_WARM_UP="false", **env),
                          capture_output=True, text=True, timeout=HANG_S)


@pytest.mark.parametrize("argv, env", [
    (["--token", "change-me"], {}),
    ([], {"FPSCAN_TOKEN": "change-me-change-me-change-me-change-me"}),
    ([], {"FPSCAN_TOKEN": "0123456789"}),
    (["--token", "correct-horse-battery"], {}),
])
def test_a_weak_token_is_refused_with_one_line(argv, env, tmp_path):
    """A token of under 128 bits of estimated entropy stops the start, in one line that says
    how to make a good one and how to start with it anyway."""
    token = argv[1] if argv else env["FPSCAN_TOKEN"]
    assert token_entropy_bits(token) < MIN_TOKEN_BITS
    p = _serve(tmp_path, *argv, **env)
    assert p.returncode == 2, (p.returncode, p.stderr[-2000:])
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "weak" in lines[0] and "secrets.token_urlsafe(32)" in lines[0] \
        and "--allow-weak-token" in lines[0], p.stderr
    assert token not in lines[0]  # the token itself is not echoed to a log
    assert not (tmp_path / "data" / "jobs.sqlite").exists()


def test_a_weak_token_starts_when_allowed(tmp_path):
    srv = start_service(tmp_path / "data", token="change-me", web=False,
                        env={"FPSCAN_WARM_UP": "false", "FPSCAN_ALLOW_WEAK_TOKEN": "true"}, timeout=HANG_S)
    try:
        assert _get(srv.url, "change-me").status_code == 200
    finally:
        srv.stop()


def test_a_token_file_is_held_to_the_same_rule(tmp_path):
    (tmp_path / "token").write_text("change-me\n")
    p = _serve(tmp_path, FPSCAN_TOKEN_FILE=str(tmp_path / "token"))
    assert p.returncode == 2 and "weak" in p.stderr and len(p.stderr.strip().splitlines()) == 1, p.stderr


def test_without_a_token_one_is_made_printed_and_required(tmp_path):
    """No token given: the server makes one (as Jupyter Server does), prints it with the web
    page's address (in the fragment, which no browser sends), and needs it."""
    port = free_port()
    log = tmp_path / "serve.log"
    proc = Process(fpscan_argv("serve", "--port", str(port)), log_path=log,
                   env=clean_env(FPSCAN_DATA_DIR=str(tmp_path / "data"), FPSCAN_WARM_UP="false"))
    try:
        end = time.monotonic() + HANG_S
        found = None
        while found is None and proc.poll() is None and time.monotonic() < end:
            found = re.search(r"open (http://127\.0\.0\.1:(\d+)/#token=([A-Za-z0-9_-]+)) ; clients: "
                              r"export FPSCAN_TOKEN=([A-Za-z0-9_-]+)", log.read_text(errors="replace"))
            if found is None:
                time.sleep(0.2)
        assert found is not None, proc.log_tail()
        _, shown_port, token, exported = found.groups()
        assert int(shown_port) == port and token == exported
        assert token_entropy_bits(token) >= MIN_TOKEN_BITS and len(token) == 43  # secrets.token_urlsafe(32)
        url = f"http://127.0.0.1:{port}"
        while True:  # until it answers
            try:
                r = _get(url, token)
                break
            except httpx.TransportError:
                assert proc.poll() is None and time.monotonic() < end, proc.log_tail()
                time.sleep(0.2)
        assert r.status_code == 200, r.text
        assert _get(url, None).status_code == 401
        assert _get(url, None, path="/api/auth").json() == {"token_required": True, "authenticated": False}
    finally:
        proc.stop()


def test_no_token_is_an_explicit_choice_on_loopback_only(tmp_path):
    """``--no-token`` serves without a token (loopback only); with a token it is refused."""
    srv = start_service(tmp_path / "data", token=None, web=False, env={"FPSCAN_WARM_UP": "false"}, timeout=HANG_S)
    try:
        assert _get(srv.url, None).status_code == 200
        assert _get(srv.url, None, path="/api/auth").json()["token_required"] is False
    finally:
        srv.stop()
    p = _serve(tmp_path, "--no-token", "--token", TOKEN)
    assert p.returncode == 2 and "no_token" in p.stderr, p.stderr
    p = _serve(tmp_path, "--no-token", "--host", "0.0.0.0")
    assert p.returncode == 2 and "beyond loopback" in p.stderr, p.stderr
