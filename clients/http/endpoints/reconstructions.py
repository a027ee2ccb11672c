"""Reconstructions: ``/api/reconstructions`` (the methods, start a reconstruction or an unmixing,
and the results: volume, MIPs, depth slices, unmixed maps; a result's exports are a job's:
:meth:`fpscan.clients.http.Client.export`)."""
from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
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
    read_models,
)
from fpscan.clients.http.models import MethodInfo

__all__ = ["Reconstructions"]


def _input(body: dict[str, Any], scan_job_id: str | None, dataset_id: str | None) -> dict[str, Any]:
    if (scan_job_id is None) == (dataset_id is None):
        raise ValueError("give exactly one of scan_job_id or dataset_id")
    if scan_job_id is not None:
        body["scan_job_id"] = scan_job_id
    else:
        body["dataset_id"] = dataset_id
    return body


def _wavelength(wavelength: int | None) -> dict[str, int] | None:
    return None if wavelength is None else {"wavelength": int(wavelength)}


def _result(job_id: str, name: str, dest: str | os.PathLike, params: Mapping[str, Any] | None = None) -> Download[Path]:
    """``GET /api/reconstructions/{job_id}/{name}`` saved to ``dest`` (``volume.h5``,
    ``mip/xy.png``, ``slice.png``, ``unmix.h5``, ``so2.png``)."""
    return Download(Request("GET", f"/api/reconstructions/{job_id}/{name}", params=params), Path(dest))


class Reconstructions:
    """The reconstruction endpoints, declared once (:func:`~fpscan.clients.http.calls.endpoint`):
    methods of :class:`fpscan.clients.http.Client` and, as coroutines, of
    :class:`fpscan.clients.http.AsyncClient`.

    Attributes
    ----------
    methods, start_reconstruction, start_unmix, download_unmix, download_so2, download_volume, download_mip, download_slice : Endpoint
        The declarations.

    Examples
    --------
    >>> from fpscan.clients.http import Client
    >>> from fpscan.clients.http.endpoints.reconstructions import Reconstructions
    >>> issubclass(Client, Reconstructions)
    True
    >>> call = Reconstructions.start_reconstruction.build(dataset_id="d1", method="ner", idempotency_key="k")
    >>> call.request.json
    {'params': {}, 'method': 'ner', 'dataset_id': 'd1'}
    >>> Reconstructions.download_mip.build("j1", "xz", "mip.png", wavelength=1).request.params
    {'wavelength': 1}
    >>> Reconstructions.start_unmix.build()
    Traceback (most recent call last):
    ...
    ValueError: give exactly one of scan_job_id or dataset_ids
    """

    @endpoint
    def methods() -> Call[list[MethodInfo]]:
        """``GET /api/reconstructions/methods``: the reconstruction methods.

        Returns
        -------
        list of MethodInfo
            ``{name, title, needs_grid, options: [{name, description, default, value_schema}],
            source}`` per method; ``value_schema`` is an option's JSON schema (``type``,
            ``minimum``/``maximum`` or ``enum``, ``unit``, ``quantity``): a value outside it is
            refused (422).

        Raises
        ------
        ApiError
            The server's reason for a 4xx/5xx (AuthError for a missing or wrong token).
        ServerUnavailable
            The server cannot be reached.
        """
        return Call(Request("GET", "/api/reconstructions/methods"), read_models(MethodInfo))

    @endpoint
    def start_reconstruction(*, scan_job_id: str | None = None, dataset_id: str | None = None,
                             method: str | None = None, params: Mapping | None = None,
                             wavelength: int | str | None = None,
                             idempotency_key: str | None = None, plan_id: str | None = None) -> Call[str | None]:
        # The defaults below (ner, nedner) are typed by hand: fpscan.clients.http never imports service (an
        # import contract), so it cannot read the registry's Method.default_for; the server's own
        # word is GET /api/reconstructions/methods (each method's default_for, :meth:`methods`).
        """``POST /api/reconstructions``: start a reconstruction job.

        Parameters
        ----------
        scan_job_id : str, optional
            A scan job whose file to reconstruct; exactly one of it and ``dataset_id``.
        dataset_id : str, optional
            An uploaded dataset.
        method : str, optional
            One of the ``fpscan.service.recon`` methods (``ner``, ``nedner``, ``linear``, ...,
            :meth:`methods`); None: the server's default for the data (ner for grid data, nedner
            for sensor points).
        params : Mapping, optional
            The reconstruction options: ``sound_speed`` (m/s or ``"auto"``; ``c`` is its
            deprecated name), ``sound_speed_range``, ``force`` and the method's own (``eps``,
            ``dtype``, ``upsample``, ``positivity``, ``dz`` in m, ...; ``tv``: ``lam`` (λ,
            default automatic) and ``iterations``; the job's progress stage names the
            iteration). Each option's type, range, unit and default: :meth:`methods`.
        wavelength : int or "all", optional
            Of a multi-wavelength scan: an index into its wavelengths, or ``"all"`` (one volume
            each: ``download_volume(..., wavelength=k)``); None: the first, recorded in the
            volume's params.
        idempotency_key : str, optional
            Same key -> same job (default: a fresh random key).
        plan_id : str, optional
            With ``dataset_id`` (dense data): reconstruct the A-lines this stored plan's sensor
            mask picks out of it (``fpscan.subsample``: what a replay scan of the data records).

        Returns
        -------
        str
            The reconstruction job's id (202).

        Raises
        ------
        ValueError
            Both or neither input given (before any request).
        ApiError
            The server's reason (422 naming an invalid option, NotFound for an unknown input).
        ServerUnavailable
            The server cannot be reached.
        """
        body: dict[str, Any] = {"params": dict(params or {})}
        if method is not None:
            body["method"] = method
        if wavelength is not None:
            body["wavelength"] = wavelength
        if plan_id is not None:
            body["plan_id"] = plan_id
        body = _input(body, scan_job_id, dataset_id)
        return Call(Request("POST", "/api/reconstructions", json=body, headers=idempotency(idempotency_key)),
                    read_job_id)

    @endpoint
    def start_unmix(*, scan_job_id: str | None = None, dataset_ids: Sequence[str] | None = None,
                    wavelengths: Sequence[float] | None = None, method: str | None = None,
                    params: Mapping | None = None, threshold: float | None = None,
                    fluence: Sequence[float] | None = None, idempotency_key: str | None = None) -> Call[str | None]:
        """``POST /api/reconstructions`` with ``unmix``: reconstruct every wavelength and unmix.

        Every wavelength is reconstructed (same ``method`` and ``params``;
        ``params["sound_speed"]`` may be ``"auto"``) and unmixed into HbO2/Hb, THb and sO2
        (``fpscan.service.recon.unmix``).

        Parameters
        ----------
        scan_job_id : str, optional
            A multi-wavelength scan job; exactly one of it and ``dataset_ids``.
        dataset_ids : sequence of str, optional
            One uploaded dataset per wavelength.
        wavelengths : sequence of float, optional
            The datasets' wavelengths, m.
        method : str, optional
            As :meth:`start_reconstruction`.
        params : Mapping, optional
            As :meth:`start_reconstruction`.
        threshold : float, optional
            THb fraction in [0, 1) below which voxels are masked.
        fluence : sequence of float, optional
            J/m² per wavelength (default: assumed equal).
        idempotency_key : str, optional
            Same key -> same job.

        Returns
        -------
        str
            The job's id (202).

        Raises
        ------
        ValueError
            Both or neither input given (before any request).
        ApiError
            The server's reason (422 for fewer than two wavelengths, ...).
        ServerUnavailable
            The server cannot be reached.
        """
        if (scan_job_id is None) == (not dataset_ids):
            raise ValueError("give exactly one of scan_job_id or dataset_ids")
        unmix: dict[str, Any] = {}
        if threshold is not None:
            unmix["threshold"] = float(threshold)
        if fluence is not None:
            unmix["fluence"] = [float(f) for f in fluence]
        body: dict[str, Any] = {"params": dict(params or {}), "unmix": unmix}
        if method is not None:
            body["method"] = method
        if scan_job_id is not None:
            body["scan_job_id"] = scan_job_id
        else:
            body["dataset_ids"] = list(dataset_ids or [])
            if wavelengths is not None:
                body["wavelengths"] = [float(w) for w in wavelengths]
        return Call(Request("POST", "/api/reconstructions", json=body, headers=idempotency(idempotency_key)),
                    read_job_id)

    @endpoint
    def download_unmix(job_id: str, dest: str | os.PathLike) -> Download[Path]:
        """``GET /api/reconstructions/{job_id}/unmix.h5`` (HbO2, Hb, THb, sO2, mask; HDF5) saved to ``dest``.

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
        return _result(job_id, "unmix.h5", dest)

    @endpoint
    def download_so2(job_id: str, dest: str | os.PathLike) -> Download[Path]:
        """``GET /api/reconstructions/{job_id}/so2.png`` (masked sO2 map with colour bar, PNG) saved to ``dest``.

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
        return _result(job_id, "so2.png", dest)

    @endpoint
    def download_volume(job_id: str, dest: str | os.PathLike, *, wavelength: int | None = None) -> Download[Path]:
        """``GET /api/reconstructions/{job_id}/volume.h5`` (p0 with its axes in m, HDF5) saved to ``dest``.

        Parameters
        ----------
        job_id : str
        dest : str or os.PathLike
            The file to write (its folder is made; ``dest.part`` while downloading).
        wavelength : int, optional
            Wavelength k's volume of a job over every wavelength.

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
        return _result(job_id, "volume.h5", dest, _wavelength(wavelength))

    @endpoint
    def download_mip(job_id: str, plane: str, dest: str | os.PathLike, *,
                     wavelength: int | None = None) -> Download[Path]:
        """``GET /api/reconstructions/{job_id}/mip/{plane}.png`` (maximum-intensity projection, PNG) saved to ``dest``.

        Parameters
        ----------
        job_id : str
        plane : {"xy", "xz", "yz"}
            The projection's plane.
        dest : str or os.PathLike
            The file to write (its folder is made; ``dest.part`` while downloading).
        wavelength : int, optional
            As :meth:`download_volume`.

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
        return _result(job_id, f"mip/{plane}.png", dest, _wavelength(wavelength))

    @endpoint
    def download_slice(job_id: str, index: int, dest: str | os.PathLike) -> Download[Path]:
        """``GET /api/reconstructions/{job_id}/slice.png?index=k`` (one depth slice, PNG) saved to ``dest``.

        Parameters
        ----------
        job_id : str
        index : int
            The slice's depth index k.
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
        return _result(job_id, "slice.png", dest, {"index": int(index)})
