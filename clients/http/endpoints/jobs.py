"""Jobs: ``/api/jobs`` (list, one job, cancel, delete, its file exported in a registered format).
Following a job's events and waiting for its end are the clients' own
(:meth:`fpscan.clients.http.Client.events`, ``wait``): they send many requests."""
from __future__ import annotations

import os
from pathlib import Path

from fpscan.clients.http.calls import (
    Call,
    Download,
    Request,
    endpoint,
    read_json,
    read_model,
    read_models,
    read_optional_model,
)
from fpscan.clients.http.models import Deleted, Job
from fpscan.clients.http.transport import unzip_folder

__all__ = ["Jobs"]


class Jobs:
    """The job endpoints, declared once (:func:`~fpscan.clients.http.calls.endpoint`): methods of
    :class:`fpscan.clients.http.Client` and, as coroutines, of :class:`fpscan.clients.http.AsyncClient`
    (``Jobs.get_job.build`` is also what a wait polls with).

    Attributes
    ----------
    list_jobs, get_job, cancel_job, delete_job, export : Endpoint
        The declarations.

    Examples
    --------
    >>> from fpscan.clients.http import Client
    >>> from fpscan.clients.http.endpoints.jobs import Jobs
    >>> issubclass(Client, Jobs)
    True
    >>> Jobs.list_jobs.build(state="running").request.params
    {'state': 'running'}
    >>> Jobs.export.build("j1", "", "out.tif")
    Traceback (most recent call last):
    ...
    ValueError: format must be an export format's name, got ''
    """

    @endpoint
    def list_jobs(*, state: str | None = None, kind: str | None = None, scan_job_id: str | None = None,
                  limit: int | None = None, before: str | None = None) -> Call[list[Job]]:
        """``GET /api/jobs?state=&kind=&scan_job_id=&limit=&before=``: the jobs, newest first, a
        page at a time.

        Parameters
        ----------
        state : str, optional
            Only jobs in this state (``queued``, ``running``, ``paused``, ``succeeded``,
            ``failed``, ``cancelled``).
        kind : str, optional
            Only jobs of this kind.
        scan_job_id : str, optional
            Only the reconstructions of this scan job (its full id).
        limit : int, optional
            At most this many (1-1000; the server's default: 200).
        before : str, optional
            A job's id: only the jobs submitted before it. A page of ``limit`` jobs may not be
            the last: the next is ``list_jobs(..., before=<its last job's id>)``, until a page
            holds fewer than ``limit``.

        Returns
        -------
        list of Job

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        params = {k: v for k, v in (("state", state), ("kind", kind), ("scan_job_id", scan_job_id),
                                    ("limit", limit), ("before", before)) if v}
        return Call(Request("GET", "/api/jobs", params=params or None), read_models(Job))

    @endpoint
    def get_job(job_id: str) -> Call[Job]:
        """``GET /api/jobs/{job_id}``: one job.

        Parameters
        ----------
        job_id : str

        Returns
        -------
        Job
            ``id, kind, state, progress, timings, params, links, error``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return Call(Request("GET", f"/api/jobs/{job_id}"), read_model(Job))

    @endpoint
    def cancel_job(job_id: str) -> Call[Job | None]:
        """``POST /api/jobs/{job_id}/cancel``: cancel a job (cooperative).

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
        return Call(Request("POST", f"/api/jobs/{job_id}/cancel"), read_optional_model(Job))

    @endpoint
    def delete_job(job_id: str) -> Call[Deleted]:
        """``DELETE /api/jobs/{job_id}``: a finished job and its files.

        Parameters
        ----------
        job_id : str

        Returns
        -------
        dict
            ``{"id", "kind", "bytes_freed"}`` (:class:`~fpscan.clients.http.models.Deleted`).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict (409) while the job or a job reading it is
            active, NotFound for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return Call(Request("DELETE", f"/api/jobs/{job_id}"), read_json)

    @endpoint
    def export(job_id: str, format: str, dest: str | os.PathLike, *,
               wavelength: int | None = None) -> Download[Path]:
        """``GET /api/jobs/{job_id}/export/{format}``: a job's file in an export format, saved to ``dest``.

        A scan job exports its scan file, a reconstruction its p0 volume: the formats of the
        server's registry (:meth:`formats`; a job's ``export_<format>`` links name those it
        offers), e.g. ``ipasc`` (a scan), ``ome-tiff`` and ``ome-zarr`` (a volume, voxel sizes in
        µm), ``fpscan`` / ``result`` (the file itself). A folder export (OME-Zarr) comes zipped and
        is unpacked into the folder ``dest`` (kept zipped when ``dest`` ends in ``.zip``). The
        download goes beside ``dest`` (resumable) and is then put in place.

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
