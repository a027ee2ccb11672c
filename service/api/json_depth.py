"""JSON nesting bounded at the door: every JSON request body nested deeper than
:data:`MAX_JSON_DEPTH` arrays and objects is refused with 422 before any parser sees it.

Python's ``json`` module parses recursively: a body of a few kilobytes nested a thousand
deep raises ``RecursionError`` (not a ``ValueError``) in whatever parses it, and a body
nested a few hundred deep parses but may exhaust the stack of the code that walks it next
(validation, ``json.dumps`` when it is stored). No request of this API nests deeper than
about 6 (a plan JSON: ``points.indices[i][j]``), so a bound of 64 costs nothing and ends the
class of failure, as Jackson's ``StreamReadConstraints.maxNestingDepth`` (1000) and Go's
``encoding/json`` (10 000) bound it.

A body is JSON when its ``Content-Type`` is ``application/json`` or ``application/…+json``,
or is absent (FastAPI and the plan routes read a body without one as JSON). The depth is
counted on the bytes (strings and their escapes skipped; :func:`json_depth`), in C-speed
passes (a 32 MiB plan JSON in about 0.1 s), once the body is complete and before the route
gets its last part. A body that is not well-formed is counted all the same (its parser
refuses it next).
"""
from __future__ import annotations

import re

import numpy as np
from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

__all__ = ["MAX_JSON_DEPTH", "json_depth", "is_json_body", "JsonDepthLimit"]

#: the deepest nesting of arrays and objects a JSON request body may have
MAX_JSON_DEPTH = 64

#: a JSON string, its escapes included (an unterminated one is not matched: its brackets count)
_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)
#: every byte but the four brackets, for ``bytes.translate``'s delete
_NOT_BRACKETS = bytes(b for b in range(256) if b not in b"[]{}")


def json_depth(body: bytes) -> int:
    """The deepest nesting of arrays and objects in a JSON text.

    Parameters
    ----------
    body : bytes
        The text (UTF-8, as a request body; need not be well-formed).

    Returns
    -------
    int
        0 for a scalar, 1 for ``[]`` or ``{"a": 1}``, 2 for ``[[1]]``, ...; the brackets
        inside strings do not count; a closing bracket without an opening one counts -1.

    Examples
    --------
    >>> json_depth(b'{"a": [1, {"b": "]]]"}]}')
    3
    >>> json_depth(b'"[[["')
    0
    """
    brackets = _STRING.sub(b'""', body).translate(None, _NOT_BRACKETS)
    if not brackets:
        return 0
    codes = np.frombuffer(brackets, np.uint8)
    steps = np.where((codes == ord("[")) | (codes == ord("{")), 1, -1).astype(np.int32)
    return int(np.cumsum(steps).max(initial=0))


def is_json_body(headers: list[tuple[bytes, bytes]]) -> bool:
    """Whether a request's body is read as JSON: its ``Content-Type`` is absent,
    ``application/json`` or ``application/…+json`` (any parameters).

    Parameters
    ----------
    headers : list of (bytes, bytes)
        The ASGI scope's ``headers`` (names lower-case).

    Returns
    -------
    bool
        True for a JSON body (or one that may be read as JSON).
    """
    types = [v for k, v in headers if k == b"content-type"]
    if not types:
        return True
    kind = types[0].split(b";")[0].strip().lower()
    main, _, sub = kind.partition(b"/")
    return main == b"application" and (sub == b"json" or sub.endswith(b"+json"))


def _too_deep(depth: int) -> JSONResponse:
    return JSONResponse({"detail": f"JSON nested {depth} levels deep; at most {MAX_JSON_DEPTH} levels of arrays "
                                   "and objects are accepted"}, 422)


class _TooDeep(Exception):
    pass


class JsonDepthLimit:
    """ASGI middleware: a JSON request body nested deeper than :data:`MAX_JSON_DEPTH`
    (:func:`json_depth`) is answered 422 with the depth and the bound, whatever the route.

    The body passes through as it arrives; its parts are kept until it is complete and
    counted before the last part is handed on, so no route parses a refused body. The
    refusal replaces whatever the route answered to the cut-off read (as the body limits of
    ``fpscan.service.api.upload_limit.UploadLimit`` do). The connection is kept (the body was read whole).

    Parameters
    ----------
    app : ASGI application
        The application it wraps.
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope.get("method") in ("GET", "HEAD", "OPTIONS", "DELETE") \
                or not is_json_body(scope.get("headers") or []):
            return await self.app(scope, receive, send)
        parts: list[bytes] = []
        refusal: list[JSONResponse] = []
        done = False

        async def watched_receive() -> Message:
            nonlocal done
            message = await receive()
            if done or message["type"] != "http.request":
                return message
            parts.append(message.get("body", b""))
            if not message.get("more_body", False):
                done = True
                body = b"".join(parts)
                parts.clear()
                depth = json_depth(body)
                if depth > MAX_JSON_DEPTH:
                    refusal.append(_too_deep(depth))
                    raise _TooDeep
            return message

        sent = False

        async def guarded_send(message: Message) -> None:
            nonlocal sent
            if refusal:
                if not sent:
                    sent = True
                    await refusal[0](scope, _no_body, send)
                return
            await send(message)

        try:
            await self.app(scope, watched_receive, guarded_send)
        except _TooDeep:
            if not sent:
                sent = True
                await refusal[0](scope, _no_body, send)


async def _no_body() -> Message:
    return {"type": "http.request", "body": b"", "more_body": False}
