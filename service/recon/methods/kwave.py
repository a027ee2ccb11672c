"""``kwave``: k-Wave's ``kspaceLineRecon`` / ``kspacePlaneRecon`` (kernels:
:mod:`fpscan.service.recon.kwave`, transcriptions checked against k-Wave's data; notes in
reference/KWAVE_RECON_NOTES.md)."""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import BeforeValidator, Field

from fpscan.service.recon.limits import KWAVE_INTERPS
from fpscan.service.recon.methods.options import MethodOptions, PositivityOption
from fpscan.service.recon.methods.registry import Method
from fpscan.service.recon.methods.work import peak_model, planar_work

if TYPE_CHECKING:
    from fpscan.service.recon.dataset import GridDataset
    from fpscan.service.recon.reconstruction import Reconstruction

__all__ = ["Options", "run", "check_start", "WORK_RATE", "work", "warm_up", "METHOD"]


def _check_interp(value: Any) -> Any:
    if value is None or value in KWAVE_INTERPS:
        return value
    from fpscan.service.recon.checks import OptionError

    raise OptionError(f"interp must be one of {', '.join(KWAVE_INTERPS)}, got {value!r}")


Interp = Annotated[Literal["*nearest", "nearest", "*linear", "linear", "*cubic", "cubic"] | None,
                   BeforeValidator(_check_interp)]


class Options(PositivityOption, MethodOptions):
    """Options of ``kwave``: k-Wave's interpolation (``*``: k-Wave's own variant) and
    ``pos_cond`` (positivity).

    Attributes
    ----------
    dtype : {"float32", "float64"}
        Working and output precision (default ``"float32"``).
    positivity : bool
        k-Wave's ``pos_cond``: clip negative p0 to 0 (default False).
    interp : {"*nearest", "nearest", "*linear", "linear", "*cubic", "cubic"}
        k-Wave's interpolation (default ``"*nearest"``, k-Wave's own).

    Examples
    --------
    >>> from pydantic import ValidationError
    >>> from fpscan.service.recon.methods.kwave import Options
    >>> Options().interp, Options(interp="cubic").interp
    ('*nearest', 'cubic')
    >>> try:
    ...     Options(interp="spline")
    ... except ValidationError as exc:
    ...     print(exc.errors()[0]["msg"])
    Value error, interp must be one of *nearest, nearest, *linear, linear, *cubic, cubic, got 'spline'
    """

    interp: Interp = Field("*nearest", description="k-Wave interpolation (k-Wave's default *nearest)")


def run(ds: GridDataset, sound_speed: float, options: Options, step: Callable[[float], None]) -> Reconstruction:
    """k-Wave's reconstruction of grid data ``(n_t, n_x)`` (kspaceLineRecon, k-Wave's 'ty')
    or ``(n_t, n_y, n_x)`` (kspacePlaneRecon, 'tyz'), the speed of sound in m/s. ValueError when the
    input's first sample is not at t = 0 (k-Wave's convention).

    Parameters
    ----------
    ds : GridDataset
        ``data`` ``(n_t, n_x)`` or ``(n_t, n_y, n_x)`` (time first), pitch ``dx`` (and
        ``dy``) in m, ``dt`` in s, ``t0`` = 0 s.
    sound_speed : float
        Speed of sound, m/s.
    options : Options
        The validated options.
    step : callable
        ``step(fraction)`` with increasing fractions in (0, 1]; it may raise to cancel.

    Returns
    -------
    Reconstruction
        p0 ``(n_t, n_x)`` / ``(n_t, n_y, n_x)`` on depths ``z = k c dt`` (m), lateral axes
        centred (m); ``params["source"]`` names the k-Wave function.

    Raises
    ------
    ValueError
        ``ds.t0`` is not 0, or what the kernels (:mod:`fpscan.service.recon.kwave`) refuse.

    References
    ----------
    .. [1] B. E. Treeby, B. T. Cox, "k-Wave: MATLAB toolbox for the simulation and
       reconstruction of photoacoustic wave fields", J. Biomed. Opt. 15 (2010);
       ``kspaceLineRecon.m`` / ``kspacePlaneRecon.m``.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.dataset import GridDataset
    >>> from fpscan.service.recon.methods.kwave import Options, run
    >>> g = np.zeros((64, 8))  # (n_t, n_x): a uniform layer at depth row 10
    >>> g[10] = 0.5
    >>> opts = Options()
    >>> r = run(GridDataset(g, dx=1e-4, dt=1e-4 / 1500, sound_speed=1500.0), 1500.0, opts, lambda f: None)
    >>> r.p0.shape, r.p0.dtype, int(r.p0[:, 4].argmax()), r.params["source"]
    ((64, 8), dtype('float32'), 10, 'kspaceLineRecon')
    >>> run(GridDataset(g, 1e-4, 1e-4 / 1500, 1500.0, t0=1e-6), 1500.0, opts, lambda f: None)
    Traceback (most recent call last):
    ...
    ValueError: method 'kwave' needs sample 0 at t = 0 (k-Wave's convention); ... t0 = 1e-06 s: use 'ner'
    """
    import numpy as np

    from fpscan.physics.axes import centred_axis
    from fpscan.service.recon.kwave import kspace_line_recon, kspace_plane_recon
    from fpscan.service.recon.reconstruction import Reconstruction

    c = sound_speed
    interp = options.interp or "*nearest"
    check_start(ds.t0)
    dtype, positivity = np.dtype(options.dtype), bool(options.positivity)
    data = ds.data
    if data.ndim == 2:  # k-Wave 'ty': y is our x
        p0 = kspace_line_recon(data, ds.dx, ds.dt, c, interp=interp, pos_cond=positivity, progress=step,
                               dtype=dtype)
        y = None
    else:  # k-Wave 'tyz': (N_t, N_y, N_z) with k-Wave's y = our y and z = our x
        dy = ds.dy or ds.dx
        p0 = kspace_plane_recon(data, dy, ds.dx, ds.dt, c, interp=interp, pos_cond=positivity, progress=step,
                                dtype=dtype)
        y = centred_axis(data.shape[1], dy)
    n_t = data.shape[0]
    params = dict(method="kwave", interp=interp, dt=ds.dt, sound_speed=c, dx=ds.dx, dy=None if y is None else ds.dy or ds.dx,
                  dtype=dtype.name, dz=c * ds.dt, n_z=n_t, positivity=positivity, t0=0.0, n_t=n_t,
                  data_shape=list(data.shape),
                  source="kspaceLineRecon" if y is None else "kspacePlaneRecon")
    return Reconstruction(p0.astype(dtype, copy=False), np.arange(n_t) * (c * ds.dt),
                          centred_axis(data.shape[-1], ds.dx), y, params)


def check_start(t0: float | None) -> None:
    """k-Wave's convention: the record's first sample at t = 0. ValueError naming the input's
    ``t0`` (s) otherwise (None: unknown, passes).

    Parameters
    ----------
    t0 : float or None
        Time of the input's sample 0, s.

    Raises
    ------
    ValueError
        ``t0`` is not 0.

    Examples
    --------
    >>> from fpscan.service.recon.methods.kwave import check_start
    >>> check_start(0.0)
    >>> check_start(1e-6)
    Traceback (most recent call last):
    ...
    ValueError: method 'kwave' needs sample 0 at t = 0 (k-Wave's convention); this input has t0 = 1e-06 s: use 'ner'
    """
    if t0:
        raise ValueError("method 'kwave' needs sample 0 at t = 0 (k-Wave's convention); this input has "
                         f"t0 = {t0} s: use 'ner'")


#: seconds of work per ``transform_units`` unit (float32, the reference 2 cores; ``planar_work``):
#: measured 1.4-2.0e-9 from 256 x 128^2 to 512 x 226^2 at load 5 (float64 1.6-2.4x); rounded up
WORK_RATE = 3e-9


def work(n_t: int, n_x: int, n_y: int = 1, *, t0: float | None = None, **kw: Any) -> float:
    """Seconds of work (``planar_work`` at :data:`WORK_RATE`) of an input whose sample 0 is at
    ``t0`` (s): an input that does not start at t = 0 is refused at the door with the words
    :func:`run` would use (:func:`check_start`).

    Parameters
    ----------
    n_t, n_x, n_y : int
        The input's samples and lateral grid.
    t0 : float, optional
        Time of its sample 0, s (None: unknown).
    **kw
        As ``planar_work``'s.

    Returns
    -------
    float
        Seconds on the reference 2 cores.

    Raises
    ------
    ValueError
        ``t0`` is not 0.

    Examples
    --------
    >>> from fpscan.service.recon.methods.kwave import work
    >>> 0 < work(256, 128, 128, dtype="float32") < 1.0
    True
    """
    check_start(t0)
    return planar_work(WORK_RATE)(n_t, n_x, n_y, **kw)

def warm_up(dtypes: Sequence[str]) -> None:
    """Compile (or load from numba's cache) the k-Wave modes' kernels: a tiny plane and line
    with k-Wave's nearest and linear interpolation in each precision.

    Parameters
    ----------
    dtypes : sequence of str
        ``"float32"`` and/or ``"float64"``.

    Examples
    --------
    >>> from fpscan.service.recon.methods import get
    >>> from fpscan.service.recon.methods.kwave import warm_up
    >>> get("kwave").warm_up is warm_up
    True
    """
    import numpy as np

    from fpscan.constants import C_DEFAULT
    from fpscan.service.recon.kwave import kspace_line_recon, kspace_plane_recon

    dx, dt = 1e-4, 2e-8
    for d in dtypes:
        data = np.zeros((32, 6, 6), dtype=d)
        data[5, 3, 3] = 1.0
        for interp in ("*nearest", "*linear"):
            kspace_plane_recon(data, dx, dx, dt, C_DEFAULT, interp=interp, dtype=d)
            kspace_line_recon(data[:, 0, :], dx, dt, C_DEFAULT, interp=interp, dtype=d)


METHOD = Method(name="kwave", title="k-Wave compatible (kspaceLineRecon / kspacePlaneRecon; their own depth grid, "
                "n_t rows of c·dt)", needs_grid=True, options_model=Options, run=run,
                source="k-Wave kspaceLineRecon / kspacePlaneRecon (reference/KWAVE_RECON_NOTES.md)",
                peak_memory=peak_model("kwave_peak"), order=40, work=work, warm_up=warm_up,
                kernel_modules=("fpscan.service.recon.kwave",))
