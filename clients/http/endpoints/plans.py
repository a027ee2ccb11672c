"""Plans: ``/api/plans`` (create, preview, list, get, the plan JSON, its picture, delete) and the
mask kinds (``/api/plans/kinds``)."""
from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from fpscan.clients.http.calls import (
    AsyncCaller,
    Call,
    Download,
    Request,
    SyncCaller,
    jsonable,
    read_json,
    read_model,
    read_models,
)

__all__ = ["Plans", "AsyncPlans"]


def _build_create_plan(body: Mapping | Any) -> Call[Any]:
    """``POST /api/plans`` (:meth:`Plans.create_plan`)."""
    return Call(Request("POST", "/api/plans", json=jsonable(body)), read_model("Plan"))


def _build_preview_plan(body: Mapping | Any) -> Call[Any]:
    """``POST /api/plans/preview`` (:meth:`Plans.preview_plan`)."""
    return Call(Request("POST", "/api/plans/preview", json=jsonable(body)), read_model("PlanPreview"))


def _build_mask_kinds() -> Call[Any]:
    """``GET /api/plans/kinds`` (:meth:`Plans.mask_kinds`)."""
    return Call(Request("GET", "/api/plans/kinds"), read_json)


def _build_list_plans() -> Call[Any]:
    """``GET /api/plans`` (:meth:`Plans.list_plans`)."""
    return Call(Request("GET", "/api/plans"), read_models("Plan"))


def _build_get_plan(plan_id: str) -> Call[Any]:
    """``GET /api/plans/{plan_id}`` (:meth:`Plans.get_plan`)."""
    return Call(Request("GET", f"/api/plans/{plan_id}"), read_model("Plan"))


def _build_get_plan_json(plan_id: str) -> Call[Any]:
    """``GET /api/plans/{plan_id}/plan.json`` (:meth:`Plans.get_plan_json`)."""
    return Call(Request("GET", f"/api/plans/{plan_id}/plan.json"), read_json)


def _build_download_plan_preview(plan_id: str, dest: str | os.PathLike) -> Download[Path]:
    """``GET /api/plans/{plan_id}/preview.png`` (:meth:`Plans.download_plan_preview`)."""
    return Download(Request("GET", f"/api/plans/{plan_id}/preview.png"), Path(dest))


def _build_delete_plan(plan_id: str) -> Call[Any]:
    """``DELETE /api/plans/{plan_id}`` (:meth:`Plans.delete_plan`)."""
    return Call(Request("DELETE", f"/api/plans/{plan_id}"), read_json)


class Plans(SyncCaller):
    """The plan endpoints of :class:`fpscan.clients.http.Client` (blocking).

    Attributes
    ----------
    None
        A mixin of methods.

    Examples
    --------
    >>> from fpscan.clients.http import Client
    >>> from fpscan.clients.http.endpoints.plans import Plans
    >>> issubclass(Client, Plans)
    True
    """

    def create_plan(self, body: Mapping | Any) -> Any:
        """``POST /api/plans``: create a plan from mask parameters or a point list.

        Parameters
        ----------
        body : Mapping or pydantic model
            The body of ``fpscan.service.api.models`` ``PlanCreate``: ``lattice`` (``n_x``, ``n_y``,
            ``pitch`` in m), ``mask`` (``kind``, ``params`` in SI units), optional ``order`` and
            ``acquisition``; or a whole plan JSON (``fpscan-plan/1``).

        Returns
        -------
        Plan or dict
            The stored plan (201; the same request gives the same plan).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (422 naming the invalid field).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_create_plan(body))

    def preview_plan(self, body: Mapping | Any) -> Any:
        """``POST /api/plans/preview``: the mask a plan body gives, nothing saved.

        Parameters
        ----------
        body : Mapping or pydantic model
            As :meth:`create_plan`.

        Returns
        -------
        PlanPreview or dict
            ``points``, ``weight_ratio``, ``expected_scan_time_s`` (s), ``preview_png_base64``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (422 naming the invalid field).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_preview_plan(body))

    def mask_kinds(self) -> Any:
        """``GET /api/plans/kinds``: the mask kinds and their parameters (SI units).

        Returns
        -------
        list of dict
            ``{kind, label, description, aliases, fields, params_schema}`` per kind.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_mask_kinds())

    def list_plans(self) -> Any:
        """``GET /api/plans``: the stored plans.

        Returns
        -------
        list of Plan or dict

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_list_plans())

    def get_plan(self, plan_id: str) -> Any:
        """``GET /api/plans/{plan_id}``: one plan's summary.

        Parameters
        ----------
        plan_id : str

        Returns
        -------
        Plan or dict

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_get_plan(plan_id))

    def get_plan_json(self, plan_id: str) -> Any:
        """``GET /api/plans/{plan_id}/plan.json``: the full plan, as ``fpscan scan`` reads it.

        Parameters
        ----------
        plan_id : str

        Returns
        -------
        dict
            The ``fpscan-plan/1`` JSON: lattice, mask, points in scan order, acquisition (SI units).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_get_plan_json(plan_id))

    def download_plan_preview(self, plan_id: str, dest: str | os.PathLike) -> Path:
        """``GET /api/plans/{plan_id}/preview.png`` (the mask picture, PNG) saved to ``dest``.

        Parameters
        ----------
        plan_id : str
        dest : str or os.PathLike
            The file to write (its folder is made; ``dest.part`` while downloading).

        Returns
        -------
        pathlib.Path
            ``dest``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_download_plan_preview(plan_id, dest))

    def delete_plan(self, plan_id: str) -> Any:
        """``DELETE /api/plans/{plan_id}``: a stored plan.

        Parameters
        ----------
        plan_id : str

        Returns
        -------
        dict
            ``{"id", "kind", "bytes_freed"}``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict (409) while an active scan uses it, NotFound
            for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_delete_plan(plan_id))


class AsyncPlans(AsyncCaller):
    """The plan endpoints of :class:`fpscan.clients.http.AsyncClient`: :class:`Plans`' methods as coroutines.

    Attributes
    ----------
    None
        A mixin of methods.

    Examples
    --------
    >>> from fpscan.clients.http import AsyncClient
    >>> from fpscan.clients.http.endpoints.plans import AsyncPlans
    >>> issubclass(AsyncClient, AsyncPlans)
    True
    """

    async def create_plan(self, body: Mapping | Any) -> Any:
        """As :meth:`Plans.create_plan`, awaited."""
        return await self._call(_build_create_plan(body))

    async def preview_plan(self, body: Mapping | Any) -> Any:
        """As :meth:`Plans.preview_plan`, awaited."""
        return await self._call(_build_preview_plan(body))

    async def mask_kinds(self) -> Any:
        """As :meth:`Plans.mask_kinds`, awaited."""
        return await self._call(_build_mask_kinds())

    async def list_plans(self) -> Any:
        """As :meth:`Plans.list_plans`, awaited."""
        return await self._call(_build_list_plans())

    async def get_plan(self, plan_id: str) -> Any:
        """As :meth:`Plans.get_plan`, awaited."""
        return await self._call(_build_get_plan(plan_id))

    async def get_plan_json(self, plan_id: str) -> Any:
        """As :meth:`Plans.get_plan_json`, awaited."""
        return await self._call(_build_get_plan_json(plan_id))

    async def download_plan_preview(self, plan_id: str, dest: str | os.PathLike) -> Path:
        """As :meth:`Plans.download_plan_preview`, awaited."""
        return await self._call(_build_download_plan_preview(plan_id, dest))

    async def delete_plan(self, plan_id: str) -> Any:
        """As :meth:`Plans.delete_plan`, awaited."""
        return await self._call(_build_delete_plan(plan_id))
