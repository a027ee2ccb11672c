"""The HTTP API (FastAPI): ``create_app(settings)`` in :mod:`fpscan.service.api.app`, request and
response models in :mod:`fpscan.service.api.models` (cheap to import; the Python client uses
them), one router module per resource. Contract: docs/api.md."""

__all__: list[str] = []  # the package's API is its modules
