"""The methods' work and memory estimators: the peak-memory model of a method
(:func:`peak_model`; the registry's ``estimate_peak_memory`` asks a method for its own) and the planar methods' work estimate in
seconds on the reference 2 cores (:func:`transform_units`, :func:`planar_work`,
:data:`FLOAT64_WORK`, :data:`PLANAR_WORK_RATE`), which a :class:`~.registry.Method` names as
its ``peak_memory`` and ``work`` hooks (the admission, ``fpscan.service.jobs.admission``).

Importing this module needs no numpy: the models of ``fpscan.service.recon.memory`` load on a call.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["peak_model", "FLOAT64_WORK", "PLANAR_WORK_RATE", "transform_units",
           "planar_work", "UNDECLARED_COPIES", "UNDECLARED_BASE", "UNDECLARED_PAIR_RATE", "undeclared_peak",
           "undeclared_work"]


def peak_model(model: str, **fixed: Any) -> Callable[..., int]:
    """A method's peak-memory model: the model ``model`` of ``fpscan.service.recon.memory`` with the
    keywords ``fixed`` (what the method's kernels do), imported on the first call (this package
    loads without numpy).

    Parameters
    ----------
    model : str
        A model of ``fpscan.service.recon.memory``: ``"planar_peak"``, ``"kwave_peak"``,
        ``"model_based_peak"``.
    **fixed
        Its keywords for this method (``temporal="nufft"``, ``points=True``, ...).

    Returns
    -------
    callable
        ``peak(n_t, n_x, n_y=1, **kw) -> int``: bytes at the peak of a reconstruction of
        ``n_t`` time samples on ``n_y`` x ``n_x`` sensors; the keywords (``n_z``, ``upsample``,
        ``dtype``, ``n_points``, ``dx`` m, ``dt`` s, ``c`` m/s, ``dz`` m) as the model's.

    Raises
    ------
    AttributeError
        From the returned ``peak``: no such model.

    Examples
    --------
    >>> from fpscan.service.recon.memory import planar_peak
    >>> from fpscan.service.recon.methods import peak_model
    >>> peak = peak_model("planar_peak", temporal="nufft")
    >>> peak(64, 8, dtype="float32") == planar_peak(64, 8, dtype="float32", temporal="nufft")
    True
    >>> peak(256, 64, 64) > peak(64, 8)  # bytes grow with the input
    True
    """
    def peak(n_t: int, n_x: int, n_y: int = 1, **kw: Any) -> int:
        import fpscan.service.recon.memory as memory

        return int(getattr(memory, model)(n_t, n_x, n_y, **{**kw, **fixed}))

    return peak


#: the work estimates' reference: seconds on 2 cores of the machine they were measured on
#: (AMD EPYC Zen 4, AVX-512, shared with other work: load average 4-6); float64 costs this
#: factor more than float32 (measured 1.1-2.4, planar methods at 256 x 128^2 to 512 x 226^2)
FLOAT64_WORK = 1.6



#: seconds per :func:`transform_units` unit of a planar method that states none (float32)
PLANAR_WORK_RATE = 3e-9


def transform_units(n_t: int, n_x: int, n_y: int = 1, *, n_z: int | None = None, upsample: int = 1) -> float:
    """The work unit of the planar methods: ``N log2 N`` for the transform grid they work on,
    ``N`` = the working depth rows (at least ``n_t``, at a fast DCT-I length) times the
    lateral transform sizes (``fpscan.service.recon.memory.padded_lateral``), an upsampled inverse
    counted as ``1 + (u² - 1) / 4`` such grids (measured: upsample 2 costs 1.1-3x upsample 1).

    Parameters
    ----------
    n_t : int
        Samples per A-line.
    n_x, n_y : int
        Lateral grid (``n_y = 1`` in 2-D).
    n_z : int, optional
        Working depth rows (default ``n_t``).
    upsample : int, optional
        Lateral upsampling factor.

    Returns
    -------
    float
        ``N log2 N`` (dimensionless).

    Examples
    --------
    >>> from fpscan.service.recon.methods import transform_units
    >>> transform_units(256, 128, 128) > transform_units(256, 64, 64) > 0
    True
    """
    import math

    from fpscan.physics.fast_lengths import fast_dct1_rows
    from fpscan.service.recon.memory import padded_lateral

    rows = fast_dct1_rows(max(int(n_z or n_t), int(n_t), 2))
    p_y, p_x = padded_lateral(int(n_y), int(n_x))
    u = int(upsample or 1)
    n = rows * p_y * p_x * (1 + (u * u - 1) / 4)
    return n * math.log2(max(n, 2.0))


def planar_work(rate: float, per_point_sample: float = 0.0) -> Callable[..., float]:
    """A planar method's work estimate: ``rate`` seconds per :func:`transform_units` unit
    (float32; float64 :data:`FLOAT64_WORK` times that), plus ``per_point_sample`` seconds per
    sensor point and sample (NEDNER's type-1 NUFFT over the points).

    Parameters
    ----------
    rate : float
        Seconds per unit, measured on the reference machine (each method's module).
    per_point_sample : float, optional
        Seconds per sensor point and time sample.

    Returns
    -------
    callable
        ``work(n_t, n_x, n_y=1, *, n_z, upsample, dtype, n_points, **_) -> float`` seconds.

    Examples
    --------
    >>> from fpscan.service.recon.methods import planar_work
    >>> work = planar_work(2e-9)
    >>> 0.05 < work(256, 128, 128, dtype="float32") < 1.0  # s: NER measured 0.14-0.17 s there
    True
    >>> work(256, 128, 128, dtype="float64") > work(256, 128, 128, dtype="float32")
    True
    """
    def work(n_t: int, n_x: int, n_y: int = 1, *, n_z: int | None = None, upsample: int = 1,
             dtype: Any = "float32", n_points: int | None = None, **_: Any) -> float:
        seconds = rate * transform_units(n_t, n_x, n_y, n_z=n_z, upsample=upsample)
        seconds += per_point_sample * float(n_points or 0) * float(n_t)
        return seconds * (FLOAT64_WORK if str(dtype) == "float64" else 1.0)

    return work


#: the conservative rule for a method that declares no peak-memory model: this many float64 copies
#: of the larger of its input (``n_t`` samples on every sensor) and its output volume (``n_z`` rows
#: on the upsampled lateral grid). fpscan's own models peak at 1.5-22 such copies (measured with
#: their models from 256 x 64^2 to 1024 x 226^2: NER 2.1-2.3, NEDNER 3.1-3.5, cubic 11.6-12.9, tv
#: 1.7-4.9, k-Wave 1.5-22, the most at the smallest size); 32 is above all of them
UNDECLARED_COPIES = 32
#: bytes the conservative rule adds for the process's own needs (imports, buffers)
UNDECLARED_BASE = 256 * 2**20
#: the conservative rule for a method that declares no work model: seconds per (sensor, voxel)
#: pair, float32 on the reference 2 cores -- a direct back-projection touches every A-line once per
#: voxel; a plain numpy delay-and-sum (the gallery's plugin: a few passes of array arithmetic per
#: pair, chunked over depth) measured 21-41 ns per pair there, so 50 ns is above it
UNDECLARED_PAIR_RATE = 5e-8


def _voxels(n_t: int, n_x: int, n_y: int, n_z: int | None, upsample: int) -> int:
    u = int(upsample or 1)
    return int(n_z or n_t) * int(n_x) * u * int(n_y) * u


def undeclared_peak(n_t: int, n_x: int, n_y: int = 1, *, n_z: int | None = None, upsample: int = 1,
                    n_points: int | None = None, **_: Any) -> int:
    """The peak memory the admission counts for a method that declares no model (a plugin's):
    :data:`UNDECLARED_COPIES` float64 copies of the larger of its input and its output, plus
    :data:`UNDECLARED_BASE`. Never NER's figure: a method the admission knows nothing of is
    judged by a rule above every model fpscan's own methods have.

    Parameters
    ----------
    n_t : int
        Samples per A-line.
    n_x, n_y : int
        The lateral grid (``n_y = 1`` in 2-D).
    n_z : int, optional
        Output depth rows (default ``n_t``).
    upsample : int, optional
        Lateral upsampling of the output.
    n_points : int, optional
        Sensors of point data (default every grid point, ``n_x n_y``).

    Returns
    -------
    int
        Bytes.

    Examples
    --------
    >>> from fpscan.service.recon.methods.work import undeclared_peak
    >>> undeclared_peak(256, 64, 64) // 2**20  # MiB: 32 float64 copies of 256 x 64 x 64 (256 MiB), + 256
    512
    """
    inputs = int(n_t) * int(n_points or int(n_x) * int(n_y))
    return int(UNDECLARED_COPIES * 8 * max(inputs, _voxels(n_t, n_x, n_y, n_z, upsample)) + UNDECLARED_BASE)


def undeclared_work(n_t: int, n_x: int, n_y: int = 1, *, n_z: int | None = None, upsample: int = 1,
                    n_points: int | None = None, dtype: Any = "float32", **_: Any) -> float:
    """The seconds of work the admission counts for a method that declares no model (a
    plugin's): :data:`UNDECLARED_PAIR_RATE` per (sensor, voxel) pair (a direct back-projection's
    count), :data:`FLOAT64_WORK` times that in float64. Never NER's figure (``N log N``).

    Parameters
    ----------
    n_t : int
        Samples per A-line.
    n_x, n_y : int
        The lateral grid.
    n_z : int, optional
        Output depth rows (default ``n_t``).
    upsample : int, optional
        Lateral upsampling of the output.
    n_points : int, optional
        Sensors of point data (default every grid point).
    dtype : str or numpy dtype, optional
        The working precision.

    Returns
    -------
    float
        Seconds on the reference 2 cores.

    Examples
    --------
    >>> from fpscan.service.recon.methods.work import undeclared_work
    >>> round(undeclared_work(256, 64, 64), 1)  # 4096 sensors x 1 Mi voxels x 50 ns
    214.7
    """
    pairs = float(n_points or int(n_x) * int(n_y)) * _voxels(n_t, n_x, n_y, n_z, upsample)
    factor = FLOAT64_WORK if "64" in str(dtype) else 1.0
    return UNDECLARED_PAIR_RATE * pairs * factor
