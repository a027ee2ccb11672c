"""The endpoints of the fpscan HTTP API, one module per group (``docs/api.md``), each declared once.

Each module holds its group's class (e.g. :class:`~.plans.Plans`) in which every endpoint is
one declaration: ``@endpoint`` (:func:`fpscan.clients.http.calls.endpoint`) over its request
builder, a function without ``self`` of the endpoint's arguments, with the endpoint's full
docstring, that checks them (a ``ValueError`` before any request) and returns a
:class:`~fpscan.clients.http.calls.Call` (the request and how its answer becomes the typed
result) or a :class:`~fpscan.clients.http.calls.Download`; its return annotation
(``Call[Job]``, ``Download[Path]``) is the result's type.

:class:`fpscan.clients.http.Client` and :class:`fpscan.clients.http.AsyncClient` are both made of
every group class: each declaration becomes a blocking method of the one and a coroutine
method of the other, with the same parameters, docstring and return type
(:class:`~fpscan.clients.http.calls.SyncCaller`, :class:`~fpscan.clients.http.calls.AsyncCaller`).
Adding an endpoint: its declaration in its group's class (a new group: a new module, and its
class added to the two client classes' bases).
"""

__all__: list[str] = []
