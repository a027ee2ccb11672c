"""The HTTP client's endpoints are declared once and typed: ``Client`` and ``AsyncClient``
offer the same endpoints with the same signatures and precise return types (never ``Any``),
and what a real ``fpscan serve`` answers comes back as those types, holding what the raw
HTTP answer holds.

Oracles: the declarations themselves (``fpscan.clients.http.calls.endpoints_of``) for the
two clients' methods; the raw HTTP answer of the same request (httpx, no client code) for
the values; ``typing`` for the types."""
from __future__ import annotations

import asyncio
import inspect
import types
import typing
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from fpscan.clients.http import AsyncClient, Client, to_dict
from fpscan.clients.http.calls import Endpoint, endpoints_of
from fpscan.clients.http.models import DICTS, MODELS
from tests.clients.clients_servers import has_command

TOKEN = "client-typing-token"

pytestmark = pytest.mark.skipif(not has_command("serve"), reason="`fpscan serve` not available yet")


def _public_methods(cls: type) -> dict[str, Any]:
    return {name: getattr(cls, name) for name in dir(cls)
            if not name.startswith("_") and inspect.isfunction(getattr(cls, name))}


def _mentions_any(tp: Any) -> bool:
    """``tp`` is ``Any``, or a union with ``Any`` in it (``Any | None``)."""
    return tp is Any or any(arg is Any for arg in typing.get_args(tp)
                            if typing.get_origin(tp) in (typing.Union, types.UnionType))


@pytest.mark.parametrize("cls", [Client, AsyncClient])
def test_every_public_method_has_a_precise_return_type(cls):
    methods = _public_methods(cls)
    assert len(methods) > 40, sorted(methods)
    for name, fn in methods.items():
        hints = typing.get_type_hints(fn)
        assert "return" in hints, f"{cls.__name__}.{name} has no return annotation"
        assert not _mentions_any(hints["return"]), f"{cls.__name__}.{name} returns {hints['return']}"


def test_both_clients_offer_the_same_endpoints_from_one_declaration():
    sync, awaited = endpoints_of(Client), endpoints_of(AsyncClient)
    assert sync and set(sync) == set(awaited)
    for name, declared in sync.items():
        assert awaited[name] is declared, name  # one declaration, not two
        assert isinstance(declared, Endpoint)
        s, a = getattr(Client, name), getattr(AsyncClient, name)
        assert inspect.signature(s) == inspect.signature(a), name
        assert typing.get_type_hints(s) == typing.get_type_hints(a), name
        assert typing.get_type_hints(s)["return"] == declared.result_type(), name
        assert not inspect.iscoroutinefunction(s) and inspect.iscoroutinefunction(a), name
        assert s.__doc__ == a.__doc__ == declared.build.__doc__ and "Returns" in s.__doc__, name
        # the method's parameters are the declaration's (self first)
        assert list(inspect.signature(s).parameters)[1:] == list(inspect.signature(declared.build).parameters)
    # the rest of the public methods are the clients' own: the connection, events and wait
    own = set(_public_methods(Client)) - set(sync)
    assert own == {"close", "events", "wait", "headers", "unavailable"}, own
    assert set(_public_methods(AsyncClient)) - set(sync) == own - {"close"} | {"aclose"}
    for name in ("events", "wait"):
        s, a = inspect.signature(getattr(Client, name)), inspect.signature(getattr(AsyncClient, name))
        assert s.parameters == a.parameters, name
    assert typing.get_type_hints(Client.wait)["return"] is typing.get_type_hints(AsyncClient.wait)["return"]


def test_a_subclass_keeps_its_own_methods_and_the_endpoints():
    class Logged(Client):
        def health(self):  # written by hand: not an endpoint method any more
            return "mine"

    assert "health" not in endpoints_of(Logged) and "get_job" in endpoints_of(Logged)
    assert Logged.get_job is Client.get_job
    with Logged("http://127.0.0.1:9", token="") as api:
        assert api.health() == "mine"


@pytest.fixture()
def api(server):
    with Client(server, token=TOKEN) as c:
        yield c


def _raw(server: str, method: str, path: str, **kwargs) -> Any:
    r = httpx.request(method, server + path, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30, **kwargs)
    r.raise_for_status()
    return r.json()


def _json(value: Any) -> Any:
    """An answer as the JSON it came from: models dumped, lists item by item."""
    if isinstance(value, list):
        return [_json(v) for v in value]
    return to_dict(value)


def _check_type(value: Any, tp: Any) -> None:
    """``value`` is an instance of the annotation ``tp`` (a model, a TypedDict, ``list[...]``,
    ``dict[str, Any]``, ``str``, ``X | None``)."""
    origin = typing.get_origin(tp)
    if origin is list:
        assert isinstance(value, list), (value, tp)
        for item in value:
            _check_type(item, typing.get_args(tp)[0])
    elif origin is dict or tp in DICTS.values():
        assert isinstance(value, dict), (value, tp)
        if tp in DICTS.values():
            assert set(value) == set(tp.__annotations__), (set(value) ^ set(tp.__annotations__), tp)
    elif origin is not None:  # X | None
        assert any(isinstance(value, a if a is not type(None) else type(None)) for a in typing.get_args(tp))
    else:
        assert isinstance(value, tp), (type(value), tp)


def test_answers_are_the_declared_types_and_hold_the_raw_answer(api, server, tmp_path):
    np.save(tmp_path / "data.npy", np.zeros((32, 4, 4), np.float32))
    dataset_id = api.upload_dataset(tmp_path / "data.npy", "npy", dt=2e-8, dx=1e-4, dy=1e-4)
    plan = api.create_plan({"lattice": {"n_x": 4, "n_y": 4, "pitch": 1e-4}, "points": [[0, 0], [1, 2]],
                            "acquisition": {"n_t": 32, "dt": 2e-8, "prf": 0}})
    # endpoint -> (its call, the raw request that answers the same)
    cases = {
        "health": ((), ("GET", "/api/health")),
        "auth": ((), ("GET", "/api/auth")),
        "retention": ((), ("GET", "/api/retention")),
        "methods": ((), ("GET", "/api/reconstructions/methods")),
        "formats": ((), ("GET", "/api/formats")),
        "dataset_formats": ((), ("GET", "/api/datasets/formats")),
        "list_datasets": ((), ("GET", "/api/datasets")),
        "mask_kinds": ((), ("GET", "/api/plans/kinds")),
        "list_plans": ((), ("GET", "/api/plans")),
        "get_plan": ((plan.id,), ("GET", f"/api/plans/{plan.id}")),
        "get_plan_json": ((plan.id,), ("GET", f"/api/plans/{plan.id}/plan.json")),
        "scanners": ((), ("GET", "/api/scanners")),
        "list_jobs": ((), ("GET", "/api/jobs")),
    }
    for name, (args, (method, path)) in cases.items():
        got = getattr(api, name)(*args)
        _check_type(got, typing.get_type_hints(getattr(Client, name))["return"])
        raw = _raw(server, method, path)
        assert _json(got) == (raw["items"] if isinstance(raw, dict) and "items" in raw and name.startswith("list")
                              else raw), name

    # the answers that were dicts before read like dicts still (code indexing them keeps working)
    health = api.health()
    assert health["status"] == "ok" and health.get("version") == health.version and "devices" in health
    assert dict(health)["executor"] == health.executor
    rows = api.list_datasets()
    assert [d["dataset_id"] for d in rows] == [dataset_id] and rows[0].get("in_use") is False
    fmts = {f["name"]: f for f in api.formats()}
    assert fmts["npy"]["upload"] is True and fmts["npy"].get("no such field", "x") == "x"
    assert all(isinstance(m["name"], str) and isinstance(m.get("default_for"), list) for m in api.methods())

    # deletions answer a typed dict with the raw answer's keys
    gone = api.delete_dataset(dataset_id)
    _check_type(gone, typing.get_type_hints(Client.delete_dataset)["return"])
    assert gone["id"] == dataset_id and gone["kind"] == "dataset" and gone["bytes_freed"] > 0

    async def main():
        async with AsyncClient(server, token=TOKEN) as c:
            return await c.health(), await c.methods(), await c.formats(), await c.get_plan(plan.id)

    a_health, a_methods, a_formats, a_plan = asyncio.run(main())
    assert type(a_health) is type(health) and a_health.version == health.version
    assert a_methods == api.methods() and a_formats == api.formats() and a_plan == plan


def test_client_dicts_mirror_the_servers_schema(server):
    """The answers typed as dicts (``fpscan.clients.http.models.DICTS``) have exactly the keys of
    the server's response schemas of the same name in the live OpenAPI document, as the
    models (``MODELS``) have its fields."""
    schemas = httpx.get(server + "/openapi.json").json()["components"]["schemas"]
    for name, typed in DICTS.items():
        assert name in schemas, f"the server has no {name} schema"
        assert set(typed.__annotations__) == set(schemas[name]["properties"]), name
    assert {"Health", "DiskUse", "ComputeDevice", "MethodInfo", "MethodOption", "FormatInfo", "DatasetFormatInfo",
            "Dataset", "DatasetInfo"} <= set(MODELS)


def test_downloads_return_their_path(api, tmp_path):
    plan = api.create_plan({"lattice": {"n_x": 4, "n_y": 4, "pitch": 1e-4}, "points": [[0, 0], [3, 3]],
                            "acquisition": {"n_t": 32, "dt": 2e-8, "prf": 0}})
    got = api.download_plan_preview(plan.id, tmp_path / "mask.png")
    assert isinstance(got, Path) and got == tmp_path / "mask.png" and got.read_bytes()[:4] == b"\x89PNG"
