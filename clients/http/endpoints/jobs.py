"""Jobs: ``/api/jobs`` (list, one job, cancel, delete). Following a job's events and waiting
for its end are the clients' own (:meth:`clients.http.Client.events`, ``wait``): they send many
requests."""
from __future__ import annotations

from typing import Any

from ..calls import AsyncCaller, Call, Request, SyncCaller, read_json, read_model, read_models

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


class Jobs(SyncCaller):
    """The job endpoints of :class:`clients.http.Client` (blocking).

    Attributes
    ----------
    None
        A mixin of methods.

    Examples
    --------
    >>> from clients.http import Client
    >>> from clients.http.endpoints.jobs import Jobs
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


class AsyncJobs(AsyncCaller):
    """The job endpoints of :class:`clients.http.AsyncClient`: :class:`Jobs`' methods as coroutines.

    Attributes
    ----------
    None
        A mixin of methods.

    Examples
    --------
    >>> from clients.http import AsyncClient
    >>> from clients.http.endpoints.jobs import AsyncJobs
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
