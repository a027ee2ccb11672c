"""A misbehaving HTTP server on 127.0.0.1 for the client's tests: the answers a broken server,
an older version or a stranger on the lab network might give. A test gives it one function per
request, ``route(request) -> None``, which writes raw bytes to ``request.sock``; the server
records, per request, how many bytes it sent before the client hung up."""
from __future__ import annotations

import json
import socket
import socketserver
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

#: what a stream sends at most, so that a client that never hangs up cannot fill the test machine;
#: above the client's answer cap (64 MiB) and what the sockets' buffers hold past it, so that a
#: test of the cap sees the client hang up before this one ends the stream
STREAM_CAP = 128 << 20

RUNNING = {"id": "J1", "kind": "recon", "state": "running", "progress": {"fraction": 0.5, "stage": "reconstructing"},
           "params": {"method": "ner"}, "links": {}}


@dataclass
class Request:
    """One request as the server read it, and what it sent back."""

    sock: socket.socket
    method: str
    path: str
    headers: dict[str, str]
    sent: int = 0
    hung_up: threading.Event = field(default_factory=threading.Event)

    def send(self, data: bytes) -> bool:
        """Send ``data``; False once the client has gone (or the cap is reached)."""
        if self.sent >= STREAM_CAP:
            return False
        try:
            self.sock.sendall(data)
        except OSError:
            self.hung_up.set()
            return False
        self.sent += len(data)
        return True

    def head(self, status: int, headers: dict | None = None) -> bool:
        lines = [f"HTTP/1.1 {status} X", "Connection: close"] + [f"{k}: {v}" for k, v in (headers or {}).items()]
        return self.send(("\r\n".join(lines) + "\r\n\r\n").encode())

    def json(self, body: object, status: int = 200) -> None:
        data = json.dumps(body).encode()
        self.head(status, {"Content-Type": "application/json", "Content-Length": len(data)})
        self.send(data)


@contextmanager
def hostile_server(route: Callable[[Request], None]) -> Iterator[tuple[str, list[Request]]]:
    """Serve ``route`` on a free loopback port; yields ``(base_url, requests)`` (every request
    served so far, in order) and stops the server on exit."""
    seen: list[Request] = []

    class Handler(socketserver.BaseRequestHandler):
        def handle(self) -> None:
            reader = self.request.makefile("rb")
            line = reader.readline(65536).decode("latin-1").split()
            if len(line) < 2:
                return
            headers = {}
            while (h := reader.readline(65536)) not in (b"\r\n", b"\n", b""):
                key, _, value = h.decode("latin-1").partition(":")
                headers[key.strip().lower()] = value.strip()
            if int(headers.get("content-length") or 0):
                reader.read(int(headers["content-length"]))
            req = Request(self.request, line[0], line[1], headers)
            seen.append(req)
            route(req)

    class Server(socketserver.ThreadingTCPServer):
        daemon_threads = True
        allow_reuse_address = True

    server = Server(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}", seen
    finally:
        server.shutdown()
        server.server_close()
