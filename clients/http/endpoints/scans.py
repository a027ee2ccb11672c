"""Scanners and scans: ``/api/scanners`` and ``/api/scans`` (start, pause, resume, abort, the
scan file, the live preview; a scan's exports are a job's: :meth:`fpscan.clients.http.Client.export`)."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from fpscan.clients.http.calls import (
    AsyncCaller,
    Call,
    Download,
    Request,
    SyncCaller,
    check_plane,
    idempotency,
    read_job_id,
    read_model,
    read_models,
)

__all__ = ["Scans", "AsyncScans"]


def _build_scanners() -> Call[Any]:
    """``GET /api/scanners`` (:meth:`Scans.scanners`)."""
    return Call(Request("GET", "/api/scanners"), read_models("Scanner"))


def _build_start_scan(plan_id: str, scanner_id: str, idempotency_key: str | None,
                     extra: dict[str, Any]) -> Call[str | None]:
    """``POST /api/scans`` (:meth:`Scans.start_scan`)."""
    body = {"plan_id": plan_id, "scanner_id": scanner_id, **extra}
    return Call(Request("POST", "/api/scans", json=body, headers=idempotency(idempotency_key)), read_job_id)


def _build_scan_action(job_id: str, action: str) -> Call[Any]:
    """``POST /api/scans/{job_id}/{pause|resume|abort}`` (:meth:`Scans.pause_scan`, ...)."""
    return Call(Request("POST", f"/api/scans/{job_id}/{action}"), read_model("Job", empty_ok=True))


def _build_download_scan(job_id: str, dest: str | os.PathLike) -> Download[Path]:
    """``GET /api/scans/{job_id}/file`` (:meth:`Scans.download_scan`)."""
    return Download(Request("GET", f"/api/scans/{job_id}/file"), Path(dest))


def _build_scan_preview(job_id: str) -> Call[Any]:
    """``GET /api/scans/{job_id}/preview`` (:meth:`Scans.scan_preview`)."""
    return Call(Request("GET", f"/api/scans/{job_id}/preview"), read_model("PreviewInfo"))


def _build_download_scan_preview(job_id: str, plane: str, dest: str | os.PathLike) -> Download[Path]:
    """``GET /api/scans/{job_id}/preview/{plane}.png`` (:meth:`Scans.download_scan_preview`)."""
    check_plane(plane)
    return Download(Request("GET", f"/api/scans/{job_id}/preview/{plane}.png"), Path(dest))


class Scans(SyncCaller):
    """The scanner and scan endpoints of :class:`fpscan.clients.http.Client` (blocking).

    Attributes
    ----------
    None
        A mixin of methods.

    Examples
    --------
    >>> from fpscan.clients.http import Client
    >>> from fpscan.clients.http.endpoints.scans import Scans
    >>> issubclass(Client, Scans)
    True
    """

    def scanners(self) -> Any:
        """``GET /api/scanners``: the configured serial devices and their status.

        Returns
        -------
        list of Scanner or dict

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_scanners())

    def start_scan(self, plan_id: str, scanner_id: str, *, idempotency_key: str | None = None,
                   **extra: Any) -> str | None:
        """``POST /api/scans`` ``{plan_id, scanner_id}``: start a scan job.

        Parameters
        ----------
        plan_id : str
        scanner_id : str
            A scanner of :meth:`scanners`.
        idempotency_key : str, optional
            Same key -> same job (default: a fresh random key).
        **extra
            Further body fields, e.g. ``preview_wavelength=1`` (the wavelength the live preview
            shows).

        Returns
        -------
        str
            The new scan job's id (202).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown plan or scanner).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_start_scan(plan_id, scanner_id, idempotency_key, extra))

    def pause_scan(self, job_id: str) -> Any:
        """``POST /api/scans/{job_id}/pause``: pause a running scan.

        Parameters
        ----------
        job_id : str

        Returns
        -------
        Job or dict or None
            The job (None for an empty answer).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict (409) if not running, NotFound for an
            unknown job).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_scan_action(job_id, "pause"))

    def resume_scan(self, job_id: str) -> Any:
        """``POST /api/scans/{job_id}/resume``: resume a paused (or interrupted) scan.

        Parameters
        ----------
        job_id : str

        Returns
        -------
        Job or dict or None
            The job (None for an empty answer).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict (409) if not paused, NotFound for an
            unknown job).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_scan_action(job_id, "resume"))

    def abort_scan(self, job_id: str) -> Any:
        """``POST /api/scans/{job_id}/abort``: stop a scan; it ends ``cancelled``.

        Parameters
        ----------
        job_id : str

        Returns
        -------
        Job or dict or None
            The job (None for an empty answer).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict for a finished job, NotFound for an
            unknown one).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_scan_action(job_id, "abort"))

    def download_scan(self, job_id: str, dest: str | os.PathLike) -> Path:
        """``GET /api/scans/{job_id}/file`` (the scan file, HDF5) saved to ``dest``.

        Parameters
        ----------
        job_id : str
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
        return self._call(_build_download_scan(job_id, dest))

    def scan_preview(self, job_id: str) -> Any:
        """``GET /api/scans/{job_id}/preview``: the live preview's state.

        Parameters
        ----------
        job_id : str

        Returns
        -------
        PreviewInfo or dict
            ``version``, ``points_used``, ``updated`` (UNIX s), ...

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_scan_preview(job_id))

    def download_scan_preview(self, job_id: str, plane: str, dest: str | os.PathLike) -> Path:
        """``GET /api/scans/{job_id}/preview/{plane}.png`` (live MIP, PNG) saved to ``dest``.

        Parameters
        ----------
        job_id : str
        plane : {"xy", "xz", "yz"}
            The MIP's plane.
        dest : str or os.PathLike
            The file to write (its folder is made; ``dest.part`` while downloading).

        Returns
        -------
        pathlib.Path
            ``dest``.

        Raises
        ------
        ValueError
            An unknown plane (before any request).
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_download_scan_preview(job_id, plane, dest))


class AsyncScans(AsyncCaller):
    """The scanner and scan endpoints of :class:`fpscan.clients.http.AsyncClient`: :class:`Scans`'
    methods as coroutines.

    Attributes
    ----------
    None
        A mixin of methods.

    Examples
    --------
    >>> from fpscan.clients.http import AsyncClient
    >>> from fpscan.clients.http.endpoints.scans import AsyncScans
    >>> issubclass(AsyncClient, AsyncScans)
    True
    """

    async def scanners(self) -> Any:
        """As :meth:`Scans.scanners`, awaited."""
        return await self._call(_build_scanners())

    async def start_scan(self, plan_id: str, scanner_id: str, *, idempotency_key: str | None = None,
                         **extra: Any) -> str | None:
        """As :meth:`Scans.start_scan`, awaited."""
        return await self._call(_build_start_scan(plan_id, scanner_id, idempotency_key, extra))

    async def pause_scan(self, job_id: str) -> Any:
        """As :meth:`Scans.pause_scan`, awaited."""
        return await self._call(_build_scan_action(job_id, "pause"))

    async def resume_scan(self, job_id: str) -> Any:
        """As :meth:`Scans.resume_scan`, awaited."""
        return await self._call(_build_scan_action(job_id, "resume"))

    async def abort_scan(self, job_id: str) -> Any:
        """As :meth:`Scans.abort_scan`, awaited."""
        return await self._call(_build_scan_action(job_id, "abort"))

    async def download_scan(self, job_id: str, dest: str | os.PathLike) -> Path:
        """As :meth:`Scans.download_scan`, awaited."""
        return await self._call(_build_download_scan(job_id, dest))

    async def scan_preview(self, job_id: str) -> Any:
        """As :meth:`Scans.scan_preview`, awaited."""
        return await self._call(_build_scan_preview(job_id))

    async def download_scan_preview(self, job_id: str, plane: str, dest: str | os.PathLike) -> Path:
        """As :meth:`Scans.download_scan_preview`, awaited."""
        return await self._call(_build_download_scan_preview(job_id, plane, dest))
