"""Jobs: ``/api/jobs`` (list, one job, cancel, delete, its file exported in a registered format).
Following a job's events and waiting for its end are the clients' own
(:meth:`fpscan.clients.http.Client.events`, ``wait``): they send many requests."""
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
    read_json,
    read_model,
    read_models,
)
from fpscan.clients.http.transport import unzip_folder

__all__ = ["Jobs", "AsyncJobs"]


def _build_list_jobs(state: str | None, kind: str | None) -> Call[Any]:
    """``GET /api/jobs?state=&kind=`` (:meth:`Jobs.list_jobs`)."""
    params = {k: v for k, v in (("state", state), ("kind", kind)) if v}
    return Call(Request("GET", "/api/jobs", params=params or None), read_models("Job"))


def _build_get_job(job_id: str) -> Call[Any]:
    """``GET /api/jobs/{job_id}`` (:meth:`Jobs.get_job`)."""
    return Call(Request("GET", f"/api/jobs/{job_id}"), read_model("Job"))


def _build_cancel_job(job_id: str) -> Call[Any]:
    """``POST /api/jobs/{job_id}/cancel`` (:meth:`Jobs.cancel_job`)."""
    return Call(Request("POST", f"/api/jobs/{job_id}/cancel"), read_model("Job", empty_ok=True))


def _build_delete_job(job_id: str) -> Call[Any]:
    """``DELETE /api/jobs/{job_id}`` (:meth:`Jobs.delete_job`)."""
    return Call(Request("DELETE", f"/api/jobs/{job_id}"), read_json)


def _build_export(job_id: str, format: str, dest: str | os.PathLike, wavelength: int | None) -> Download[Path]:
    """``GET /api/jobs/{job_id}/export/{format}`` (:meth:`Jobs.export`), downloaded beside
    ``dest`` (resumable) and then put in place: a zipped folder export (``Content-Type:
    application/zip``) unpacked into the folder ``dest`` unless ``dest`` ends in ``.zip``."""
    dest = Path(dest)
    if not format or "/" in format:
        raise ValueError(f"format must be an export format's name, got {format!r}")
    keep_zip = dest.name.endswith(".zip")

    def finish(got: Path, content_type: str) -> Path:
        if keep_zip:
            return got
        if content_type.split(";")[0].strip() != "application/zip":
            os.replace(got, dest)  # a file export: into place
            return dest
        try:
            return unzip_folder(got, dest)
        finally:
            got.unlink(missing_ok=True)

    params = None if wavelength is None else {"wavelength": int(wavelength)}
    return Download(Request("GET", f"/api/jobs/{job_id}/export/{format}", params=params),
                    dest if keep_zip else dest.with_name(f".{dest.name}.download"), finish)


class Jobs(SyncCaller):
    """The job endpoints of :class:`fpscan.clients.http.Client` (blocking).

    Attributes
    ----------
    None
        A mixin of methods.

    Examples
    --------
    >>> from fpscan.clients.http import Client
    >>> from fpscan.clients.http.endpoints.jobs import Jobs
    >>> issubclass(Client, Jobs)
    True
    """

    def list_jobs(self, *, state: str | None = None, kind: str | None = None) -> Any:
        """``GET /api/jobs?state=&kind=``: the jobs, newest first.

        Parameters
        ----------
        state : str, optional
            Only jobs in this state (``queued``, ``running``, ``paused``, ``succeeded``,
            ``failed``, ``cancelled``).
        kind : str, optional
            Only jobs of this kind.

        Returns
        -------
        list of Job or dict

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_list_jobs(state, kind))

    def get_job(self, job_id: str) -> Any:
        """``GET /api/jobs/{job_id}``: one job.

        Parameters
        ----------
        job_id : str

        Returns
        -------
        Job or dict
            ``id, kind, state, progress, timings, params, links, error``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_get_job(job_id))

    def cancel_job(self, job_id: str) -> Any:
        """``POST /api/jobs/{job_id}/cancel``: cancel a job (cooperative).

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
        return self._call(_build_cancel_job(job_id))

    def delete_job(self, job_id: str) -> Any:
        """``DELETE /api/jobs/{job_id}``: a finished job and its files.

        Parameters
        ----------
        job_id : str

        Returns
        -------
        dict
            ``{"id", "kind", "bytes_freed"}``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict (409) while the job or a job reading it is
            active, NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_delete_job(job_id))

    def export(self, job_id: str, format: str, dest: str | os.PathLike, *,
               wavelength: int | None = None) -> Path:
        """``GET /api/jobs/{job_id}/export/{format}``: a job's file in an export format, saved to ``dest``.

        A scan job exports its scan file, a reconstruction its p0 volume: the formats of the
        server's registry (:meth:`formats`; a job's ``export_<format>`` links name those it
        offers), e.g. ``ipasc`` (a scan), ``ome-tiff`` and ``ome-zarr`` (a volume, voxel sizes in
        µm), ``fpscan`` / ``result`` (the file itself). A folder export (OME-Zarr) comes zipped and
        is unpacked into the folder ``dest`` (kept zipped when ``dest`` ends in ``.zip``).

        Parameters
        ----------
        job_id : str
        format : str
            The export format's name.
        dest : str or os.PathLike
            The file (or folder) to write; its folder is made; an existing folder there is replaced.
        wavelength : int, optional
            Wavelength k's volume of a reconstruction over every wavelength.

        Returns
        -------
        pathlib.Path
            ``dest``.

        Raises
        ------
        ValueError
            An empty format name (before any request); a zip that is not one folder.
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown job or a format the job
            does not export, naming those it does; Conflict while its result is not there).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_export(job_id, format, dest, wavelength))


class AsyncJobs(AsyncCaller):
    """The job endpoints of :class:`fpscan.clients.http.AsyncClient`: :class:`Jobs`' methods as coroutines.

    Attributes
    ----------
    None
        A mixin of methods.

    Examples
    --------
    >>> from fpscan.clients.http import AsyncClient
    >>> from fpscan.clients.http.endpoints.jobs import AsyncJobs
    >>> issubclass(AsyncClient, AsyncJobs)
    True
    """

    async def list_jobs(self, *, state: str | None = None, kind: str | None = None) -> Any:
        """As :meth:`Jobs.list_jobs`, awaited."""
        return await self._call(_build_list_jobs(state, kind))

    async def get_job(self, job_id: str) -> Any:
        """As :meth:`Jobs.get_job`, awaited."""
        return await self._call(_build_get_job(job_id))

    async def cancel_job(self, job_id: str) -> Any:
        """As :meth:`Jobs.cancel_job`, awaited."""
        return await self._call(_build_cancel_job(job_id))

    async def delete_job(self, job_id: str) -> Any:
        """As :meth:`Jobs.delete_job`, awaited."""
        return await self._call(_build_delete_job(job_id))

    async def export(self, job_id: str, format: str, dest: str | os.PathLike, *,
                     wavelength: int | None = None) -> Path:
        """As :meth:`Jobs.export`, awaited."""
        return await self._call(_build_export(job_id, format, dest, wavelength))
