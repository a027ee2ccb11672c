"""Datasets: ``/api/datasets`` (upload a data file, list, delete) and the file formats the
server reads (``/api/datasets/formats``, ``/api/formats``)."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import httpx

from fpscan.clients.http.calls import Call, Request, endpoint, read_json, read_models
from fpscan.clients.http.models import DatasetFormatInfo, DatasetInfo, Deleted, FormatInfo

__all__ = ["Datasets"]


def _dataset_id(response: httpx.Response) -> str:
    body = response.json()
    return str(body.get("dataset_id") or body.get("id"))


class Datasets:
    """The dataset and format endpoints, declared once (:func:`~fpscan.clients.http.calls.endpoint`):
    methods of :class:`fpscan.clients.http.Client` and, as coroutines, of
    :class:`fpscan.clients.http.AsyncClient`.

    Attributes
    ----------
    upload_dataset, dataset_formats, formats, list_datasets, delete_dataset : Endpoint
        The declarations.

    Examples
    --------
    >>> from fpscan.clients.http import Client
    >>> from fpscan.clients.http.endpoints.datasets import Datasets
    >>> issubclass(Client, Datasets)
    True
    >>> Datasets.delete_dataset.build("d1").request.method, Datasets.delete_dataset.build("d1").request.path
    ('DELETE', '/api/datasets/d1')
    >>> Datasets.upload_dataset.build("no/such/file.npy")
    Traceback (most recent call last):
    ...
    ValueError: no such file: no/such/file.npy
    """

    @endpoint
    def upload_dataset(path: str | os.PathLike, format: str = "fpscan", **fields: Any) -> Call[str]:
        """``POST /api/datasets``: upload a data file for reconstruction.

        The file is streamed (multipart), not read into memory.

        Parameters
        ----------
        path : str or os.PathLike
            The file.
        format : str, optional
            One of the server's (:meth:`dataset_formats`; another is answered 422 naming them);
            default ``"fpscan"``.
        **fields
            Spacings and settings the format needs, SI units: ``dx``, ``dy`` (m), ``dt`` (s),
            ``sound_speed`` (m/s; ``c`` is its deprecated name), ...

        Returns
        -------
        str
            The dataset id (201).

        Raises
        ------
        ValueError
            A missing file (before any request).
        ApiError
            The server's reason (422 for a bad file or field).
        ServerUnavailable
            The server cannot be reached.
        """
        p = Path(path)
        if not p.is_file():
            raise ValueError(f"no such file: {p}")
        form = {"format": format, **{k: str(v) for k, v in fields.items() if v is not None}}
        return Call(Request("POST", "/api/datasets", form=form, upload=p), _dataset_id)

    @endpoint
    def dataset_formats() -> Call[list[DatasetFormatInfo]]:
        """``GET /api/datasets/formats``: the formats :meth:`upload_dataset` takes.

        Returns
        -------
        list of DatasetFormatInfo
            ``name``, ``title``, ``wavelengths`` per format (the server's registry of formats).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        return Call(Request("GET", "/api/datasets/formats"), read_models(DatasetFormatInfo))

    @endpoint
    def formats() -> Call[list[FormatInfo]]:
        """``GET /api/formats``: every file format the server reads or writes (its registry).

        Returns
        -------
        list of FormatInfo
            ``name, title, noun, input, upload, wavelengths, export_from, suffix, media_type,
            folder, options`` per format: ``input`` / ``upload`` a reconstruction input / an
            upload choice, ``export_from`` the format whose files it exports (None: no export),
            ``suffix`` an export's file-name ending, ``folder`` an export that is a folder (served
            zipped), ``options`` its load options (name, description, value schema).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        return Call(Request("GET", "/api/formats"), read_models(FormatInfo))

    @endpoint
    def list_datasets() -> Call[list[DatasetInfo]]:
        """``GET /api/datasets``: the stored datasets, oldest first.

        Returns
        -------
        list of DatasetInfo
            ``dataset_id``, ``name``, ``format``, ``layout``, ``shape``, ``size_bytes`` (on disk),
            ``created`` (UNIX s), ``content_sha256``, ``jobs`` (ids of the jobs that read it),
            ``in_use`` (an active job does: it cannot be deleted).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        return Call(Request("GET", "/api/datasets"), read_models(DatasetInfo))

    @endpoint
    def delete_dataset(dataset_id: str) -> Call[Deleted]:
        """``DELETE /api/datasets/{dataset_id}``: a stored dataset.

        Parameters
        ----------
        dataset_id : str

        Returns
        -------
        dict
            ``{"id", "kind", "bytes_freed"}`` (:class:`~fpscan.clients.http.models.Deleted`).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict (409) while an active reconstruction reads
            it, NotFound (404) for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return Call(Request("DELETE", f"/api/datasets/{dataset_id}"), read_json)
