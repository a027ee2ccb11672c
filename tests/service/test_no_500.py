"""No input reaches a 500 (issue 50.3): property tests (hypothesis) of every parser a request
reaches, beside the schema fuzzing of ``test_openapi_fuzz.py`` (schemathesis).

- The library's parsers, given hostile values (numbers with unit text and exponents up to
  ±10⁹, ``"(1,2"`` and ``"f4,f4,..."`` for a dtype, huge integers, lists, objects): the
  quantity parser (``driver.units.parse_quantity``), every method's options model
  (``service.recon.methods``) and the option check of the dispatch
  (``service.pipeline.method_options``) answer a value or a ``ValueError``, never another
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

from clients.processes import clean_env, fpscan_argv
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
    from driver.units import parse_quantity

    try:
        value = parse_quantity(text, kind, name="x")
    except ValueError:
        return
    assert isinstance(value, float) and np.isfinite(value)


@PROPERTY
@given(data=st.data())
def test_every_method_s_options_are_checked_to_a_value_or_a_reason(data):
    from service.pipeline import method_options
    from service.recon.methods import METHODS

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
    from service.recon.methods import METHODS, option_fields

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
    from service.plans.kinds import KINDS

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
