"""``ner``: NER-NUFFT on a full regular grid (paper §3.1): a temporal NUFFT and a lateral
FFT (kernel: :func:`fpscan.service.recon.planar.reconstruct_grid`)."""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from fpscan.service.recon.limits import DEFAULT_DTYPE, DEFAULT_EPS
from fpscan.service.recon.methods.options import (
    DepthOptions,
    DeviceOption,
    MethodOptions,
    NufftOptions,
    PositivityOption,
    UpsampleOption,
)
from fpscan.service.recon.methods.registry import Method
from fpscan.service.recon.methods.work import peak_model, planar_work

if TYPE_CHECKING:
    from fpscan.service.recon.dataset import GridDataset
    from fpscan.service.recon.reconstruction import Reconstruction

__all__ = ["Options", "run", "run_grid", "WORK_RATE", "warm_up", "METHOD"]


class Options(DeviceOption, DepthOptions, PositivityOption, UpsampleOption, MethodOptions, NufftOptions):
    """Options of ``ner`` (the fields of its mix-ins; SI units).

    Attributes
    ----------
    eps : float
        NUFFT tolerance in [1e-14, 1e-1] (default 1e-6).
    dtype : {"float32", "float64"}
        Working and output precision (default ``"float32"``).
    upsample : int
        Lateral upsampling factor 1..8 (default 1).
    positivity : bool
        Clip negative p0 to 0 (default False).
    n_z : int or None
        Output depth samples, 2..65536 (None: down to c t_last; ``fpscan.service.recon.depth``).
    dz : float or None
        Output depth spacing in m, [1e-9, 0.1] (None: the lateral pitch, c dt where that is finer).

    Examples
    --------
    >>> from pydantic import ValidationError
    >>> from fpscan.service.recon.methods.ner import Options
    >>> Options().model_dump()
    {'eps': 1e-06, 'sound_speed': None, 'sound_speed_range': None, 'force': False, 'dtype': 'float32', 'upsample': 1, 'positivity': False, 'n_z': None, 'dz': None, 'device': 'auto'}
    >>> try:
    ...     Options(eps=5e-15)
    ... except ValidationError as exc:
    ...     print(exc.errors()[0]["msg"])
    Value error, eps must be in [1e-14, 1e-1], got 5e-15
    """


def run_grid(name: str, ds: GridDataset, sound_speed: float, options: MethodOptions,
             step: Callable[[float], None]) -> Reconstruction:
    """``fpscan.service.recon.planar.reconstruct_grid`` with ``method=name`` on grid data
    ``ds.data`` ``(n_t, n_y, n_x)`` or ``(n_t, n_x)``, the speed of sound in m/s, the validated options.

    Parameters
    ----------
    name : str
        ``reconstruct_grid``'s method: ``"ner"``, ``"linear"``, ``"nearest"`` or ``"cubic"``.
    ds : GridDataset
        ``data`` ``(n_t, n_x)`` or ``(n_t, n_y, n_x)`` (time first) at pitch ``dx`` (and
        ``dy``) in m, sample interval ``dt`` in s, first sample at ``t0`` s.
    sound_speed : float
        Speed of sound, m/s.
    options : Options
        The method's validated options (``ner``'s, or ``fpscan.service.recon.methods.interp.Options``:
        the same fields but ``eps``; ``n_z``/``dz`` None: derived from the data).
    step : callable
        ``step(fraction)``, called with increasing fractions in (0, 1]; it may raise to
        cancel.

    Returns
    -------
    Reconstruction
        p0 ``(n_z, n_x u)`` / ``(n_z, n_y u, n_x u)`` (u = ``upsample``), row 0 at z = 0,
        with ``z``, ``x``, ``y`` in m and ``params``.

    Raises
    ------
    ValueError
        What ``reconstruct_grid`` refuses (NaN/inf data, fewer than 2 samples, an estimated
        peak memory above the limit, ...).

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", §3.1 (NER).
    .. [2] M. Xu, D. Feng, L. V. Wang, "Exact frequency-domain reconstruction for
       thermoacoustic tomography: I. Planar geometry", IEEE Trans. Med. Imaging 21 (2002)
       (the interpolating methods).

    Examples
    --------
    A laterally uniform layer at depth row 10 (data g = p0(c t) / 2 at every sensor):

    >>> import numpy as np
    >>> from fpscan.service.recon.dataset import GridDataset
    >>> from fpscan.service.recon.methods.ner import Options, run_grid
    >>> g = np.zeros((64, 8))  # (n_t, n_x)
    >>> g[10] = 0.5
    >>> ds = GridDataset(g, dx=1e-4, dt=1e-4 / 1500, sound_speed=1500.0)  # dz = c dt = 0.1 mm
    >>> from fpscan.service.recon.methods.interp import Options
    >>> r = run_grid("linear", ds, 1500.0, Options(), lambda fraction: None)
    >>> r.p0.shape, r.p0.dtype, int(r.p0[:, 4].argmax()), round(float(r.p0[10, 4]), 3)
    ((64, 8), dtype('float32'), 10, 1.0)
    >>> r.params["method"]
    'linear'
    """
    from fpscan.service.recon.planar import reconstruct_grid

    dy = ds.dy if ds.data.ndim == 3 else None
    # ner's options, or the interpolating methods' (no NUFFT tolerance, no device option)
    o = options
    return reconstruct_grid(ds.data, ds.dx, ds.dt, sound_speed, method=name, dy=dy, t0=ds.t0, progress=step,
                            dtype=o.dtype or DEFAULT_DTYPE, upsample=getattr(o, "upsample", 1), positivity=getattr(o, "positivity", False),
                            n_z=getattr(o, "n_z", None), dz=getattr(o, "dz", None), eps=getattr(o, "eps", DEFAULT_EPS),
                            device=getattr(o, "device", "auto"))


def run(ds: GridDataset, sound_speed: float, options: Options, step: Callable[[float], None]) -> Reconstruction:
    """NER-NUFFT of grid data (:func:`run_grid`).

    Parameters
    ----------
    ds : GridDataset
        ``data`` ``(n_t, n_x)`` or ``(n_t, n_y, n_x)`` (time first), pitch in m, ``dt`` in s.
    sound_speed : float
        Speed of sound, m/s.
    options : Options
        The validated options.
    step : callable
        ``step(fraction)`` with increasing fractions in (0, 1]; it may raise to cancel.

    Returns
    -------
    Reconstruction
        p0 ``(n_z, n_x u)`` / ``(n_z, n_y u, n_x u)`` (u = ``upsample``), axes in m.

    Raises
    ------
    ValueError
        What ``fpscan.service.recon.planar.reconstruct_grid`` refuses.

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", §3.1 (NER).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.dataset import GridDataset
    >>> from fpscan.service.recon.methods.ner import Options, run
    >>> g = np.zeros((64, 8))  # (n_t, n_x): a uniform layer at depth row 10
    >>> g[10] = 0.5
    >>> ds = GridDataset(g, dx=1e-4, dt=1e-4 / 1500, sound_speed=1500.0)
    >>> fractions = []
    >>> r = run(ds, 1500.0, Options(), fractions.append)
    >>> r.p0.shape, r.p0.dtype, int(r.p0[:, 4].argmax()), round(float(r.p0[10, 4]), 3)
    ((64, 8), dtype('float32'), 10, 1.0)
    >>> fractions == sorted(fractions), fractions[-1]
    (True, 1.0)
    """
    return run_grid("ner", ds, sound_speed, options, step)


#: seconds of work per ``transform_units`` unit (float32, the reference 2 cores; ``planar_work``):
#: measured 0.9-2.9e-9 from 256 x 64^2 to 512 x 226^2 at load 5 (float64 1.1-1.7x); rounded up
WORK_RATE = 3e-9

def warm_up(dtypes: Sequence[str]) -> None:
    """Compile (or load from numba's cache) NER's kernels: one tiny grid and one line of
    sensors in each precision, laterally above ``fpscan.physics.fft_engine.SMALL_ELEMENTS``
    (a smaller transform runs in numpy and would compile nothing).

    Parameters
    ----------
    dtypes : sequence of str
        ``"float32"`` and/or ``"float64"``.

    Examples
    --------
    >>> from fpscan.service.recon.methods import get
    >>> from fpscan.service.recon.methods.ner import warm_up
    >>> get("ner").warm_up is warm_up
    True
    """
    import numpy as np

    from fpscan.constants import C_DEFAULT
    from fpscan.service.recon.planar import reconstruct_grid

    n, dx, dt = 64, 1e-4, 2e-8
    for d in dtypes:
        data = np.zeros((32, n, n), dtype=d)
        data[5, 3, 3] = 1.0
        reconstruct_grid(data, dx, dt, dtype=d, device="cpu")
        # the depth grid of c·dt too: its inverse transform's crop and scatter kernels, so that a
        # job at either grid compiles or loads no kernel of its own
        reconstruct_grid(data, dx, dt, dtype=d, device="cpu", dz=C_DEFAULT * dt)
        reconstruct_grid(np.tile(data[:, 0, :], (1, n)), dx, dt, dtype=d, device="cpu")  # a line of n * n sensors


METHOD = Method(name="ner", title="NER-NUFFT (full regular grid)", needs_grid=True, options_model=Options, run=run,
                source="paper §3.1: temporal NUFFT, lateral FFT",
                peak_memory=peak_model("planar_peak", temporal="nufft"), order=20, work=planar_work(WORK_RATE), default_for=("grid",), warm_up=warm_up,
                kernel_modules=("fpscan.physics.nufft_kernels", "fpscan.physics.array_kernels"))
