"""The app's OpenAPI schema: it states whether routes need the token, and is served as
bytes rendered once."""
from __future__ import annotations

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from fpscan.service.settings import Settings

__all__ = ["state_security_in_openapi", "render_openapi_once"]


def state_security_in_openapi(app: FastAPI, settings: Settings) -> None:
    """Make the app's OpenAPI schema say whether routes need the token.

    With a token configured (``settings.token`` or ``settings.token_file``) every API route
    needs it, as FastAPI's schema says; without one (a loopback-only server) none does: each
    operation's ``security`` lists the empty requirement first. Wraps ``app.openapi``.

    Parameters
    ----------
    app : FastAPI
        The application, its routes added.
    settings : Settings
        The service's settings (whether a token is configured).
    """
    base_openapi = app.openapi

    def openapi() -> dict:
        """The schema states what the server enforces: with a token configured every API
        route needs it; without one (a loopback-only server) none does (``security``
        lists the empty requirement first)."""
        done = app.openapi_schema is not None
        schema = base_openapi()
        if not done and settings.token is None and settings.token_file is None:
            for item in schema.get("paths", {}).values():
                for op in item.values():
                    if isinstance(op, dict) and op.get("security") and {} not in op["security"]:
                        op["security"] = [{}, *op["security"]]
        return schema

    app.openapi = openapi  # type: ignore[method-assign]


def render_openapi_once(app: FastAPI) -> None:
    """Serve ``/openapi.json`` as bytes rendered once.

    The schema (some 100 kB of JSON) does not change while the server runs, and FastAPI's
    own route serialises it on the event loop at every request (a few ms each: strangers
    pipelining it held the loop for seconds). Replaces that route.

    Parameters
    ----------
    app : FastAPI
        The application, its routes added and its ``openapi`` final
        (:func:`state_security_in_openapi` before this).
    """
    from starlette.responses import Response
    from starlette.routing import Route

    rendered: list[bytes] = []

    async def openapi(request: Request) -> Response:
        if not rendered:
            rendered.append(bytes(JSONResponse(app.openapi()).body))
        return Response(rendered[0], media_type="application/json")

    for i, route in enumerate(app.router.routes):
        if isinstance(route, Route) and route.path == app.openapi_url:
            app.router.routes[i] = Route(route.path, openapi, include_in_schema=False)
