"""The interactive API reference page, served from installed files: ``/docs`` (Swagger UI),
nothing fetched from elsewhere at run time.

FastAPI's own pages load Swagger UI and ReDoc from a CDN at a floating major version
(``swagger-ui-dist@5``, ``redoc@2``) and start them with an inline script: a lab machine
without internet gets a blank page, and the page, which shares its origin with the web page
that keeps the token, runs whatever the CDN serves. Here Swagger UI's script and style are
the files the package ``fastapi-offline`` ships (pinned in pyproject.toml), served at
``/docs/assets/``, and the page is started by a script file of this server
(``/docs/assets/swagger-init.js``), so it runs under the server's Content-Security-Policy
(``fpscan.service.api.browser_headers``) unchanged. There is no ReDoc page (``/redoc``): ReDoc's
bundle loads its logo from its vendor's CDN whatever its options, and writes inline styles.

Source: FastAPI, "Custom Docs UI Static Assets (Self-Hosting)"
(https://fastapi.tiangolo.com/how-to/custom-docs-ui-assets/).
"""
from __future__ import annotations

import json

from fastapi import FastAPI
from starlette.requests import Request
from starlette.responses import HTMLResponse, Response
from starlette.routing import BaseRoute, Mount, Route
from starlette.staticfiles import StaticFiles

__all__ = ["ASSETS_PATH", "ASSETS_PACKAGE", "add_reference_pages"]

#: where the page's script, style and icon are served
ASSETS_PATH = "/docs/assets"
#: the installed package and its folder that hold Swagger UI's files
ASSETS_PACKAGE = ("fastapi_offline", "static")


def _swagger_init(openapi_url: str) -> bytes:
    """Swagger UI's start: ``SwaggerUIBundle`` with FastAPI's default parameters, the schema
    at ``openapi_url``, no online validator (it would send the schema elsewhere)."""
    from fastapi.openapi.docs import swagger_ui_default_parameters

    parameters = {**swagger_ui_default_parameters, "url": openapi_url, "validatorUrl": None}
    return ("\"use strict\";\n/* Swagger UI's start (fpscan.service.api.reference_pages). */\n"
            f"window.ui = SwaggerUIBundle(Object.assign({json.dumps(parameters)}, {{\n"
            "  presets: [SwaggerUIBundle.presets.apis, SwaggerUIBundle.SwaggerUIStandalonePreset],\n"
            "}));\n").encode()


def add_reference_pages(app: FastAPI) -> None:
    """Serve ``/docs`` (Swagger UI) from installed files, and its files at :data:`ASSETS_PATH`.

    The app must be made with ``docs_url=None, redoc_url=None`` (FastAPI's CDN pages off).
    Without the package that holds the files (``fastapi-offline``, part of ``fpscan[server]``)
    the page answers 503 saying so.

    Parameters
    ----------
    app : FastAPI
        The application (its ``openapi_url`` is the schema the page shows).
    """
    openapi_url = app.openapi_url or "/openapi.json"
    title = app.title
    try:
        files: StaticFiles | None = StaticFiles(packages=[ASSETS_PACKAGE])
    except (ImportError, AssertionError):  # not installed: Starlette asserts the package's folder
        files = None
    swagger_init = _swagger_init(openapi_url)

    page = ("<!doctype html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
            f"<title>{title} - Swagger UI</title>\n<link rel=\"icon\" href=\"{ASSETS_PATH}/favicon.png\">\n"
            f"<link rel=\"stylesheet\" href=\"{ASSETS_PATH}/swagger-ui.css\">\n</head>\n<body>\n"
            f"<div id=\"swagger-ui\"></div>\n<script src=\"{ASSETS_PATH}/swagger-ui-bundle.js\"></script>\n"
            f"<script src=\"{ASSETS_PATH}/swagger-init.js\"></script>\n</body>\n</html>\n")

    async def swagger_page(request: Request) -> Response:
        if files is None:
            return Response("the API reference page needs the package fastapi-offline (pip install 'fpscan[server]')",
                            status_code=503, media_type="text/plain")
        return HTMLResponse(page)

    async def swagger_start(request: Request) -> Response:
        return Response(swagger_init, media_type="text/javascript")

    routes: list[BaseRoute] = [Route("/docs", swagger_page, include_in_schema=False),
                               Route(f"{ASSETS_PATH}/swagger-init.js", swagger_start, include_in_schema=False)]
    if files is not None:
        routes.append(Mount(ASSETS_PATH, app=files, name="reference-assets"))
    app.router.routes.extend(routes)
