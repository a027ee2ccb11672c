"""The client against a server that misbehaves (tests/clients/hostile_server.py, a real socket on
127.0.0.1): every call ends in bounded time and memory, with an error that says why."""
from __future__ import annotations

import asyncio
import json

import pytest

from fpscan.clients.http import AsyncClient, Client
from fpscan.clients.http.errors import WaitTimeout
from fpscan.clients.http.waiting import MAX_EVENT_BYTES
from tests.clients.hostile_server import RUNNING, Request, hostile_server
from tests.waits import HANG_S


def running_job_then(events):
    """A server whose job J1 runs for ever, its event stream answered by ``events(request)``."""
    def route(req: Request) -> None:
        if req.path.startswith("/api/jobs/J1/events"):
            req.head(200, {"Content-Type": "text/event-stream"})
            events(req)
        elif req.path.startswith("/api/jobs/J1"):
            req.json(RUNNING)
        else:
            req.json({"detail": f"no route {req.path}"}, 404)
    return route


def keepalives(req: Request) -> None:
    """What the real server sends while a job makes no event (every 15 s there; 0.2 s here)."""
    while req.send(b": keep-alive\n\n"):
        req.hung_up.wait(0.2)


def endless_line(req: Request) -> None:
    """One event line that never ends."""
    req.send(b"data: ")
    while req.send(b"x" * 65536):
        pass


@pytest.mark.timeout(120)
def test_wait_ends_at_its_timeout_while_the_stream_sends_only_keepalives():
    """A keep-alive comment is no event: the wait checked its deadline on events alone, so
    ``wait(timeout=...)`` (and ``fpscan jobs wait --timeout``) never ended while a job was quiet."""
    with hostile_server(running_job_then(keepalives)) as (url, _):
        with Client(url) as api, pytest.raises(WaitTimeout, match="still running after 1.5 s"):
            api.wait("J1", timeout=1.5)

        async def main() -> None:
            async with AsyncClient(url) as api:
                await api.wait("J1", timeout=1.5)

        with pytest.raises(WaitTimeout, match="still running after 1.5 s"):
            asyncio.run(main())


@pytest.mark.timeout(120)
def test_an_event_line_that_never_ends_is_dropped_after_a_bounded_read():
    """A stream that sends one line for ever: the client stops reading after
    ``MAX_EVENT_BYTES`` without an event (it read all of it into memory before) and polls the job
    instead, until its timeout."""
    with hostile_server(running_job_then(endless_line)) as (url, requests):
        with Client(url) as api, pytest.raises(WaitTimeout):
            api.wait("J1", timeout=3)
    streams = [r for r in requests if r.path.endswith("/events")]
    # the server's thread notices the hang-up on its next send, maybe after the wait has returned
    assert streams and all(r.hung_up.wait(HANG_S) for r in streams), [(r.path, r.sent) for r in streams]
    # what the client read, plus what the sockets' buffers held when it hung up
    assert max(r.sent for r in streams) < MAX_EVENT_BYTES + (16 << 20), [r.sent for r in streams]
    assert any(r.path == "/api/jobs/J1" for r in requests[requests.index(streams[0]) + 1:])  # then it polled


def file_server(body: bytes, partial):
    """Serves ``body`` as a volume: ``partial(req)`` answers a request with a ``Range`` (a first
    request without one is cut after 3/4 of the body, so the client holds a part to resume)."""
    cuts: list = []

    def route(req: Request) -> None:
        if "range" in req.headers:
            partial(req)
            return
        req.head(200, {"Content-Type": "application/x-hdf5", "Content-Length": len(body), "ETag": '"v1"'})
        req.send(body if cuts else body[: len(body) * 3 // 4])
        cuts.append(True)
    return route


def test_a_redirect_is_not_saved_as_the_download(tmp_path):
    """A 3xx on a download (a proxy's or a stranger's) was saved as the volume, exit 0: the
    file is any answer but 200/206, named with its Location, and nothing is left at ``dest``."""
    from fpscan.clients.http.errors import ApiError

    def route(req: Request) -> None:
        req.head(307, {"Location": "http://10.255.255.1/volume.h5", "Content-Length": 5})
        req.send(b"Moved")

    with hostile_server(route) as (url, _), Client(url) as api:
        with pytest.raises(ApiError, match=r"307 \(to http://10.255.255.1/volume.h5\) instead of the file"):
            api.download_volume("J1", tmp_path / "v.h5")
    assert list(tmp_path.iterdir()) == []


def test_a_partial_answer_that_does_not_continue_the_part_starts_the_download_over(tmp_path):
    """A resumed download asks ``Range: bytes=HELD-``; a 206 whose ``Content-Range`` starts
    elsewhere (here: the whole file again) was appended to the part, and a file of 7/4 the size
    returned as the volume. Such a 206 is discarded and the file fetched whole."""
    from fpscan.clients.http.errors import ServerUnavailable

    body = b"\x89HDF\r\n\x1a\n" + bytes(range(256)) * (16 << 10)  # 4 MiB, as a volume begins

    def whole_as_206(req: Request) -> None:
        req.head(206, {"Content-Range": f"bytes 0-{len(body) - 1}/{len(body)}", "Content-Length": len(body),
                       "ETag": '"v1"'})
        req.send(body)

    with hostile_server(file_server(body, whole_as_206)) as (url, requests), Client(url) as api:
        with pytest.raises(ServerUnavailable):  # the first answer is cut: the part is kept
            api.download_volume("J1", tmp_path / "v.h5")
        assert (tmp_path / "v.h5.part").stat().st_size == len(body) * 3 // 4
        api.download_volume("J1", tmp_path / "v.h5")
    assert (tmp_path / "v.h5").read_bytes() == body
    assert [("range" in r.headers) for r in requests] == [False, True, False]  # cut, refused 206, whole


def test_a_zip_that_unpacks_to_far_more_than_an_export_is_refused(tmp_path):
    """An OME-Zarr export arrives zipped; a zip of zeros unpacks 1000:1 and more, so 100 MB
    became 100 GB on the user's disk. Refused before anything is unpacked."""
    import zipfile

    from fpscan.clients.http.transport import MAX_ZIP_RATIO, unzip_folder

    bomb = tmp_path / "v.zip"
    with zipfile.ZipFile(bomb, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("v.ome.zarr/zarr.json", "{}")
        z.writestr("v.ome.zarr/0/c/0/0/0", bytes(64 << 20))
    with pytest.raises(ValueError, match=f"over the {MAX_ZIP_RATIO}:1 an export reaches"):
        unzip_folder(bomb, tmp_path / "out.ome.zarr")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.zip"]


def test_jobs_list_all_stops_on_a_server_that_does_not_page(tmp_path):
    """``fpscan jobs list --all`` asks page after page with ``?before=``; a server that ignores it
    (an older fpscan) answered the same page for ever, and the command never ended (1.8 GiB
    after 40 s). It stops with the reason at the first page it has seen before."""
    import subprocess
    import sys


    def route(req: Request) -> None:
        req.json([{**RUNNING, "id": "J2"}, {**RUNNING, "id": "J1"}])

    with hostile_server(route) as (url, requests):
        res = subprocess.run([sys.executable, "-m", "fpscan", "jobs", "list", "--all", "--limit", "2",
                              "--server", url], capture_output=True, text=True, timeout=HANG_S)
    assert res.returncode == 1 and "already listed" in res.stderr, (res.returncode, res.stderr[-500:])
    assert len(requests) == 2


def test_a_servers_reason_is_shown_as_one_bounded_safe_line():
    """The server's ``detail`` is printed on the user's terminal: a 5 MB one was a 5 MB line (an
    error's body is now read to ``MAX_ERROR_BYTES``; this one is half a MiB), and
    one with line breaks and escape sequences printed a fake traceback and retitled the terminal.
    Shown as one line, control characters escaped, cut at ``MAX_DETAIL_CHARS`` (the rest counted)."""
    from fpscan.clients.http.errors import MAX_DETAIL_CHARS, ApiError

    reason = "line one\nTraceback (fake)\n\x1b]0;title\x07 " + "x" * (512 << 10)

    def route(req: Request) -> None:
        req.json({"detail": reason}, 500)

    with hostile_server(route) as (url, _), Client(url) as api, pytest.raises(ApiError) as caught:
        api.list_jobs()
    shown = str(caught.value)
    assert "\n" not in shown and "\x1b" not in shown and "\x07" not in shown, shown[:200]
    assert "line one Traceback (fake) \\x1b]0;title\\x07" in shown, shown[:200]
    assert len(shown) < MAX_DETAIL_CHARS + 100 and f"({len(reason) - MAX_DETAIL_CHARS} characters more)" in shown


@pytest.mark.parametrize("command, route, said", [
    (["datasets", "list"], lambda req: req.json([{"name": "a.h5", "format": "fpscan", "size_bytes": 1}]),
     "answered in a shape this client does not read (KeyError: 'dataset_id')"),
    (["jobs", "list"], lambda req: req.json([{**RUNNING, "progress": [1, 2]}]),
     "answered in a shape this client does not read (AttributeError"),
    (["recon", "--scan-job", "J1", "--method", "ner"],
     lambda req: req.json({"accepted": True}, 202) if req.method == "POST" else req.json(RUNNING),
     "the server accepted the job (HTTP 202) but named no job id"),
], ids=["dataset-without-id", "progress-a-list", "202-without-id"])
def test_an_answer_of_another_shape_is_one_line_not_a_traceback(tmp_path, command, route, said):
    """The command line read the server's answers as its own server writes them; another shape
    (an older or newer server, or not fpscan) ended in a Python traceback (a KeyError,
    AttributeError, or an AssertionError after the server had accepted a job). Exit 1, one
    line naming the server."""
    import subprocess
    import sys


    with hostile_server(route) as (url, _):
        res = subprocess.run([sys.executable, "-m", "fpscan", *command, "--server", url], capture_output=True,
                             text=True, timeout=HANG_S, cwd=tmp_path)
    assert res.returncode == 1 and said in res.stderr, (res.returncode, res.stderr[-800:])
    assert "Traceback" not in res.stderr, res.stderr[-800:]


@pytest.mark.parametrize("answer, said", [
    (lambda req: (req.head(200, {"Content-Type": "application/json", "Content-Length": 9}), req.send(b"<html>hi!")),
     "JSONDecodeError"),
    (lambda req: (req.head(301, {"Location": "http://127.0.0.1:9/api/jobs", "Content-Length": 0})),
     "HTTP 301 to http://127.0.0.1:9/api/jobs"),
    (lambda req: req.json(["a", "b"]), "ValidationError"),
], ids=["not-json", "redirect", "list-of-strings"])
def test_an_answer_the_client_cannot_read_is_a_bad_answer(answer, said):
    """A body that is not JSON, a redirect (never followed) or JSON of another shape was a bare
    JSONDecodeError or pydantic error, which the command line reported as a usage error (exit 2)
    in the decoder's words. It is a ``BadAnswer`` naming the server and the request (exit 1)."""
    from fpscan.clients.http import BadAnswer

    with hostile_server(answer) as (url, _), Client(url) as api, pytest.raises(BadAnswer) as caught:
        api.list_jobs()
    assert f"the server at {url} answered GET /api/jobs with what this client cannot read" in str(caught.value)
    assert said in str(caught.value), str(caught.value)


def test_jobs_list_shows_a_fraction_that_is_none_as_unknown(tmp_path):
    """A progress fraction that is text, NaN or past 1 printed "nan%" or "inf%", or ended the
    listing with a format error (exit 2); it shows as "?"."""
    import subprocess
    import sys


    jobs = [{**RUNNING, "id": f"J{i}", "progress": {"fraction": f, "stage": "x"}}
            for i, f in enumerate(["half", float("nan"), 1e308, 0.25])]

    def route(req: Request) -> None:
        data = json.dumps(jobs).encode()  # NaN as JSON's NaN, as Python writes it
        req.head(200, {"Content-Type": "application/json", "Content-Length": len(data)})
        req.send(data)

    with hostile_server(route) as (url, _):
        res = subprocess.run([sys.executable, "-m", "fpscan", "jobs", "list", "--server", url], capture_output=True,
                             text=True, timeout=HANG_S, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-500:]
    shown = {line.split()[0]: line for line in res.stdout.splitlines()[1:]}
    assert all(shown[f"J{i}"].rstrip().endswith("? x") for i in range(3)), res.stdout
    assert shown["J3"].rstrip().endswith("25.0% x") and "nan" not in res.stdout and "inf" not in res.stdout


def test_an_answer_larger_than_any_of_fpscans_is_refused_at_its_cap():
    """A JSON answer was read into memory whole, however large (a 300 MB one took 860 MiB, a
    500's body 1.5 GiB): the client stops at ``MAX_ANSWER_BYTES`` with a ``BadAnswer``."""
    from fpscan.clients.http import BadAnswer
    from fpscan.clients.http.core import MAX_ANSWER_BYTES

    def route(req: Request) -> None:
        req.head(200, {"Content-Type": "application/json"})  # a body that ends at the close
        req.send(b"[")
        while req.send(b'"x",' * 16384):
            pass

    with hostile_server(route) as (url, requests), Client(url) as api, pytest.raises(BadAnswer) as caught:
        api.list_jobs()
    assert f"more than {MAX_ANSWER_BYTES} bytes" in str(caught.value)
    assert requests[0].hung_up.wait(HANG_S)  # the server's thread has seen the hang-up: sent is final
    assert requests[0].sent < MAX_ANSWER_BYTES + (16 << 20), requests[0].sent  # it hung up there


@pytest.mark.timeout(120)
def test_an_answer_that_trickles_in_ends_after_the_timeout(tmp_path):
    """httpx's timeout bounds each read: a server sending a byte now and then held ``list_jobs``
    (and ``fpscan jobs list``, and a download) for ever. Once the client's timeout has passed, a
    body must average ``MIN_BODY_RATE`` bytes/s."""
    from fpscan.clients.http.core import MIN_BODY_RATE
    from fpscan.clients.http.errors import ServerUnavailable

    def route(req: Request) -> None:
        req.head(200, {"Content-Type": "application/json", "Content-Length": 1000})
        while req.send(b" "):
            req.hung_up.wait(0.2)

    with hostile_server(route) as (url, _), Client(url, timeout=1.0) as api:
        with pytest.raises(ServerUnavailable, match=f"under {MIN_BODY_RATE} bytes/s"):
            api.list_jobs()
        with pytest.raises(ServerUnavailable, match=f"under {MIN_BODY_RATE} bytes/s"):
            api.download_volume("J1", tmp_path / "v.h5")
    assert (tmp_path / "v.h5.part").exists() and not (tmp_path / "v.h5").exists()  # kept, to resume


def test_a_download_that_is_not_the_file_it_names_is_not_kept(tmp_path):
    """A 200 with a web page (a proxy's login page, a stranger's server) was saved as
    ``volume.h5`` and the command exited 0; a volume, scan file or picture that does not begin
    with its format's signature is a ``BadAnswer``, and nothing is left at ``dest``."""
    from fpscan.clients.http import BadAnswer

    page = b"<html>please log in</html>"

    def route(req: Request) -> None:
        req.head(200, {"Content-Type": "text/html", "Content-Length": len(page)})
        req.send(page)

    with hostile_server(route) as (url, _), Client(url) as api:
        with pytest.raises(BadAnswer, match="does not begin as an HDF5 file does"):
            api.download_volume("J1", tmp_path / "v.h5")
        with pytest.raises(BadAnswer, match="does not begin as a PNG picture does"):
            api.download_mip("J1", "xy", tmp_path / "xy.png")
    assert list(tmp_path.iterdir()) == []


def trickled_head(req: Request) -> None:
    """A status line, then a header byte every 0.2 s: each read waits less than any timeout."""
    req.send(b"HTTP/1.1 200 X\r\nX-Slow: ")
    while req.send(b"x"):
        req.hung_up.wait(0.2)


@pytest.mark.timeout(120)
def test_an_answer_whose_head_trickles_in_ends_after_the_timeout(tmp_path):
    """httpx's timeout bounds each read, and the body's minimum rate starts once the head has
    arrived: a server sending a byte of its headers now and then held every call (a JSON answer,
    a download, a job's event stream; both clients) for ever. The head now arrives whole within
    the client's timeout of the request's sending, or the call raises ``ServerUnavailable``."""
    from fpscan.clients.http.errors import ServerUnavailable

    said = "answer's head .* did not arrive whole within 1 s"
    with hostile_server(trickled_head) as (url, requests):
        with Client(url, timeout=1.0) as api:
            with pytest.raises(ServerUnavailable, match=said):
                api.list_jobs()
            with pytest.raises(ServerUnavailable, match=said):
                api.download_volume("J1", tmp_path / "v.h5")
            with pytest.raises(ServerUnavailable, match=said):
                next(api.events("J1"))

        async def main() -> None:
            async with AsyncClient(url, timeout=1.0) as api:
                with pytest.raises(ServerUnavailable, match=said):
                    await api.list_jobs()
                with pytest.raises(ServerUnavailable, match=said):
                    await api.events("J1").__anext__()

        asyncio.run(main())
        assert not (tmp_path / "v.h5").exists()
        assert len(requests) >= 5 and all(r.hung_up.wait(HANG_S) for r in requests)  # the client hung up on each


@pytest.mark.timeout(120)
def test_the_environment_s_proxy_is_used_and_its_answer_s_head_is_bounded(monkeypatch):
    """A client made with a transport of its own is not given httpx's proxies from the environment:
    the head's bound once cost a lab behind ``HTTP_PROXY`` its way to the server. The clients send
    through the environment's proxy (here one that trickles its answer's head, so the bound must hold
    through it too), and straight to a ``NO_PROXY`` host."""
    from fpscan.clients.http.errors import ServerUnavailable

    for name in ("HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY", "NO_PROXY"):
        for spelled in (name, name.lower()):
            monkeypatch.delenv(spelled, raising=False)
    said = "answer's head .* did not arrive whole within 1 s"
    server = "http://fpscan.invalid:8000"  # a name no resolver knows: only the proxy can take it there
    with hostile_server(trickled_head) as (proxy, via_proxy):
        monkeypatch.setenv("HTTP_PROXY", proxy)
        with Client(server, timeout=1.0) as api, pytest.raises(ServerUnavailable, match=said):
            api.list_jobs()

        async def main() -> None:
            async with AsyncClient(server, timeout=1.0) as api:
                with pytest.raises(ServerUnavailable, match=said):
                    await api.list_jobs()

        asyncio.run(main())
        assert [r.path.split("?")[0] for r in via_proxy] == [f"{server}/api/jobs"] * 2  # the proxy's absolute form
        assert all(r.hung_up.wait(HANG_S) for r in via_proxy)

        with hostile_server(lambda req: req.json([])) as (direct, straight):
            monkeypatch.setenv("NO_PROXY", "127.0.0.1")
            with Client(direct, timeout=5.0) as api:
                assert api.list_jobs() == []
            assert [r.path.split("?")[0] for r in straight] == ["/api/jobs"] and len(via_proxy) == 2


@pytest.mark.timeout(120)
def test_an_upload_s_time_is_not_the_head_s():
    """The head's time counts from the request's sending: an upload that takes longer than the
    timeout is answered, as long as its answer's head then comes within it."""
    import time

    from fpscan.clients.http.transport import bound_reads, bounded_head

    def route(req: Request) -> None:
        req.json({"ok": True})

    with hostile_server(route) as (url, _):
        import httpx

        def slow_body():
            for _ in range(4):
                time.sleep(1.5)  # at least 6 s of upload against a head time of 5 s
                yield b"x" * 1000

        with bound_reads(httpx.Client(base_url=url, timeout=5.0)) as http:
            with bounded_head(http.stream("POST", "/upload", content=slow_body(),
                                          headers={"Content-Length": "4000"}), 5.0) as r:
                assert r.status_code == 200 and r.read() == b'{"ok": true}'


@pytest.mark.waits
@pytest.mark.timeout(120)
def test_wait_ends_at_its_timeout_not_at_the_next_keepalive():
    """A wait's deadline was checked as each chunk of its event stream came: with a keep-alive
    comment every 8 s, ``wait(timeout=9)`` read on until the comment at 16 s. Each read of the
    stream now ends by the deadline, so the wait ends before the server sends that comment."""
    interval = 8.0
    late: list[Request] = []

    def sparse_keepalives(req: Request) -> None:
        for k in range(3):
            if k == 2:
                late.append(req)  # the comment after the deadline: the wait should be over by now
            if not req.send(b": keep-alive\n\n") or req.hung_up.wait(interval):
                return

    with hostile_server(running_job_then(sparse_keepalives)) as (url, requests):
        with Client(url) as api, pytest.raises(WaitTimeout, match="still running after 9"):
            api.wait("J1", timeout=9)
        assert not late, "the wait read on past its deadline, to the next keep-alive"
        before = len(requests)

        async def main() -> None:
            async with AsyncClient(url) as api:
                await api.wait("J1", timeout=9)

        with pytest.raises(WaitTimeout, match="still running after 9"):
            asyncio.run(main())
        assert not set(map(id, late)) & set(map(id, requests[before:])), \
            "the async wait read on past its deadline, to the next keep-alive"


def trickled_line(req: Request) -> None:
    """Part of an event line, a byte every 0.3 s, never ended: each read brings a byte in time."""
    req.send(b"data: ")
    while req.send(b"x"):
        req.hung_up.wait(0.3)


@pytest.mark.timeout(120)
def test_an_event_line_that_trickles_and_never_ends_is_dropped_after_the_read_timeout():
    """``MAX_EVENT_BYTES`` bounds an unended line's bytes, not its time: a server sending a byte of
    one line now and then held ``events`` (and a ``wait`` without a deadline) for ever. A line
    begun must end within the stream's read timeout, as a read must bring a byte within it."""
    with hostile_server(running_job_then(trickled_line)) as (url, requests):
        with Client(url) as api, pytest.raises(ValueError, match="a line that did not end in"):
            next(api.events("J1", read_timeout=2))

        async def main() -> None:
            async with AsyncClient(url) as api:
                await api.events("J1", read_timeout=2).__anext__()

        with pytest.raises(ValueError, match="a line that did not end in"):
            asyncio.run(main())
        streams = [r for r in requests if r.path.startswith("/api/jobs/J1/events")]
        assert len(streams) == 2 and all(r.hung_up.wait(HANG_S) for r in streams)
