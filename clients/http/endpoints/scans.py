"""Scanners and scans: ``/api/scanners`` and ``/api/scans`` (start, pause, resume, abort, the
scan file, the live preview; a scan's exports are a job's: :meth:`fpscan.clients.http.Client.export`)."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from fpscan.clients.http.calls import (
    Call,
    Download,
    Request,
    check_plane,
    endpoint,
    idempotency,
    read_job_id,
    read_model,
    read_models,
    read_optional_model,
)
from fpscan.clients.http.models import Job, PreviewInfo, Scanner

__all__ = ["Scans"]


def _scan_action(job_id: str, action: str) -> Call[Job | None]:
    """``POST /api/scans/{job_id}/{pause|resume|abort}``."""
    return Call(Request("POST", f"/api/scans/{job_id}/{action}"), read_optional_model(Job))


class Scans:
    """The scanner and scan endpoints, declared once (:func:`~fpscan.clients.http.calls.endpoint`):
    methods of :class:`fpscan.clients.http.Client` and, as coroutines, of
    :class:`fpscan.clients.http.AsyncClient`.

    Attributes
    ----------
    scanners, start_scan, pause_scan, resume_scan, abort_scan, download_scan, scan_preview, download_scan_preview : Endpoint
        The declarations.

    Examples
    --------
    >>> from fpscan.clients.http import Client
    >>> from fpscan.clients.http.endpoints.scans import Scans
    >>> issubclass(Client, Scans)
    True
    >>> call = Scans.start_scan.build("p1", "sim", idempotency_key="k1", preview_wavelength=1)
    >>> call.request.json, call.request.headers
    ({'plan_id': 'p1', 'scanner_id': 'sim', 'preview_wavelength': 1}, {'Idempotency-Key': 'k1'})
    >>> Scans.pause_scan.build("j1").request.path
    '/api/scans/j1/pause'
    """

    @endpoint
    def scanners() -> Call[list[Scanner]]:
        """``GET /api/scanners``: the configured serial devices and their status.

        Returns
        -------
        list of Scanner

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        return Call(Request("GET", "/api/scanners"), read_models(Scanner))

    @endpoint
    def start_scan(plan_id: str, scanner_id: str, *, idempotency_key: str | None = None,
                   **extra: Any) -> Call[str | None]:
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
        body = {"plan_id": plan_id, "scanner_id": scanner_id, **extra}
        return Call(Request("POST", "/api/scans", json=body, headers=idempotency(idempotency_key)), read_job_id)

    @endpoint
    def pause_scan(job_id: str) -> Call[Job | None]:
        """``POST /api/scans/{job_id}/pause``: pause a running scan.

        Parameters
        ----------
        job_id : str

        Returns
        -------
        Job or None
            The job (None for an empty answer).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict (409) if not running, NotFound for an
            unknown job).
        ServerUnavailable
            The server cannot be reached.
        """
        return _scan_action(job_id, "pause")

    @endpoint
    def resume_scan(job_id: str) -> Call[Job | None]:
        """``POST /api/scans/{job_id}/resume``: resume a paused (or interrupted) scan.

        Parameters
        ----------
        job_id : str

        Returns
        -------
        Job or None
            The job (None for an empty answer).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict (409) if not paused, NotFound for an
            unknown job).
        ServerUnavailable
            The server cannot be reached.
        """
        return _scan_action(job_id, "resume")

    @endpoint
    def abort_scan(job_id: str) -> Call[Job | None]:
        """``POST /api/scans/{job_id}/abort``: stop a scan; it ends ``cancelled``.

        Parameters
        ----------
        job_id : str

        Returns
        -------
        Job or None
            The job (None for an empty answer).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict for a finished job, NotFound for an
            unknown one).
        ServerUnavailable
            The server cannot be reached.
        """
        return _scan_action(job_id, "abort")

    @endpoint
    def download_scan(job_id: str, dest: str | os.PathLike) -> Download[Path]:
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
        return Download(Request("GET", f"/api/scans/{job_id}/file"), Path(dest))

    @endpoint
    def scan_preview(job_id: str) -> Call[PreviewInfo]:
        """``GET /api/scans/{job_id}/preview``: the live preview's state.

        Parameters
        ----------
        job_id : str

        Returns
        -------
        PreviewInfo
            ``version``, ``points_used``, ``updated`` (UNIX s), ...

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return Call(Request("GET", f"/api/scans/{job_id}/preview"), read_model(PreviewInfo))

    @endpoint
    def download_scan_preview(job_id: str, plane: str, dest: str | os.PathLike) -> Download[Path]:
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
        check_plane(plane)
        return Download(Request("GET", f"/api/scans/{job_id}/preview/{plane}.png"), Path(dest))
