"""No input reaches a 500: property tests (hypothesis) of every parser a request
reaches, beside the schema fuzzing of ``test_openapi_fuzz.py`` (schemathesis).

- The library's parsers, given hostile values (numbers with unit text and exponents up to
  ±10⁹, ``"(1,2"`` and ``"f4,f4,..."`` for a dtype, huge integers, lists, objects): the
  quantity parser (``fpscan.driver.units.parse_quantity``), every method's options model
  (``fpscan.service.recon.methods``) and the option check of the dispatch
  (``fpscan.service.pipeline.method_options``) answer a value or a ``ValueError``, never another
  exception.
- A real ``fpscan serve``, over one kept-alive connection: reconstruction requests with such
  options, plan previews with such lengths, times and speeds, and uploads with such spacings
  are answered 4xx (or 2xx), never 5xx, and the connection is kept across every 4xx.
- ``fpscan plan`` and ``fpscan recon`` given ``1e999999999m`` end with exit status 2 and one
  error line, no traceback.
"""
from __future__ import annotations

import http.client
import io
import json
import subprocess

import httpx
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fpscan.clients.processes import clean_env, fpscan_argv
from tests.service.service_servers import TOKEN

UNITS = ["", "m", "um", "µm", "mm", "km", "nm", "Ym", "ym", "ns", "us", "s", "ms", "Hz", "kHz", "MHz", "m/s",
         "km/s", "mm/us", "parsec", "m**2", "1/s", "°", "furlong"]

#: text a person (or a fuzzer) might type for a number with a unit
QUANTITY_TEXT = st.builds(
    lambda m, e, sp, u: f"{m}e{e}{sp}{u}",
    st.sampled_from(["1", "-1", "9.99", ".5", "0", "0.0", "123456789012345678901234567890"]),
    st.integers(-10**9, 10**9), st.sampled_from(["", " "]), st.sampled_from(UNITS))
HOSTILE_TEXT = st.one_of(
    QUANTITY_TEXT,
    st.text(max_size=40),
    st.sampled_from(["(1,2", "f4," * 50, "auto", "nan", "inf", "-inf", "1e400", "-1e400", "0x10", "1_000",
                     "١٢٣", "float32", "float64", "f4", "<f8", "1e-400 m", "1e30 Ym", "auto auto"]),
)
HOSTILE = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-2**70, max_value=2**70),
    st.floats(allow_nan=False, allow_infinity=False), HOSTILE_TEXT,
    st.lists(st.one_of(st.integers(-10, 10), QUANTITY_TEXT), max_size=3),
    st.dictionaries(st.text(max_size=5), st.integers(), max_size=2),
)
PROPERTY = settings(max_examples=150, deadline=None, derandomize=True, database=None,
                    suppress_health_check=list(HealthCheck))


@PROPERTY
@given(text=st.one_of(HOSTILE_TEXT, st.text(max_size=60)), kind=st.sampled_from(["length", "time", "frequency",
                                                                                 "speed"]))
def test_the_quantity_parser_answers_a_number_or_a_reason(text, kind):
    from fpscan.driver.units import parse_quantity

    try:
        value = parse_quantity(text, kind, name="x")
    except ValueError:
        return
    assert isinstance(value, float) and np.isfinite(value)


@PROPERTY
@given(data=st.data())
def test_every_method_s_options_are_checked_to_a_value_or_a_reason(data):
    from fpscan.service.pipeline import method_options
    from fpscan.service.recon.methods import METHODS

    method = data.draw(st.sampled_from(sorted(METHODS)))
    names = sorted(METHODS[method].options_model.model_fields) + ["c", "c_range", "lam", "interp"]
    options = data.draw(st.dictionaries(st.sampled_from(names), HOSTILE, max_size=3))
    try:
        METHODS[method].check({k: v for k, v in options.items() if k not in ("c", "c_range")})
    except ValueError:
        pass
    try:
        method_options(method, options)
    except ValueError:
        pass


# -- over HTTP ---------------------------------------------------------------------------

class KeptAlive:
    """One HTTP/1.1 connection to the server, kept alive; :meth:`send` says whether the
    server kept it after answering."""

    def __init__(self, port: int) -> None:
        self.conn = http.client.HTTPConnection("127.0.0.1", port, timeout=120)
        self.conn.connect()
        self.sock = self.conn.sock
        self.dropped = 0

    def send(self, method: str, path: str, body: bytes, headers: dict) -> tuple[int, bool]:
        self.conn.request(method, path, body=body, headers={"Authorization": f"Bearer {TOKEN}", **headers})
        r = self.conn.getresponse()
        r.read()
        kept = self.conn.sock is not None and self.conn.sock is self.sock
        if not kept:
            self.dropped += 1
            self.conn.close()
            self.conn.connect()
            self.sock = self.conn.sock
        return r.status, kept

    def close(self) -> None:
        self.conn.close()


@pytest.fixture(scope="module")
def fuzz_target(shared_server):
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(1).standard_normal((32, 6, 6)).astype(np.float32))
    with shared_server.client() as c:
        r = c.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
                   files={"file": ("d.npy", buf.getvalue())})
        assert r.status_code == 201, r.text
    conn = KeptAlive(shared_server.port)
    yield shared_server, r.json()["dataset_id"], conn
    conn.close()


def _check(answer: tuple[int, bool], what: object) -> None:
    status, kept = answer
    assert status < 500, (status, what)
    assert kept or status < 400 or status in (408, 413, 429), ("a 4xx dropped the connection", status, what)


@pytest.mark.timeout(600)
def test_reconstruction_requests_never_get_a_5xx(fuzz_target):
    _, dataset_id, conn = fuzz_target
    from fpscan.service.recon.methods import METHODS, option_fields

    names = sorted(option_fields()) + ["sound_speed", "sound_speed_range", "force", "c"]

    @PROPERTY
    @given(method=st.sampled_from(sorted(METHODS) + ["fbp", ""]),
           params=st.dictionaries(st.sampled_from(names), HOSTILE, max_size=3))
    def run(method, params):
        body = json.dumps({"dataset_id": dataset_id, "method": method, "params": params}).encode()
        _check(conn.send("POST", "/api/reconstructions", body, {"Content-Type": "application/json"}), params)

    run()
    assert conn.dropped == 0


@pytest.mark.timeout(600)
def test_plan_requests_never_get_a_5xx(fuzz_target):
    _, _, conn = fuzz_target
    from fpscan.service.plans.kinds import KINDS

    @PROPERTY
    @given(kind=st.sampled_from(sorted(KINDS)), pitch=HOSTILE,
           acquisition=st.dictionaries(st.sampled_from(["dt", "prf", "sound_speed", "n_t", "wavelengths"]), HOSTILE,
                                       max_size=2),
           params=st.dictionaries(st.sampled_from(["depth", "poi", "min_distance", "n_points", "spacing"]), HOSTILE,
                                  max_size=2))
    def run(kind, pitch, acquisition, params):
        body = json.dumps({"kind": kind, "lattice": {"n_x": 16, "n_y": 16, "pitch": pitch},
                           "acquisition": acquisition, "params": params}).encode()
        _check(conn.send("POST", "/api/plans/preview", body, {"Content-Type": "application/json"}),
               (kind, pitch, acquisition, params))

    run()
    assert conn.dropped == 0


@pytest.mark.timeout(600)
def test_upload_forms_never_get_a_5xx(fuzz_target):
    srv, _, conn = fuzz_target
    buf = io.BytesIO()
    np.save(buf, np.zeros((16, 4, 4), np.float32))
    npy = buf.getvalue()

    @settings(max_examples=40, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck))
    @given(form=st.dictionaries(st.sampled_from(["dt", "dx", "dy", "sound_speed", "c", "wavelength", "key"]),
                                HOSTILE_TEXT, max_size=3))
    def run(form):
        req = httpx.Request("POST", srv.url + "/api/datasets", data={"format": "npy", **form},
                            files={"file": ("x.npy", npy)})
        body = req.read()
        headers = {"Content-Type": req.headers["content-type"], "Content-Length": str(len(body))}
        _check(conn.send("POST", "/api/datasets", body, headers), form)

    run()


@pytest.mark.parametrize("argv", [["plan", "full", "--n-x", "4", "--n-y", "4", "--pitch", "1e999999999m"],
                                  ["plan", "full", "--n-x", "4", "--n-y", "4", "--dt", "1e999999999 s"],
                                  ["recon", "missing.npy", "--dz", "1e999999999m"]])
def test_the_command_line_says_one_line_for_an_absurd_number(tmp_path, argv):
    r = subprocess.run(fpscan_argv(*argv), cwd=tmp_path, capture_output=True, text=True, env=clean_env(),
                       timeout=120)
    assert r.returncode == 2, r
    assert "Traceback" not in r.stderr, r.stderr
    errors = [line for line in r.stderr.splitlines() if "error:" in line]
    assert len(errors) == 1 and "out of range" in errors[0], r.stderr


# -- nesting and headers ------------------------------------------------------

#: every route that reads a JSON body, with a body it takes whose one value the tests nest
JSON_ROUTES = [("POST", "/api/plans", lambda deep: {"kind": "full", "lattice": {"n_x": 4, "n_y": 4, "pitch": deep}}),
               ("POST", "/api/plans/preview", lambda deep: {"kind": "full", "lattice": deep}),
               ("POST", "/api/reconstructions", lambda deep: {"dataset_id": "0" * 32, "params": {"lam": deep}}),
               ("POST", "/api/scans", lambda deep: {"plan_id": deep, "scanner_id": "sim"}),
               ("PUT", "/api/retention", lambda deep: {"keep_results": deep})]


def nested(depth: int, kind: str) -> str:
    """A JSON text ``depth`` arrays or objects deep (``"mixed"``: alternating), built
    without recursion (``json.dumps`` recurses)."""
    opens, closes = [], []
    for i in range(depth):
        use = kind if kind != "mixed" else ("array" if i % 2 else "object")
        opens.append("[" if use == "array" else '{"a": ')
        closes.append("]" if use == "array" else "}")
    return "".join(opens) + "1" + "".join(reversed(closes))


def body_with(make, value: str) -> bytes:
    """The request body ``make`` builds, with ``value`` (a JSON text) as its nested value."""
    return json.dumps(make("@@")).replace('"@@"', value).encode()


def deep_text(depth: int) -> bytes:
    """A JSON text ``depth`` arrays deep."""
    return nested(depth, "array").encode()


@pytest.mark.parametrize("method,path,make", JSON_ROUTES, ids=[f"{m} {p}" for m, p, _ in JSON_ROUTES])
def test_json_nested_beyond_the_bound_is_refused_at_the_door(fuzz_target, method, path, make):
    """A JSON body nested deeper than 64 gets 422 naming the depth and the
    bound, on every route that reads JSON, and the connection is kept; 2000 deep (a
    RecursionError in the parser before) and 100 000 deep (over the body limits of the
    small routes: 413) get no 5xx; at the bound the request is answered by the route."""
    conn = KeptAlive(fuzz_target[0].port)  # its own: the module's may have idled past keep_alive_s
    try:
        _nested_at_the_door(conn, method, path, make)
    finally:
        conn.close()


def _nested_at_the_door(conn: KeptAlive, method: str, path: str, make) -> None:
    from fpscan.service.api.json_depth import MAX_JSON_DEPTH, json_depth

    own = json_depth(body_with(make, "1"))  # the request's own levels around the nested value
    for depth in (MAX_JSON_DEPTH + 1, 2000):
        for kind in ("array", "object", "mixed"):
            body = body_with(make, nested(depth - own, kind))
            assert json_depth(body) == depth
            for ctype in ("application/json", "application/vnd.fpscan+json; charset=utf-8", None):
                headers = {"Content-Type": ctype} if ctype else {}
                conn.conn.request(method, path, body=body, headers={"Authorization": f"Bearer {TOKEN}", **headers})
                r = conn.conn.getresponse()
                detail = json.loads(r.read())["detail"]
                assert r.status == 422, (depth, kind, ctype, r.status, detail)
                assert f"at most {MAX_JSON_DEPTH} levels" in detail and "nested" in detail, detail
                assert conn.conn.sock is conn.sock, "the refusal dropped the connection"
    # the bound itself passes the door: the route answers it (a 4xx of its own, never the door's)
    body = body_with(make, nested(MAX_JSON_DEPTH - own, "array"))
    conn.conn.request(method, path, body=body, headers={"Authorization": f"Bearer {TOKEN}",
                                                        "Content-Type": "application/json"})
    r = conn.conn.getresponse()
    answer = r.read().decode()
    assert r.status < 500 and "levels of arrays" not in answer, (r.status, answer)
    # far beyond: still a 4xx (413 where the body is over the route's limit)
    _check(conn.send(method, path, deep_text(100_000), {"Content-Type": "application/json"}), (path, 100_000))


def test_json_depth_counts_brackets_outside_strings_only():
    from fpscan.service.api.json_depth import json_depth

    for depth in (0, 1, 2, 64, 65, 3000):
        for kind in ("array", "object", "mixed"):
            assert json_depth(nested(depth, kind).encode()) == depth, (depth, kind)
    assert json_depth(json.dumps({"a": "[[[{{{", "b": ['\\"[[', "]]]"]}).encode()) == 2
    assert json_depth(b'"unterminated [[[') == 3  # counted all the same: the parser refuses it next


HEADER_NAMES = ["Content-Type", "Accept", "Accept-Encoding", "Range", "If-Range", "Idempotency-Key", "Origin",
                "Cookie", "X-Forwarded-For", "Transfer-Encoding", "Expect", "Authorization", "Host",
                "Content-Encoding", "Cache-Control", "If-None-Match"]
HEADER_VALUES = st.one_of(
    st.sampled_from(["", " ", "application/json", "application/json; charset=utf-16", "application/x+json",
                     "text/plain", "multipart/form-data", "multipart/form-data; boundary=", "*/*", "gzip, br;q=2",
                     "bytes=0-", "bytes=-0", "bytes=99999999999999999999999-", "bytes=5-1", "bytes=0-1,2-3,4-5",
                     "chunked", "gzip", "identity", "100-continue", "Bearer", f"Bearer {TOKEN}x", "127.0.0.1",
                     "[::1]:99999", "a" * 4000, "\u00ff\u00fe", "1" * 40, "null", "W/\"x\"", "max-age=-1"]),
    st.text(alphabet=st.characters(min_codepoint=0x20, max_codepoint=0xFF, blacklist_characters="\x7f"),
            max_size=60))


@pytest.mark.timeout(600)
def test_odd_headers_never_get_a_5xx(fuzz_target):
    """Requests to every kind of route (JSON bodies, reads, a ranged file, an
    event stream's head) with odd values of the headers a client can send are answered
    below 500, and a 4xx keeps the connection."""
    srv, dataset_id, _ = fuzz_target
    routes = [("POST", "/api/reconstructions", json.dumps({"dataset_id": dataset_id, "method": "ner",
                                                           "params": {"upsample": 1}}).encode()),
              ("POST", "/api/plans/preview", json.dumps({"kind": "full", "lattice": {"n_x": 4, "n_y": 4,
                                                                                    "pitch": 1e-4}}).encode()),
              ("PUT", "/api/retention", b"{}"),
              ("GET", "/api/jobs", b""), ("GET", "/api/datasets", b""), ("GET", "/api/formats", b""),
              ("GET", "/openapi.json", b""), ("DELETE", f"/api/datasets/{'f' * 32}", b"")]
    conn = KeptAlive(srv.port)

    @settings(max_examples=120, deadline=None, derandomize=True, database=None,
              suppress_health_check=list(HealthCheck))
    @given(route=st.sampled_from(routes),
           headers=st.dictionaries(st.sampled_from(HEADER_NAMES), HEADER_VALUES, max_size=3))
    def run(route, headers):
        method, path, body = route
        # a body's length is always said truly (a Content-Length larger than the body is a
        # slow client, answered by the body timeout, not a parser's case)
        headers = {k: v for k, v in headers.items() if k not in ("Transfer-Encoding", "Expect")}
        sent = {"Authorization": f"Bearer {TOKEN}", **headers, "Content-Length": str(len(body))}
        try:
            conn.conn.putrequest(method, path, skip_host="Host" in headers, skip_accept_encoding=True)
            for k, v in sent.items():
                conn.conn.putheader(k, v.encode("latin-1"))
            conn.conn.endheaders(body)
            r = conn.conn.getresponse()
            r.read()
        except (http.client.HTTPException, OSError) as exc:
            raise AssertionError(f"no answer to {method} {path} {headers}: {exc!r}") from None
        assert r.status < 500, (r.status, method, path, headers)
        if conn.conn.sock is not conn.sock:  # a 4xx that closes (431, 400 on a broken head) is fine
            conn.dropped += 1
            conn.conn.close()
            conn.conn.connect()
            conn.sock = conn.conn.sock

    try:
        run()
    finally:
        conn.close()


# -- Last-Event-ID -----------------------------------------------------------

#: what a client (or a proxy, or a fuzzer) may send as ``Last-Event-ID``: our ids, ids beyond
#: SQLite's 64-bit range, signs, exponents, spaces, letters, any Latin-1 text
EVENT_IDS = st.one_of(
    st.integers(min_value=-2**70, max_value=2**70).map(str),
    st.integers(min_value=0, max_value=12).map(str),
    st.builds(lambda sign, digits, pad: f"{pad}{sign}{digits}{pad}", st.sampled_from(["", "+", "-", "0", "00"]),
              st.text(alphabet="0123456789", min_size=1, max_size=40), st.sampled_from(["", " ", "\t"])),
    st.sampled_from(["", "1e3", "0x10", "1_000", "1.0", "NaN", "inf", "١٢", "１２", "9" * 19, "9" * 20,
                     str(2**63 - 1), str(2**63), "-0", "null", "a" * 4000, "1 2"]),
    st.text(alphabet=st.characters(min_codepoint=0x20, max_codepoint=0xFF, blacklist_characters="\x7f"),
            max_size=60),
)


def _expected_after(value: str) -> int:
    """The oracle: the id a stream resumes after, written from the SSE specification's rule
    (an opaque string; ours are decimal integers), not from the server's code."""
    text = value.strip(" \t")
    if text and all(ch in "0123456789" for ch in text) and int(text) <= 2**63 - 1:
        return int(text)
    return 0


@PROPERTY
@given(value=EVENT_IDS)
def test_last_event_id_parses_to_a_bounded_sequence_or_the_beginning(value):
    from fpscan.service.api.jobs import LAST_EVENT_MAX, last_event_seq

    got = last_event_seq(value)
    assert 0 <= got <= LAST_EVENT_MAX
    assert got == _expected_after(value), (value, got)


def _event_ids(body: bytes) -> list[int]:
    return [int(line[3:].strip()) for line in body.decode().splitlines() if line.startswith("id:")]


@pytest.mark.timeout(600)
def test_odd_last_event_ids_never_get_a_5xx_and_nonsense_replays_from_the_beginning(fuzz_target):
    """The event stream of a finished job, asked with any ``Last-Event-ID`` over
    one kept-alive connection, answers 200 with the events after a valid id, and every
    event for nonsense (beyond 2**63 - 1, signs, letters, any Latin-1 text); never a 5xx, and
    the connection is kept."""
    from tests.service.service_servers import wait_job

    srv, dataset_id, _ = fuzz_target
    with srv.client() as c:
        r = c.post("/api/reconstructions", json={"dataset_id": dataset_id, "method": "ner", "params": {"upsample": 1}})
        assert r.status_code == 202, r.text
        job_id = r.json()["id"]
        c.post(f"/api/jobs/{job_id}/cancel")
        wait_job(c, job_id)  # finished (cancelled or not): its stream ends after its events
    conn = KeptAlive(srv.port)
    path = f"/api/jobs/{job_id}/events"

    def stream(value: str | None) -> tuple[int, list[int]]:
        conn.conn.putrequest("GET", path, skip_accept_encoding=True)
        conn.conn.putheader("Authorization", f"Bearer {TOKEN}")
        if value is not None:
            conn.conn.putheader("Last-Event-ID", value.encode())  # UTF-8: obs-text bytes beyond Latin-1
        conn.conn.endheaders()
        r = conn.conn.getresponse()
        body = r.read()
        assert conn.conn.sock is conn.sock, ("the stream's connection was dropped", value)
        return r.status, _event_ids(body) if r.status == 200 else []

    status, every = stream(None)
    assert status == 200 and every and every == sorted(every), every
    seen = {"from the beginning": 0, "resumed": 0}

    @settings(max_examples=150, deadline=None, derandomize=True, database=None,
              suppress_health_check=list(HealthCheck))
    @given(value=EVENT_IDS)
    def run(value):
        status, ids = stream(value)
        assert status == 200, (status, value)
        after = _expected_after(value)
        assert ids == [i for i in every if i > after], (value, ids, every)
        seen["resumed" if after else "from the beginning"] += 1

    try:
        run()
    finally:
        conn.close()
    print(f"Last-Event-ID: {sum(seen.values())} values, {seen}; the job's events: {every}")
