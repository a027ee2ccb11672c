"""Datasets: ``/api/datasets`` (upload a data file, list, delete) and the input formats the
server reads (``/api/datasets/formats``)."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import httpx

from fpscan.clients.http.calls import AsyncCaller, Call, Request, SyncCaller, read_json

__all__ = ["Datasets", "AsyncDatasets"]


def _dataset_id(response: httpx.Response) -> str:
    body = response.json()
    return str(body.get("dataset_id") or body.get("id"))


def _build_upload_dataset(path: str | os.PathLike, format: str, fields: dict[str, Any]) -> Call[str]:
    """``POST /api/datasets`` (:meth:`Datasets.upload_dataset`); a missing file is a ValueError."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"no such file: {p}")
    form = {"format": format, **{k: str(v) for k, v in fields.items() if v is not None}}
    return Call(Request("POST", "/api/datasets", form=form, upload=p), _dataset_id)


def _build_dataset_formats() -> Call[Any]:
    """``GET /api/datasets/formats`` (:meth:`Datasets.dataset_formats`)."""
    return Call(Request("GET", "/api/datasets/formats"), read_json)


def _build_formats() -> Call[Any]:
    """``GET /api/formats`` (:meth:`Datasets.formats`)."""
    return Call(Request("GET", "/api/formats"), read_json)


def _build_list_datasets() -> Call[Any]:
    """``GET /api/datasets`` (:meth:`Datasets.list_datasets`)."""
    return Call(Request("GET", "/api/datasets"), read_json)


def _build_delete_dataset(dataset_id: str) -> Call[Any]:
    """``DELETE /api/datasets/{dataset_id}`` (:meth:`Datasets.delete_dataset`)."""
    return Call(Request("DELETE", f"/api/datasets/{dataset_id}"), read_json)


class Datasets(SyncCaller):
    """The dataset endpoints of :class:`fpscan.clients.http.Client` (blocking).

    Attributes
    ----------
    None
        A mixin of methods.

    Examples
    --------
    >>> from fpscan.clients.http import Client
    >>> from fpscan.clients.http.endpoints.datasets import Datasets
    >>> issubclass(Client, Datasets)
    True
    """

    def upload_dataset(self, path: str | os.PathLike, format: str = "fpscan", **fields: Any) -> str:
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
        return self._call(_build_upload_dataset(path, format, fields))

    def dataset_formats(self) -> Any:
        """``GET /api/datasets/formats``: the formats :meth:`upload_dataset` takes.

        Returns
        -------
        list of dict
            ``{name, title, wavelengths}`` per format (the server's registry of formats).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_dataset_formats())

    def formats(self) -> Any:
        """``GET /api/formats``: every file format the server reads or writes (its registry).

        Returns
        -------
        list of dict
            ``{name, title, noun, input, upload, wavelengths, export_from, suffix, media_type,
            folder, options}`` per format: ``input`` / ``upload`` a reconstruction input / an
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
        return self._call(_build_formats())

    def list_datasets(self) -> Any:
        """``GET /api/datasets``: the stored datasets, oldest first.

        Returns
        -------
        list of dict
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
        return self._call(_build_list_datasets())

    def delete_dataset(self, dataset_id: str) -> Any:
        """``DELETE /api/datasets/{dataset_id}``: a stored dataset.

        Parameters
        ----------
        dataset_id : str

        Returns
        -------
        dict
            ``{"id", "kind", "bytes_freed"}``.

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (Conflict (409) while an active reconstruction reads
            it, NotFound (404) for an unknown id).
        ServerUnavailable
            The server cannot be reached.
        """
        return self._call(_build_delete_dataset(dataset_id))


class AsyncDatasets(AsyncCaller):
    """The dataset endpoints of :class:`fpscan.clients.http.AsyncClient`: :class:`Datasets`' methods as
    coroutines.

    Attributes
    ----------
    None
        A mixin of methods.

    Examples
    --------
    >>> from fpscan.clients.http import AsyncClient
    >>> from fpscan.clients.http.endpoints.datasets import AsyncDatasets
    >>> issubclass(AsyncClient, AsyncDatasets)
    True
    """

    async def upload_dataset(self, path: str | os.PathLike, format: str = "fpscan", **fields: Any) -> str:
        """As :meth:`Datasets.upload_dataset`, awaited."""
        return await self._call(_build_upload_dataset(path, format, fields))

    async def dataset_formats(self) -> Any:
        """As :meth:`Datasets.dataset_formats`, awaited."""
        return await self._call(_build_dataset_formats())

    async def formats(self) -> Any:
        """As :meth:`Datasets.formats`, awaited."""
        return await self._call(_build_formats())

    async def list_datasets(self) -> Any:
        """As :meth:`Datasets.list_datasets`, awaited."""
        return await self._call(_build_list_datasets())

    async def delete_dataset(self, dataset_id: str) -> Any:
        """As :meth:`Datasets.delete_dataset`, awaited."""
        return await self._call(_build_delete_dataset(dataset_id))
