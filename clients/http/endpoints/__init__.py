"""The endpoints of the fpscan HTTP API, one module per group (``docs/api.md``).

Each module holds, for each endpoint of its group:

- a request builder ``_build_<name>(...)``: the endpoint's arguments checked (a ``ValueError``
  before any request) and turned into a :class:`~fpscan.clients.http.calls.Call` (the request and how
  its answer becomes the result) or a :class:`~fpscan.clients.http.calls.Download`;
- ``<name>`` on the group's blocking mixin (e.g. :class:`~.plans.Plans`), with the
  endpoint's full docstring: ``return self._call(_build_<name>(...))``;
- ``<name>`` on the group's asyncio mixin (e.g. :class:`~.plans.AsyncPlans`):
  ``return await self._call(_build_<name>(...))``.

:class:`fpscan.clients.http.Client` and :class:`fpscan.clients.http.AsyncClient` are the blocking and asyncio
mixins of every group over one transport each. Adding an endpoint: its builder and its two
methods in its group's module (a new group: a new module, and its mixins added to the two
client classes' bases).
"""

__all__: list[str] = []
