"""The fields of the HTTP API's responses, defined once (``fpscan.wire.models``), in SI units
(m, s, Hz, bytes).

The bottom layer (``docs/architecture.md``): pure pydantic, it imports nothing of fpscan, so
that both ends of the wire build on it. Each model here holds the fields in their lenient
form (states and kinds as plain strings, defaults for fields a server may omit) with the
descriptions the OpenAPI schema shows. The server (``fpscan.service.api.models``) narrows them to
what it guarantees (literal states and kinds, required fields); the client
(``fpscan.clients.http.models``) keeps them lenient and keeps unknown fields, so that it works
against a slightly newer or older server.
"""

__all__: list[str] = []
