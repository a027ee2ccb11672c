"""Plans: ``/api/plans`` (create, preview, list, get, the plan JSON, its picture, delete) and the
mask kinds (``/api/plans/kinds``)."""
from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from fpscan.clients.http.calls import (
    Call,
    Download,
    Request,
    endpoint,
    jsonable,
    read_json,
    read_model,
    read_models,
)
from fpscan.clients.http.models import Deleted, MaskKindInfo, Plan, PlanPreview

__all__ = ["Plans"]


class Plans:
    """The plan endpoints, declared once (:func:`~fpscan.clients.http.calls.endpoint`): methods of
    :class:`fpscan.clients.http.Client` and, as coroutines, of :class:`fpscan.clients.http.AsyncClient`.

    Attributes
    ----------
    create_plan, preview_plan, mask_kinds, list_plans, get_plan, get_plan_json, download_plan_preview, delete_plan : Endpoint
        The declarations.

    Examples
    --------
    >>> from fpscan.clients.http import Client
    >>> from fpscan.clients.http.endpoints.plans import Plans
    >>> issubclass(Client, Plans)
    True
    >>> call = Plans.create_plan.build({"lattice": {"n_x": 5, "n_y": 5, "pitch": 1e-4}, "mask": {"kind": "full"}})
    >>> call.request.method, call.request.path, call.request.json["mask"]
    ('POST', '/api/plans', {'kind': 'full'})
    >>> Plans.download_plan_preview.build("p1", "mask.png").dest.name
    'mask.png'
    """

    @endpoint
    def create_plan(body: Mapping | Any) -> Call[Plan]:
        """``POST /api/plans``: create a plan from mask parameters or a point list.

        Parameters
        ----------
        body : Mapping or pydantic model
            The body of ``fpscan.service.api.models`` ``PlanCreate``: ``lattice`` (``n_x``, ``n_y``,
            ``pitch`` in m), ``mask`` (``kind``, ``params`` in SI units), optional ``order`` and
            ``acquisition``; or a whole plan JSON (``fpscan-plan/1``).

        Returns
        -------
        Plan
            The stored plan (201; the same request gives the same plan).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (422 naming the invalid field).
        ServerUnavailable
            The server cannot be reached.
        """
        return Call(Request("POST", "/api/plans", json=jsonable(body)), read_model(Plan))

    @endpoint
    def preview_plan(body: Mapping | Any) -> Call[PlanPreview]:
        """``POST /api/plans/preview``: the mask a plan body gives, nothing saved.

        Parameters
        ----------
        body : Mapping or pydantic model
            As :meth:`create_plan`.

        Returns
        -------
        PlanPreview
            ``points``, ``weight_ratio``, ``expected_scan_time_s`` (s), ``preview_png_base64``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (422 naming the invalid field).
        ServerUnavailable
            The server cannot be reached.
        """
        return Call(Request("POST", "/api/plans/preview", json=jsonable(body)), read_model(PlanPreview))

    @endpoint
    def mask_kinds() -> Call[list[MaskKindInfo]]:
        """``GET /api/plans/kinds``: the mask kinds and their parameters (SI units).

        Returns
        -------
        list of dict
            ``{kind, label, description, aliases, fields, params_schema}`` per kind
            (:class:`~fpscan.clients.http.models.MaskKindInfo`).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        return Call(Request("GET", "/api/plans/kinds"), read_json)

    @endpoint
    def list_plans() -> Call[list[Plan]]:
        """``GET /api/plans``: the stored plans.

        Returns
        -------
        list of Plan

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        return Call(Request("GET", "/api/plans"), read_models(Plan))

    @endpoint
    def get_plan(plan_id: str) -> Call[Plan]:
        """``GET /api/plans/{plan_id}``: one plan's summary.

        Parameters
        ----------
        plan_id : str

        Returns
        -------
        Plan

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return Call(Request("GET", f"/api/plans/{plan_id}"), read_model(Plan))

    @endpoint
    def get_plan_json(plan_id: str) -> Call[dict[str, Any]]:
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
        return Call(Request("GET", f"/api/plans/{plan_id}/plan.json"), read_json)

    @endpoint
    def download_plan_preview(plan_id: str, dest: str | os.PathLike) -> Download[Path]:
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
        return Download(Request("GET", f"/api/plans/{plan_id}/preview.png"), Path(dest))

    @endpoint
    def delete_plan(plan_id: str) -> Call[Deleted]:
        """``DELETE /api/plans/{plan_id}``: a stored plan.

        Parameters
        ----------
        plan_id : str

        Returns
        -------
        dict
            ``{"id", "kind", "bytes_freed"}`` (:class:`~fpscan.clients.http.models.Deleted`).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict (409) while an active scan uses it, NotFound
            for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return Call(Request("DELETE", f"/api/plans/{plan_id}"), read_json)
