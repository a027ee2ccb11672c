"""Multi-wavelength reconstruction and spectral unmixing (docs/spectral.md), on top of the one
reconstruction dispatch and the pure unmixing (:mod:`fpscan.service.recon.unmix`).

- :func:`reconstruct_wavelengths`: one volume per excitation wavelength, the same method
  and options for all (``c="auto"``: the sound speed is found once, on the first
  wavelength, and used for every wavelength: it does not depend on the light).
- :func:`unmix_reconstructions`: HbO2/Hb/THb/sO2 from those volumes (same grid).
- :func:`so2_map`: the picture of a volume's sO2: at every lateral position (x, y) the
  sO2 of the voxel of largest THb along depth (masked where that voxel is masked); a
  2-D image ``(n_z, n_x)`` is shown as it is.
- :func:`thb_map`: the THb of the same voxels (the picture's brightness).
- :func:`write_unmix`: ``unmix.h5`` and ``so2.png`` (sO2 as colour 0..100 % with a colour
  bar, brightness from THb, the background below the THb threshold black:
  ``fpscan.service.pictures.render.render_so2``) into a result folder.

``unmix.h5`` layout: ``/hbo2``, ``/hb``, ``/thb`` (float32, units in the attribute
``concentration_units``), ``/so2`` (float32, NaN where masked), ``/mask`` (uint8, 1 =
signal strong enough), all ``(n_z, n_y, n_x)`` / ``(n_z, n_x)``; ``/z``, ``/x`` (``/y``)
in m; ``/wavelengths_m``; attributes ``format`` = ``fpscan-unmix/1``, ``params`` (JSON),
``input_id``.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fpscan.service.formats.unmix import UNMIX_FORMAT, read_unmix
from fpscan.service.progress import Progress, span
from fpscan.service.recon.unmix import Unmixed, endmember_matrix, too_few_wavelengths, unmix

__all__ = [
    "UNMIX_FORMAT", "MASK_COLOUR", "dataset_wavelengths", "reconstruct_wavelengths",
    "write_wavelength_results", "unmix_reconstructions", "so2_map", "thb_map", "render_so2_png",
    "write_unmix", "read_unmix", "load_wavelength_datasets", "reconstruct_and_unmix",
]

#: masked pixels of the sO2 picture (THb below the threshold, sO2 unknown): black
MASK_COLOUR = (0.0, 0.0, 0.0, 1.0)


def dataset_wavelengths(dataset: Any) -> np.ndarray:
    """The excitation wavelengths a dataset records: its ``wavelengths``, else
    ``meta["wavelengths"]``; empty when it records none.

    Parameters
    ----------
    dataset : object
        A loaded dataset (``fpscan.service.recon.dataset.Dataset`` or anything with a
        ``wavelengths`` attribute or a ``meta`` dict).

    Returns
    -------
    ndarray, shape ``(n_w,)``
        The wavelengths in m, float64 (``(0,)`` when none are recorded).
    """
    w = getattr(dataset, "wavelengths", None)
    if w is None:
        w = (getattr(dataset, "meta", None) or {}).get("wavelengths")
    return np.asarray([] if w is None else w, dtype=np.float64).reshape(-1)


def reconstruct_wavelengths(datasets: Sequence[Any], method: str, *, reconstruct: Callable[..., Any],
                            options: Any, progress: Progress | None = None,
                            should_stop: Callable[[], bool] | None = None) -> list[Any]:
    """Reconstruct every wavelength's dataset with the same method and options.

    With ``sound_speed="auto"`` the first wavelength's reconstruction chooses the speed and the
    others reuse it (recorded in their ``params["autofocus_from"]``).

    Parameters
    ----------
    datasets : sequence of Dataset
        One dataset per wavelength (same sensors and grid).
    method : str
        The reconstruction method's name (``fpscan.service.recon.methods``).
    reconstruct : callable
        The dispatch ``reconstruct(dataset, method, options, progress=..., should_stop=...)``
        -> ``Reconstruction``.
    options : fpscan.service.recon.methods.MethodOptions
        The method's validated options, the same for every wavelength (``sound_speed`` in m/s or
        ``"auto"``).
    progress : callable, optional
        ``progress(fraction, stage)``, spanning all wavelengths (each wavelength's stage gets the
        suffix ``" (wavelength k/n)"``).
    should_stop : callable, optional
        ``should_stop()`` -> True to cancel; passed on to ``reconstruct``.

    Returns
    -------
    list of Reconstruction
        The reconstructions, in the order of ``datasets``.

    Raises
    ------
    ValueError
        An empty ``datasets``; and whatever the dispatch raises.
    """
    if len(datasets) == 0:
        raise ValueError("no wavelengths to reconstruct")
    n = len(datasets)
    out = []
    opts = options
    for k, ds in enumerate(datasets):
        part = span(progress, k / n, (k + 1) / n, suffix=f" (wavelength {k + 1}/{n})")
        rec = reconstruct(ds, method, opts, progress=part, should_stop=should_stop)
        if k == 0 and opts.sound_speed == "auto":
            opts = opts.model_copy(update={"sound_speed": float(rec.params["sound_speed"]), "sound_speed_range": None,
                                           "force": True})
        elif k > 0 and options.sound_speed == "auto":
            rec.params["autofocus_from"] = "wavelength 1"
        out.append(rec)
    return out


def write_wavelength_results(out_dir: str | os.PathLike, recons: Sequence[Any], wavelengths: Any = None, *,
                             input_id: str = "") -> dict:
    """Write the result folder of a multi-wavelength reconstruction.

    ``volume.h5`` + MIPs of the first wavelength at the top (as any reconstruction result, so
    a viewer of one volume shows it) and ``wavelength_<k>/`` (``volume.h5`` + MIPs) for each
    reconstruction ``k`` (:func:`fpscan.service.storage.results.write_result`; the unmixing job and
    ``wavelength="all"`` share this layout).

    Parameters
    ----------
    out_dir : str or os.PathLike
        The result folder.
    recons : sequence of Reconstruction
        One reconstruction per wavelength.
    wavelengths : array_like, shape ``(n_w,)``, optional
        The wavelengths in m, one per reconstruction, recorded as ``wavelength_nm`` in each
        volume's params where the reconstruction does not record its own. None: none recorded.
    input_id : str, optional
        The input's id, recorded in each volume.

    Returns
    -------
    dict
        The first volume's summary (``shape``, ``max``, ``planes``, ``params_used``) plus
        ``wavelengths``: one ``{"index", "wavelength_nm", "shape", "max"}`` per reconstruction.

    Raises
    ------
    ValueError
        No reconstructions, or a count of wavelengths that differs from the reconstructions.
    """
    from fpscan.service.storage.results import write_result

    if len(recons) == 0:
        raise ValueError("no wavelengths to write")
    w = None if wavelengths is None else np.asarray(wavelengths, dtype=np.float64).reshape(-1)
    if w is not None and w.size != len(recons):
        raise ValueError(f"{len(recons)} volumes for {w.size} wavelengths")
    out = Path(out_dir)
    for k, rec in enumerate(recons):
        if w is not None:
            rec.params.setdefault("wavelength_nm", round(float(w[k]) * 1e9, 6))
    written = write_result(out, recons[0], input_id=input_id)
    rows = []
    for k, rec in enumerate(recons):
        one = write_result(out / f"wavelength_{k}", rec, input_id=input_id)
        rows.append({"index": k, "wavelength_nm": rec.params.get("wavelength_nm"), "shape": one["shape"],
                     "max": one["max"]})
    return {**written, "wavelengths": rows}


def unmix_reconstructions(recons: Sequence[Any], wavelengths: Any, **kwargs: Any) -> Unmixed:
    """Unmix per-wavelength reconstructions (``p0`` on one grid) into HbO2/Hb, THb and sO2
    (:func:`fpscan.service.recon.unmix.unmix`).

    Parameters
    ----------
    recons : sequence of Reconstruction
        One reconstruction per wavelength, all on one grid (same ``p0`` shape and z, x, y axes).
    wavelengths : array_like, shape ``(n_w,)``
        The excitation wavelengths, m, one per reconstruction.
    **kwargs
        ``fluence``, ``gruneisen``, ``threshold`` for :func:`fpscan.service.recon.unmix.unmix`.

    Returns
    -------
    Unmixed
        HbO2, Hb, THb, sO2 and the mask on the reconstructions' grid.

    Raises
    ------
    ValueError
        A single wavelength, mismatched grids, a count of wavelengths that differs from the
        volumes, or what :func:`fpscan.service.recon.unmix.unmix` refuses.
    """
    w = np.asarray(wavelengths, dtype=np.float64).reshape(-1)
    if len(recons) != w.size:
        raise ValueError(f"{len(recons)} volumes for {w.size} wavelengths")
    if w.size < 2:
        raise too_few_wavelengths(w)
    first = recons[0]
    for r in recons[1:]:
        same = r.p0.shape == first.p0.shape and np.allclose(r.z, first.z) and np.allclose(r.x, first.x) and \
            ((r.y is None and first.y is None) or (r.y is not None and first.y is not None
                                                   and np.allclose(r.y, first.y)))
        if not same:
            raise ValueError("the wavelengths' volumes are not on one grid; reconstruct them with the same options")
    return unmix(np.stack([np.asarray(r.p0) for r in recons]), w, **kwargs)


def so2_map(u: Unmixed) -> np.ndarray:
    """2-D sO2 picture: the sO2 at each column's largest-THb voxel.

    Parameters
    ----------
    u : Unmixed
        An unmixing result, ``(n_z, n_y, n_x)`` or ``(n_z, n_x)``.

    Returns
    -------
    ndarray
        3-D input: ``(n_y, n_x)``, the sO2 (0..1) at each lateral position's voxel of largest THb
        along depth (NaN where that voxel is masked); 2-D input: the ``(n_z, n_x)`` sO2 image
        itself.
    """
    if u.so2.ndim == 2:
        return u.so2
    k = np.argmax(u.thb, axis=0)[None]
    return np.take_along_axis(u.so2, k, axis=0)[0]


def thb_map(u: Unmixed) -> np.ndarray:
    """2-D THb picture matching :func:`so2_map`.

    Parameters
    ----------
    u : Unmixed
        An unmixing result, ``(n_z, n_y, n_x)`` or ``(n_z, n_x)``.

    Returns
    -------
    ndarray
        3-D input: ``(n_y, n_x)``, the largest THb along depth (the voxel whose sO2
        :func:`so2_map` shows); 2-D input: the ``(n_z, n_x)`` THb image. In ``u``'s
        concentration units.
    """
    return u.thb if u.thb.ndim == 2 else np.max(u.thb, axis=0)


def render_so2_png(u: Unmixed, z: Any, x: Any, y: Any = None) -> bytes:
    """PNG of :func:`so2_map` through the one rendering path.

    :func:`fpscan.service.pictures.render.render_so2`: mm axes, row 0 at the top, colour bar; sO2 as
    colour (``RdYlBu_r`` over 0 % blue .. 100 % red), brightness from THb (:func:`thb_map`),
    black (:data:`MASK_COLOUR`) where THb is below the unmixing's ``threshold`` (default 0.1)
    of its maximum or sO2 is unknown.

    Parameters
    ----------
    u : Unmixed
        An unmixing result.
    z, x : array_like
        The depth and x axes, m.
    y : array_like, optional
        The y axis, m (3-D results: the picture's vertical axis); None for 2-D.

    Returns
    -------
    bytes
        The PNG file's bytes.
    """
    from fpscan.service.pictures.render import render_so2

    threshold = float((u.params or {}).get("threshold", 0.1))
    if u.so2.ndim == 2:
        return render_so2(so2_map(u), thb_map(u), np.asarray(x), np.asarray(z), hlabel="x", vlabel="z",
                          threshold=threshold, title="sO2 (colour), THb (brightness)")
    return render_so2(so2_map(u), thb_map(u), np.asarray(x), np.asarray(y), hlabel="x", vlabel="y",
                      threshold=threshold, title="sO2 at the THb maximum along z (colour), THb MIP (brightness)")


def write_unmix(out_dir: str | os.PathLike, u: Unmixed, z: Any, x: Any, y: Any = None, *,
                input_id: str = "", extra: dict | None = None) -> dict:
    """Write ``unmix.h5`` and ``so2.png`` into ``out_dir`` (an existing folder; the caller writes
    the folder atomically).

    Parameters
    ----------
    out_dir : str or os.PathLike
        The result folder.
    u : Unmixed
        The unmixing result.
    z, x : array_like
        The depth and x axes, m.
    y : array_like, optional
        The y axis, m; None for 2-D.
    input_id : str, optional
        The input's id (the file's ``input_id`` attribute).
    extra : dict, optional
        More parameters recorded in the file's ``params`` (e.g. ``method``, ``c``).

    Returns
    -------
    dict
        ``so2_median`` (the median sO2 inside the mask, None when all is masked),
        ``masked_fraction``, ``thb_max`` and ``wavelengths_m``.
    """
    from fpscan.service.formats.unmix import write

    out = Path(out_dir)
    write(out / "unmix.h5", u, z, x, y, input_id=input_id, extra=extra)
    (out / "so2.png").write_bytes(render_so2_png(u, z, x, y))
    inside = u.so2[u.mask]
    return {"so2_median": float(np.median(inside)) if inside.size else None,
            "masked_fraction": float(u.params.get("masked_fraction", 1.0)),
            "thb_max": float(u.thb.max()) if u.thb.size else 0.0,
            "wavelengths_m": [float(v) for v in u.wavelengths]}


def load_wavelength_datasets(paths: Sequence[str | os.PathLike], format: str | None = None, *,
                             wavelengths: Sequence[float] | None = None,
                             **load: Any) -> tuple[np.ndarray, list[Any]]:
    """The datasets of a multi-wavelength acquisition, one per wavelength.

    Parameters
    ----------
    paths : sequence of str or os.PathLike
        One multi-wavelength scan file (each wavelength's completed A-lines), or one file per
        wavelength (any format of :func:`fpscan.service.storage.loader.load_dataset`).
    format : str, optional
        The input format's name; None: detected.
    wavelengths : sequence of float, optional
        The wavelengths in m, one per file (default: the single wavelength each file records).
    **load
        ``dt``, ``dx``, ``dy``, ``key``, ``c`` for ``load_dataset`` (None values are dropped).

    Returns
    -------
    tuple of (ndarray, list of Dataset)
        The wavelengths ``(n_w,)`` in m and the datasets in the same order.

    Raises
    ------
    ValueError
        No files, a single-wavelength input, a single file that is no fpscan scan file, counts
        that differ, unknown or bad wavelengths.
    FileNotFoundError
        A file that does not exist.
    """
    from fpscan.service.storage import loader as dsm

    load = {k: v for k, v in load.items() if v is not None}
    paths = list(paths)
    if not paths:
        raise ValueError("no input files")
    if len(paths) == 1:
        every = dsm.load_wavelengths(paths[0], format, wavelength="all", **load)  # one open of the file
        ds = every[0]
        recorded = dsm.file_wavelengths(ds)
        if wavelengths is not None and len(wavelengths) != 1 and len(wavelengths) != recorded.size:
            raise ValueError(f"{len(wavelengths)} wavelengths given for a file with {recorded.size}")
        if recorded.size < 2:
            raise too_few_wavelengths(wavelengths if wavelengths is not None else recorded)
        fmt = ds.source  # the format that read it (no second open to detect it)
        if fmt != "fpscan":
            raise ValueError(f"a {fmt} file holds one wavelength's data; give one file per wavelength")
        return recorded, every
    dsets = [dsm.load_dataset(p, format, **load) for p in paths]
    if wavelengths is None:
        rec = [dataset_wavelengths(d) for d in dsets]
        if any(r.size != 1 for r in rec):
            raise ValueError("give --wavelengths: the files do not each record one excitation wavelength")
        wavelengths = [float(r[0]) for r in rec]
    if len(wavelengths) != len(dsets):
        raise ValueError(f"{len(dsets)} files need {len(dsets)} wavelengths, got {len(wavelengths)}")
    endmember_matrix(wavelengths)  # bad wavelengths end here, before any reconstruction
    return np.asarray(wavelengths, dtype=np.float64), dsets


def reconstruct_and_unmix(out_dir: str | os.PathLike, datasets: Sequence[Any], wavelengths: Any, method: str, *,
                          input_id: str = "", threshold: float = 0.1, fluence: Any = None,
                          gruneisen: float = 1.0, progress: Progress | None = None,
                          should_stop: Callable[[], bool] | None = None,
                          reconstruct: Callable[..., Any], options: Any) -> dict:
    """Reconstruct every wavelength, unmix, and write the result folder ``out_dir``.

    The folder: ``volume.h5`` + MIPs of the first wavelength (as any reconstruction result),
    ``wavelength_<k>/`` the same per wavelength, ``unmix.h5`` and ``so2.png``
    (:func:`write_unmix`). Progress: the reconstructions on [0, 0.9], ``"writing"`` at 0.95.

    Parameters
    ----------
    out_dir : str or os.PathLike
        The result folder (existing; the caller writes it atomically).
    datasets : sequence of Dataset
        One dataset per wavelength (same sensors and grid).
    wavelengths : array_like, shape ``(n_w,)``
        The excitation wavelengths, m, one per dataset.
    method : str
        The reconstruction method's name; the same method and ``options`` for every wavelength.
    input_id : str, optional
        The input's id, recorded in the files.
    threshold : float, optional
        Fraction in [0, 1) of the largest THb below which a voxel is masked (default 0.1).
    fluence : ndarray or float, optional
        Fluence Φ, J/m² (:func:`fpscan.service.recon.unmix.unmix`); None: the same unknown
        fluence everywhere.
    gruneisen : float, optional
        The Grüneisen parameter Γ, used with ``fluence`` (default 1).
    progress : callable, optional
        ``progress(fraction, stage)``.
    should_stop : callable, optional
        ``should_stop()`` -> True to cancel.
    reconstruct : callable
        The dispatch ``fpscan.service.pipeline.reconstruct``, which calls this through ``run_file``.
    options : fpscan.service.recon.methods.MethodOptions
        The method's validated options.

    Returns
    -------
    dict
        The first wavelength's volume summary plus ``wavelengths`` (per volume), ``unmix`` (the
        :func:`write_unmix` summary), ``so2_median``, ``masked_fraction``, ``sound_speed``,
        ``wavelengths_m``, ``params`` (wavelength 1's reconstruction parameters) and
        ``timings`` (``reconstruct_s``, ``unmix_s``, ``write_s``).

    Raises
    ------
    ValueError
        Before any reconstruction: fewer than two wavelengths or datasets, repeats,
        wavelengths outside 400-1000 nm (:func:`fpscan.service.recon.unmix.endmember_matrix`), counts
        that differ; and whatever the reconstruction or unmixing raises.
    """
    import time

    w = np.asarray(wavelengths, dtype=np.float64).reshape(-1)
    if w.size < 2 or len(datasets) < 2:
        raise too_few_wavelengths(w)
    if len(datasets) != w.size:
        raise ValueError(f"{len(datasets)} datasets for {w.size} wavelengths")
    endmember_matrix(w)  # wavelengths that cannot be unmixed end here, before any reconstruction
    t0 = time.perf_counter()

    recons = reconstruct_wavelengths(datasets, method, reconstruct=reconstruct, progress=span(progress, 0.0, 0.9),
                                     should_stop=should_stop, options=options)
    t1 = time.perf_counter()
    u = unmix_reconstructions(recons, w, threshold=threshold, fluence=fluence, gruneisen=gruneisen)
    t2 = time.perf_counter()
    if progress is not None:
        progress(0.95, "writing")
    out = Path(out_dir)
    first = recons[0]
    written = write_wavelength_results(out, recons, w, input_id=input_id)
    extra = {"method": method, "sound_speed": float(first.params.get("sound_speed", 0.0)) or None}
    if "autofocus" in first.params:
        extra["autofocus"] = first.params["autofocus"]
    summary = write_unmix(out, u, first.z, first.x, getattr(first, "y", None), input_id=input_id, extra=extra)
    t3 = time.perf_counter()
    return {**written, "unmix": summary, "so2_median": summary["so2_median"],
            "masked_fraction": summary["masked_fraction"],
            "sound_speed": extra["sound_speed"], "wavelengths_m": [float(v) for v in w], "params": dict(first.params),
            "timings": {"reconstruct_s": t1 - t0, "unmix_s": t2 - t1, "write_s": t3 - t2}}
