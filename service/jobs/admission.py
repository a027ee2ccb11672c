"""Memory admission (docs/api.md): the one rule that says whether a reconstruction fits.

:func:`estimate_memory` is a job's peak memory (bytes) from the shape of its input and its
options; :func:`admit` refuses an estimate over the memory limit (:class:`AdmissionError`,
a ``ValueError``: 422 over HTTP, exit 2 on the command line). The input's shape comes from
:func:`input_shape`, the one place it is built (a plan, a stored dataset's record or a
loaded dataset). The API estimates once, before a job is queued, and stores the figure
with the job; the worker admits that figure against the configured limit (and estimates
from the dataset as loaded only for a job that carries none, ``fpscan.service.jobs.work``); the
queue (``fpscan.service.jobs.queue``) starts a job only while the running jobs' estimates plus
its own fit. The methods' own peak models are ``fpscan.service.recon.memory``'s (each method's
``peak_memory``, ``fpscan.service.recon.methods``), with the method's admission class (its
``memory_calibration`` margin, whether it ``holds_input``).
"""
from __future__ import annotations

import math
from typing import Any

from fpscan.constants import C_AUTOFOCUS_RANGE, C_DEFAULT

__all__ = ["MAX_DEPTH_ROWS", "AUTOFOCUS_EVALUATIONS", "AdmissionError", "admit", "admit_device", "estimate_gpu_memory", "estimate_memory",
           "estimate_work", "admit_work", "estimate_result_bytes", "input_shape", "output_depth_rows",
           "working_depth_rows"]


class AdmissionError(ValueError):
    """A job that can never fit in the memory limit (or the work limit, or a depth grid that
    can never be made); a ``ValueError``: 422 over HTTP, exit 2 on the command line.

    Parameters
    ----------
    message : str
        The reason, naming the estimate and the limit (what the user reads).
    """


#: Most depth rows the depth transform may work on (``dz`` far below ``c·dt`` multiplies
#: them); beyond this a request is refused whatever the memory limit.
MAX_DEPTH_ROWS = 1 << 20


def input_shape(source: Any) -> dict:
    """The shape of a reconstruction's input for :func:`estimate_memory` and
    :func:`estimate_work` (their ``shape`` argument).

    Parameters
    ----------
    source : dict or GridDataset or PointDataset
        One of

        - a plan document (``{"lattice", "acquisition", "points", ...}``: a scan's input, one
          A-line per plan point);
        - a stored dataset's record (``{"layout": "grid" | "points", "shape", "dt", "sound_speed", "dx",
          ...}``, ``fpscan.service.jobs.store``);
        - a loaded `fpscan.service.recon.dataset.GridDataset` / `PointDataset`.

    Returns
    -------
    dict
        ``n_t``, ``n_x``, ``n_y``, ``n_points`` (sensor points; absent for grid data), ``dt``
        (s), ``sound_speed`` (m/s), ``dx`` (m, the lateral pitch; None when unknown), ``t0`` (s, the time
        of sample 0; None when unknown: a dataset stored by an older server), for a loaded
        dataset ``input_itemsize`` (bytes a sample) and for a plan ``n_wavelengths``; for a
        stored record, where it has them, ``record_facts`` (what the record holds above its
        noise, found at import: tv sizes its cut record from them) and ``bandwidth`` (a
        declared sensor bandwidth, Hz).

    Raises
    ------
    ValueError
        ``source`` is none of these.
    """
    from fpscan.service.recon.dataset import GridDataset, PointDataset

    if isinstance(source, GridDataset):
        d = source.data
        return {"n_t": d.shape[0], "n_x": d.shape[-1], "n_y": d.shape[1] if d.ndim == 3 else 1, "dx": source.dx,
                "dt": source.dt, "sound_speed": source.sound_speed, "t0": source.t0, "input_itemsize": d.itemsize}
    if isinstance(source, PointDataset):
        grid = source.grid
        return {"n_t": source.alines.shape[1], "n_x": len(grid[0]), "n_y": len(grid[1]) if len(grid) > 1 else 1,
                "n_points": source.alines.shape[0],
                "dx": float(grid[0][1] - grid[0][0]) if len(grid[0]) > 1 else None,
                "dt": source.dt, "sound_speed": source.sound_speed, "t0": source.t0, "input_itemsize": source.alines.itemsize}
    if isinstance(source, dict) and "lattice" in source and "acquisition" in source:
        lat, acq = source["lattice"], source["acquisition"]
        return {"n_t": acq["n_t"], "n_x": lat["n_x"], "n_y": lat.get("n_y", 1),
                "n_points": len(source["points"]["indices"]), "dt": acq["dt"], "sound_speed": acq.get("sound_speed"),
                "dx": lat.get("pitch"), "t0": 0.0, "n_wavelengths": max(len(acq.get("wavelengths") or []), 1)}
    if isinstance(source, dict) and source.get("layout") == "grid":
        s = source["shape"]
        return {"n_t": s[0], "n_x": s[-1], "n_y": s[1] if len(s) == 3 else 1, "dt": source.get("dt"),
                "sound_speed": source.get("sound_speed"), "dx": source.get("dx"), "t0": source.get("t0"), **_facts(source)}
    if isinstance(source, dict) and source.get("layout") == "points":
        n, n_t = source["shape"]
        side = int(math.ceil(math.sqrt(n)))
        return {"n_t": n_t, "n_x": source.get("n_x", side), "n_y": source.get("n_y", side), "n_points": n,
                "dt": source.get("dt"), "sound_speed": source.get("sound_speed"), "dx": source.get("dx"), "t0": source.get("t0"),
                **_facts(source)}
    raise ValueError(f"no input shape for {type(source).__name__}: give a plan, a stored dataset's record or a "
                     "loaded dataset")


def _facts(record: dict) -> dict:
    """What a stored dataset's record says of its data beyond their shape: ``record_facts``
    (what the record holds above its noise, ``fpscan.service.recon.tv.grid.RecordFacts``, stored at
    import) and a declared ``bandwidth`` (Hz), where it has them."""
    from fpscan.service.recon.methods.tv import BANDWIDTH_KEY

    out = {}
    if isinstance(record.get("record_facts"), dict):
        out["record_facts"] = record["record_facts"]
    if record.get(BANDWIDTH_KEY) is not None:
        out["bandwidth"] = record[BANDWIDTH_KEY]
    return out


def _speed(shape: dict, params: dict) -> float:
    """The speed of sound a job reconstructs at, m/s: ``params["sound_speed"]``, the fastest of
    ``sound_speed_range`` (default ``C_AUTOFOCUS_RANGE``) for ``"auto"`` (it reaches deepest),
    else the input's, else ``C_DEFAULT``."""
    c_param = params.get("sound_speed")
    if c_param == "auto":  # autofocus: the fastest speed it may choose reaches deepest
        c_param = max(params.get("sound_speed_range") or C_AUTOFOCUS_RANGE)
    return float(c_param or shape.get("sound_speed") or C_DEFAULT)


def _start(shape: dict, params: dict) -> float:
    """The time of sample 0, s: the input's, else ``params["t0"]``, else 0."""
    return float(shape.get("t0") or params.get("t0") or 0.0)


def output_depth_rows(shape: dict, params: dict) -> int:
    """The depth rows of the output volume: ``n_z``, else the default grid's
    (``fpscan.service.recon.depth.depth_grid``, every method's rule: the input's pitch ``dx``,
    c·dt where that is finer, down to c·t_last), as the reconstruction makes them. Where the
    input declares a sensor band f (``bandwidth``, at which ``tv`` works: its spacing c / (2 f))
    and that spacing is finer, its rows are counted: an upper bound for every method.

    Parameters
    ----------
    shape : dict
        :func:`input_shape`'s: ``n_t`` and, for the default grid, ``dt`` (s), ``dx`` (m; None:
        not known, the spacing is then c·dt, the most rows), ``sound_speed`` (m/s), ``t0`` (s)
        and ``bandwidth`` (Hz).
    params : dict
        The options: ``n_z``, ``dz`` (m), ``sound_speed`` (m/s, or ``"auto"``: the fastest of
        ``sound_speed_range``), ``t0`` (s, where the shape has none).

    Returns
    -------
    int
        Rows; ``n_z`` (default ``n_t``) where ``dt`` is not known.

    Raises
    ------
    ValueError
        ``n_z`` or ``dz`` outside its range (``fpscan.service.recon.checks.OptionError``).

    Examples
    --------
    >>> from fpscan.service.jobs.admission import output_depth_rows
    >>> shape = {"n_t": 751, "n_x": 96, "n_y": 96, "dt": 8e-9, "dx": 60e-6, "sound_speed": 1500.0}
    >>> output_depth_rows(shape, {}), output_depth_rows(shape, {"n_z": 64}), output_depth_rows(shape, {"dz": 3e-5})
    (151, 64, 301)
    """
    n_t = int(shape["n_t"])
    if shape.get("dt") is None:
        return int(params.get("n_z") or n_t)
    from fpscan.service.recon.depth import depth_grid

    c, pitch = _speed(shape, params), shape.get("dx")
    if pitch and shape.get("bandwidth"):  # tv's spacing at a declared sensor band, where finer
        pitch = min(float(pitch), c / (2.0 * float(shape["bandwidth"])))
    _, n_z = depth_grid(n_t, float(shape["dt"]), c, pitch, dz=params.get("dz") or None,
                        n_z=params.get("n_z") or None, t0=_start(shape, params))
    return n_z


def working_depth_rows(shape: dict, params: dict) -> int:
    """The depth rows the reconstruction works on: ``max(n_z, ceil(c·t_last/dz) + 1)``
    (``fpscan.service.recon.planar``: no recorded signal may fold back through the depth
    period), with the output grid's ``n_z`` and ``dz`` (:func:`output_depth_rows`; the default
    ``dz`` the input's pitch ``dx``, c·dt where that is finer or not known).

    Parameters
    ----------
    shape : dict
        :func:`input_shape`'s: needs ``n_t`` and, for the depth reached, ``dt`` (s), ``dx`` (m),
        ``sound_speed`` (m/s; ``params["sound_speed"]`` wins) and ``t0`` (s).
    params : dict
        The options: ``n_z``, ``dz`` (m), ``sound_speed`` (m/s, or ``"auto"``: the fastest of
        ``sound_speed_range``, default ``C_AUTOFOCUS_RANGE``), ``t0`` (s).

    Returns
    -------
    int
        Depth rows; ``n_z`` (default ``n_t``) when ``dt`` is not given.

    Raises
    ------
    AdmissionError
        The rows ``c·t_last/dz`` reach are not fewer than :data:`MAX_DEPTH_ROWS`.
    ValueError
        What :func:`output_depth_rows` refuses.
    """
    n_t = int(shape["n_t"])
    if shape.get("dt") is None:
        return int(params.get("n_z") or n_t)
    from fpscan.service.recon.depth import default_spacing

    c, dt = _speed(shape, params), float(shape["dt"])
    dz = float(params["dz"]) if params.get("dz") else default_spacing(dt, c, shape.get("dx"))
    reach = c * (_start(shape, params) + (n_t - 1) * dt) / dz
    if not reach < MAX_DEPTH_ROWS:
        raise AdmissionError(f"dz = {dz:g} m is too fine for this input: the depth transform would need "
                             f"{reach:.3g} rows (at most {MAX_DEPTH_ROWS}); use a larger dz (c·dt is "
                             f"{c * dt:.3g} m)")
    return max(output_depth_rows(shape, params), int(reach) + 2)


def _default_method(shape: dict) -> str:
    """The registry's default method for an input of this shape (points when it has
    ``n_points``, else a grid): ``fpscan.service.recon.methods.default_for``."""
    from fpscan.service.recon.methods import default_for

    return default_for("points" if shape.get("n_points") else "grid")


def estimate_memory(shape: dict, params: dict) -> int:
    """Peak memory (bytes) of a reconstruction with the options actually used — the one
    admission rule, applied before a job is queued and again by the worker.

    The method's peak-memory model of the working depth rows (:func:`working_depth_rows`)
    times the method's ``memory_calibration``, plus the input as loaded (unless it is in the
    working precision and the method does not ``holds_input``). The peak model is the
    method's (``fpscan.service.recon.methods``, its ``peak_memory``: a model of
    ``fpscan.service.recon.memory``).

    Parameters
    ----------
    shape : dict
        :func:`input_shape`'s: ``n_t`` and ``n_x`` (``n_y``) of the output grid, ``n_points``
        for point inputs, ``input_itemsize`` (bytes a sample of the input as loaded; default
        8), ``dt`` (s), ``sound_speed`` (m/s) and the lateral pitch ``dx`` (m) of the input (optional;
        the model-based ``tv`` pads its grid by the record's reach in pitches), ``t0`` (s),
        ``record_facts`` and ``bandwidth`` (a stored record's: tv's grid for its data).
    params : dict
        ``method`` (default: the registry's default for the input's layout), ``dtype``
        (default ``"float32"``), ``upsample``, ``n_z``, ``dz`` (m), ``sound_speed`` (m/s or ``"auto"``).

    Returns
    -------
    int
        Bytes.

    Raises
    ------
    AdmissionError
        A depth grid that can never be made (:func:`working_depth_rows`).
    """
    n_t = int(shape["n_t"])
    n_x = int(shape["n_x"])
    n_y = int(shape.get("n_y", 1))
    rows = working_depth_rows(shape, params)
    from fpscan.service.recon.methods import get as method_named

    geometry: dict[str, float | None] = {}
    if shape.get("dx") and shape.get("dt"):  # the model-based operator's padding depends on them
        c = params.get("sound_speed")
        c = max(params.get("sound_speed_range") or C_AUTOFOCUS_RANGE) if c == "auto" else c
        geometry = {"dx": float(shape["dx"]), "dt": float(shape["dt"]), "c": float(c or shape.get("sound_speed") or C_DEFAULT),
                    "dz": float(params["dz"]) if params.get("dz") else None}
    # the method's own peak-memory model (fpscan.service.recon.methods: its module's peak_memory hook)
    method = method_named(params.get("method") or _default_method(shape))
    value = method.memory(
        n_t, n_x, n_y, n_z=rows, upsample=method.upsample(params), dtype=params.get("dtype") or "float32",
        n_points=shape.get("n_points"), dx=geometry.get("dx"), dt=geometry.get("dt"), c=geometry.get("c"),
        dz=geometry.get("dz"), t0=shape.get("t0"), options=params, record_facts=shape.get("record_facts"),
        bandwidth=shape.get("bandwidth"))
    factor = method.memory_calibration
    # + the input as loaded (shape["input_itemsize"] bytes a sample, default 8: float64, as scan files load),
    # unless it is in the working precision: then it is the working copy the estimate already counts
    itemsize = int(shape.get("input_itemsize") or 8)
    work = 8 if (params.get("dtype") or "float32") == "float64" else 4
    loaded = 0 if itemsize == work and not method.holds_input else itemsize
    return int(factor * value) + n_t * int(shape.get("n_points", n_x * n_y)) * loaded


def estimate_gpu_memory(shape: dict, params: dict) -> int | None:
    """GPU memory (bytes) of a reconstruction's GPU path, for the methods whose whole peak the
    GPU path models (`fpscan.service.recon.gpu.inversion_peak`: NER and NEDNER); None for the others
    (tv's operator is sized on the GPU when it is made, `fpscan.service.recon.gpu.operator_peak`, and
    sends an ``"auto"`` job to the CPU, or fails a ``"cuda"`` one with the reason).

    Parameters
    ----------
    shape, params : dict
        As :func:`estimate_memory`.

    Returns
    -------
    int or None
        Bytes.

    Raises
    ------
    AdmissionError
        A depth grid that can never be made (:func:`working_depth_rows`).
    """
    method = params.get("method") or _default_method(shape)
    if method not in ("ner", "nedner"):
        return None
    from fpscan.physics.fast_lengths import fast_lateral
    from fpscan.service.recon import gpu

    n_t, n_x, n_y = int(shape["n_t"]), int(shape["n_x"]), int(shape.get("n_y", 1))
    n_yp, n_xp = fast_lateral(n_y, n_x, square=True)
    rows = working_depth_rows(shape, params)
    upsample = int(params.get("upsample") or 1)
    n_out = output_depth_rows(shape, params) * n_x * upsample * (n_y * upsample if n_y > 1 else 1)
    data = n_t * n_x * n_y if method == "ner" else 0
    return gpu.inversion_peak(n_t, n_yp * (n_xp // 2 + 1), rows, n_out, float(params.get("eps") or 1e-6),
                              params.get("dtype") or "float32", data)


def admit_device(shape: dict, params: dict, gpus: list[dict]) -> None:
    """Refuse a job that asks for ``device: "cuda"`` where it can never run: the server has no
    GPU, or the job's GPU path needs more than the largest GPU's memory (`estimate_gpu_memory`;
    the free memory is checked again when the job runs, `fpscan.service.recon.device.choose`).
    ``"auto"`` and ``"cpu"`` jobs always pass (the CPU takes what the GPU cannot).

    Parameters
    ----------
    shape, params : dict
        As :func:`estimate_memory` (``params["device"]``: ``"auto"``, ``"cpu"`` or ``"cuda"``).
    gpus : list of dict
        The server's GPUs (``name``, ``memory_total`` in bytes; `fpscan.service.recon.device.probe_devices`).

    Raises
    ------
    AdmissionError
        The reason.
    """
    if params.get("device") != "cuda":
        return
    if not gpus:
        raise AdmissionError("device 'cuda' was asked, but this server has no CUDA GPU (GET /api/health lists its "
                             "devices); ask for 'auto' or 'cpu'")
    need = estimate_gpu_memory(shape, params)
    largest = max(gpus, key=lambda g: int(g["memory_total"]))
    from fpscan.service.recon.device import GPU_MEMORY_SHARE

    if need is not None and need > GPU_MEMORY_SHARE * int(largest["memory_total"]):
        raise AdmissionError(f"the GPU path needs about {need / 2**30:.2f} GiB of GPU memory, more than the server's "
                             f"GPU ({largest['name']}, {int(largest['memory_total']) / 2**30:.2f} GiB) has; ask for "
                             "'auto' or 'cpu'")


def estimate_result_bytes(shape: dict, params: dict, volumes: int = 1) -> int:
    """Bytes a reconstruction's result folder takes on disk: ``volumes`` images of
    :func:`output_depth_rows` rows (k-Wave's modes: ``n_t``) by the lateral grid times the method's
    upsampling (``fpscan.service.recon.methods.Method.upsample``: its ``upsample`` option, 1 without) in
    the working precision (``volume.h5``, chunked and uncompressed), 2 % for the HDF5 file's
    own structure and 1 MiB per volume for its pictures (MIPs: PNG). The queue holds a job
    whose result does not fit the free disk and ends a running one whose result no longer
    does (``fpscan.service.jobs.queue``).

    Parameters
    ----------
    shape : dict
        :func:`input_shape`'s.
    params : dict
        ``method``, ``n_z``, ``dz``, ``upsample``, ``dtype``, ``sound_speed``.
    volumes : int, optional
        Volumes written (a wavelength each; an unmixing job's maps count as 5 more).

    Returns
    -------
    int
        Bytes.

    Examples
    --------
    >>> from fpscan.service.jobs.admission import estimate_result_bytes
    >>> estimate_result_bytes({"n_t": 256, "n_x": 128, "n_y": 128}, {"method": "ner"})  # float32
    18161336
    """
    from fpscan.service.recon.methods import get as method_named

    method = method_named(params.get("method") or _default_method(shape))
    takes_depth = "n_z" in method.options
    n_z = output_depth_rows(shape, params) if takes_depth else int(shape["n_t"])  # else n_t rows (k-Wave)
    up = method.upsample(params)  # the method's lateral upsampling (1 where it takes no upsample)
    n_y = int(shape.get("n_y", 1))
    voxels = n_z * int(shape["n_x"]) * up * (n_y * up if n_y > 1 else 1)
    itemsize = 8 if (params.get("dtype") or "float32") == "float64" else 4
    return int(max(1, volumes) * (voxels * itemsize * 1.02 + (1 << 20)))


#: reconstructions an autofocus search (``sound_speed: "auto"``) makes besides the final one, at
#: most (``fpscan.service.autofocus``: a coarse scan of 7, then up to 8 refinements)
AUTOFOCUS_EVALUATIONS = 15


def estimate_work(shape: dict, params: dict) -> float:
    """The work of a reconstruction with the options actually used, in seconds on the
    reference 2 cores (``fpscan.service.recon.methods.FLOAT64_WORK``) -- the one work rule, applied
    with :func:`admit_work` before a job is queued.

    The method's own estimate (``fpscan.service.recon.methods``: its ``work`` hook; the planar
    methods' ``transform_units`` of their transform grid times their measured rate, tv's
    operator pairs on its padded grid, its iterations' share capped by ``time_limit``), on
    the working depth rows (:func:`working_depth_rows`), plus an autofocus search's
    evaluations when ``sound_speed`` is ``"auto"``. A method's hook may refuse options the input
    cannot carry (tv: an image deeper than the record can hear; kwave: an input whose sample
    0 is not at t = 0), with the words the worker would use.

    Parameters
    ----------
    shape : dict
        :func:`input_shape`'s.
    params : dict
        ``method`` and the options as asked (``sound_speed`` in m/s or ``"auto"``, ``dz`` m,
        ``time_limit`` s, ...).

    Returns
    -------
    float
        Seconds.

    Raises
    ------
    AdmissionError
        A depth grid that can never be made (:func:`working_depth_rows`).
    ValueError
        The method's refusal (``fpscan.service.recon.checks.OptionError``).
    """
    n_t, n_x, n_y = int(shape["n_t"]), int(shape["n_x"]), int(shape.get("n_y", 1))
    rows = working_depth_rows(shape, params)
    from fpscan.service.recon.methods import get as method_named

    c = params.get("sound_speed")
    c = max(params.get("sound_speed_range") or C_AUTOFOCUS_RANGE) if c == "auto" else c
    name = params.get("method") or _default_method(shape)
    common = dict(upsample=method_named(name).upsample(params), dtype=params.get("dtype") or "float32",
                  n_points=shape.get("n_points"), dx=shape.get("dx"), dt=shape.get("dt"),
                  c=float(c or shape.get("sound_speed") or C_DEFAULT), t0=shape.get("t0"),
                  record_facts=shape.get("record_facts"), bandwidth=shape.get("bandwidth"))
    seconds = method_named(name).estimate_work(n_t, n_x, n_y, n_z=rows, options=params, **common)
    if params.get("sound_speed") == "auto":  # the search: the method itself, or the direct method for an iterative one
        search = _default_method(shape) if method_named(name).iterative else name
        depth = 3 * n_t  # its grid: twice as fine as the decimated samples at c_min, as deep as c_max reaches
        seconds += AUTOFOCUS_EVALUATIONS * method_named(search).estimate_work(
            n_t, n_x, n_y, n_z=depth, options={}, **{**common, "upsample": 1, "dtype": "float32"})
    return seconds


def admit_work(seconds: float, limit_s: float) -> None:
    """Refuse a reconstruction whose estimated work is over the server's work limit.

    Parameters
    ----------
    seconds : float
        The estimate (:func:`estimate_work`), in s on the reference 2 cores.
    limit_s : float
        The server's ``work_limit_s``, in s.

    Raises
    ------
    AdmissionError
        ``seconds`` > ``limit_s``, saying the estimate and the limit.
    """
    if seconds > limit_s:
        raise AdmissionError(f"reconstruction needs about {_duration(seconds)} of work by its estimate ({seconds:.3g} "
                             f"s on 2 cores), more than the server's work limit of {_duration(limit_s)} "
                             f"(work_limit_s = {limit_s:g} s); reduce the size, n_z, upsample, iterations or "
                             "time_limit, or use a larger dz or float32")


def _duration(seconds: float) -> str:
    """``seconds`` in words: ``"42 s"``, ``"12 min"``, ``"3.4 h"``, ``"2.1 days"``."""
    if seconds < 120:
        return f"{seconds:.3g} s"
    if seconds < 7200:
        return f"{seconds / 60:.3g} min"
    if seconds < 2 * 86400:
        return f"{seconds / 3600:.3g} h"
    return f"{seconds / 86400:.3g} days"


def admit(estimate: int, limit: int) -> None:
    """Refuse a reconstruction whose estimated peak memory is over the memory limit.

    Parameters
    ----------
    estimate : int
        The peak memory (:func:`estimate_memory`), in bytes.
    limit : int
        The memory limit, in bytes.

    Raises
    ------
    AdmissionError
        ``estimate`` > ``limit``, with the reason (both in GiB).
    """
    if estimate > limit:
        raise AdmissionError(f"reconstruction needs about {estimate / 2**30:.2f} GiB, more than the "
                             f"memory limit of {limit / 2**30:.2f} GiB; reduce the size, upsample or n_z, or use a "
                             "larger dz or float32")
