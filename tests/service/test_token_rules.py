"""What a browser and a stranger get from a real ``fpscan serve`` on 127.0.0.1: the headers a
browser obeys on every answer (no framing by another site, scripts from the server only), refusals
at the connection included, an API reference page that fetches nothing from elsewhere, wrong tokens
throttled per client address on every connection (one on probation beyond the address's connection
budget included), weak tokens refused at start, and a token made and printed when none is given.

Oracles: the raw HTTP answers (status, headers, bodies) of real servers, from several loopback
addresses (127.0.0.1 to 127.0.0.4: clients of different addresses), timed by the client's monotonic
clock against the ``Retry-After`` the server gave (the wait a wrong token owes); the server's exit
status and its one line of stderr; the HTML of the reference pages parsed with the standard
library's ``html.parser``. The pages in a real browser: tests/web/test_web_policy.py.
"""
from __future__ import annotations

import contextlib
import re
import secrets
import socket
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
    assert len(lines) == 1 and "weak" in lines[0] and "secrets.token_hex(32)" in lines[0] \
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
        assert token_entropy_bits(token) >= MIN_TOKEN_BITS and re.fullmatch(r"[0-9a-f]{64}", token)  # token_hex(32)
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
    # "--token=…": a token_urlsafe token starts with "-" one time in 64, which argparse would take for an option
    p = _serve(tmp_path, "--no-token", f"--token={TOKEN}")
    assert p.returncode == 2 and "no_token" in p.stderr, p.stderr
    p = _serve(tmp_path, "--no-token", "--host", "0.0.0.0")
    assert p.returncode == 2 and "beyond loopback" in p.stderr, p.stderr


def _ask(port: int, source: str, token: str | None, path: str = "/api/jobs") -> tuple[int, dict, bytes, float]:
    """One request on a new connection from the loopback address ``source`` (a raw socket:
    the server's own answer, refusals at the connection included); its status, headers (lower-case
    names), body and the client's monotonic time once the answer was read to its close."""
    auth = f"Authorization: Bearer {token}\r\n" if token is not None else ""
    with socket.create_connection(("127.0.0.1", port), timeout=HANG_S, source_address=(source, 0)) as s:
        s.sendall(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n{auth}Connection: close\r\n\r\n".encode())
        chunks = []
        while chunk := s.recv(65536):
            chunks.append(chunk)
        answered = time.monotonic()
    head, _, body = b"".join(chunks).partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    headers = {k.strip().lower(): v.strip() for k, _, v in (line.partition(":") for line in lines[1:])}
    return int(lines[0].split()[1]), headers, body, answered


@contextlib.contextmanager
def _holding_a_stranger_slot(port: int, source: str):
    """A connection of ``source`` that sends half a request head and holds it (a stranger's)."""
    with socket.create_connection(("127.0.0.1", port), timeout=HANG_S, source_address=(source, 0)) as s:
        s.sendall(b"GET /api/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        yield s


def _assert_browser_headers(headers: dict, what: object) -> None:
    assert headers.get("x-frame-options") == "DENY", (what, headers)
    assert "frame-ancestors 'none'" in headers.get("content-security-policy", ""), (what, headers)
    assert headers.get("x-content-type-options") == "nosniff", (what, headers)


def test_a_refusal_at_the_connection_carries_the_browser_headers(server):
    """A head over ``max_head_bytes`` is refused by the connection layer (431, before the app):
    that answer too forbids framing and foreign scripts."""
    port = int(server.url.rsplit(":", 1)[1])
    status, headers, body, _ = _ask(port, "127.0.0.1", "x" * 20000)
    assert status == 431, (status, body)
    _assert_browser_headers(headers, status)


@pytest.mark.waits
def test_a_wrong_token_on_probation_waits_like_any_other(tmp_path):
    """An address whose one stranger's connection is held (``connections_per_address`` 1) gets
    its next connections on probation. There a wrong token from a waiting address is answered
    429, held until the wait owed (the previous answer's ``Retry-After``) is over, as on any
    connection; never a quick 503 beside a 200 for the right token, which would tell a guesser
    right from wrong at once. The right token on probation is answered 200; a wrong token of an
    address that does not wait is refused (401), never served."""
    srv = start_service(tmp_path / "data", token=TOKEN, web=False, timeout=HANG_S,
                        env={"FPSCAN_WARM_UP": "false", "FPSCAN_CONNECTIONS_PER_ADDRESS": "1",
                             "FPSCAN_HEADER_TIMEOUT_S": "120"})
    port, source, wrong = srv.port, "127.0.0.3", secrets.token_urlsafe(32)
    try:
        for i in range(FREE_FAILURES + 1):  # the last one starts the address's first wait
            status, _, body, _ = _ask(port, source, wrong)
            assert status == 401, (i, status, body)
        with _holding_a_stranger_slot(port, source):
            status, headers, body, _ = _ask(port, source, None)  # the next connection is on probation
            assert status == 503 and b"without the token" in body, (status, body)
            _assert_browser_headers(headers, status)
            # wrong tokens on probation: 429 once the wait is over (401 if it was over before one
            # came: a loaded machine), each answer no sooner than the wait the previous one owed
            owed: tuple[float, int] | None = None  # (client time the previous was sent, its Retry-After)
            for _ in range(6):
                sent = time.monotonic()
                status, headers, body, answered = _ask(port, source, wrong)
                assert status in (401, 429), (status, body)
                if owed is not None:
                    assert answered - owed[0] >= owed[1] - 0.01, (answered - owed[0], owed[1])
                if status == 429:
                    if owed is not None:
                        break
                    owed = sent, int(headers["retry-after"])
            assert status == 429 and owed is not None, (status, body)
            status, _, body, _ = _ask(port, source, TOKEN)
            assert status == 200, (status, body)
        with _holding_a_stranger_slot(port, "127.0.0.4"):
            status, _, body, _ = _ask(port, "127.0.0.4", wrong, path="/api/auth")
            assert status == 401 and b"invalid bearer token" in body, (status, body)
    finally:
        srv.stop()
