"""``nedner``: NEDNER-NUFFT for any sensor mask (paper §3.2): a temporal NUFFT and a type-1
NUFFT over the sensor positions (kernel: :func:`fpscan.service.recon.planar.reconstruct_points`)."""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from fpscan.service.recon.limits import DEFAULT_DEVICE, DEFAULT_DTYPE, DEFAULT_EPS
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
    from fpscan.service.recon.dataset import PointDataset
    from fpscan.service.recon.reconstruction import Reconstruction

__all__ = ["Options", "run", "WORK_RATE", "warm_up", "METHOD"]


class Options(DeviceOption, DepthOptions, PositivityOption, UpsampleOption, MethodOptions, NufftOptions):
    """Options of ``nedner`` (the fields of its mix-ins; SI units).

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
    >>> from fpscan.service.recon.methods.nedner import Options
    >>> Options(upsample=2, dz="5e-5").upsample, Options(upsample=2, dz="5e-5").dz  # dz in m
    (2, 5e-05)
    >>> try:
    ...     Options(lam=0.1)  # a tv option
    ... except ValidationError as exc:
    ...     print(exc.errors()[0]["type"])
    extra_forbidden
    """


def run(ds: PointDataset, sound_speed: float, options: Options, step: Callable[[float], None]) -> Reconstruction:
    """NEDNER-NUFFT of A-lines ``ds.alines`` ``(n, n_t)`` at ``ds.positions`` ``(n, 2)`` (m),
    the speed of sound in m/s; ValueError when there are no A-lines.

    Parameters
    ----------
    ds : PointDataset
        ``alines`` ``(n, n_t)`` at ``positions`` ``(n, 1)`` x / ``(n, 2)`` (x, y) in m, with
        quadrature ``weights`` ``(n,)`` (None: clipped Voronoi areas), the output ``grid``,
        ``dt`` in s and ``t0`` in s.
    sound_speed : float
        Speed of sound, m/s.
    options : Options
        The validated options.
    step : callable
        ``step(fraction)`` with increasing fractions in (0, 1]; it may raise to cancel.

    Returns
    -------
    Reconstruction
        p0 ``(n_z, n_x u)`` / ``(n_z, n_y u, n_x u)`` on the positions' lattice (u =
        ``upsample``), axes in m; ``params["method"]`` is ``"nedner"``.

    Raises
    ------
    ValueError
        No A-lines, or what ``fpscan.service.recon.planar.reconstruct_points`` refuses.

    References
    ----------
    .. [1] J. Schmid, T. Glatz, B. Zabihian, M. Liu, W. Drexler, O. Scherzer, "Computational
       Realization of a Non-Equidistant Grid Sampling in Photoacoustics with a Non-Uniform
       FFT", §3.2 (NEDNER).

    Examples
    --------
    A uniform layer at depth row 10, every point of an 8-sensor line a sensor:

    >>> import numpy as np
    >>> from fpscan.service.recon.dataset import GridDataset
    >>> from fpscan.service.recon.methods.nedner import Options, run
    >>> g = np.zeros((64, 8))  # (n_t, n_x)
    >>> g[10] = 0.5
    >>> ds = GridDataset(g, dx=1e-4, dt=1e-4 / 1500, sound_speed=1500.0).to_points()
    >>> ds.alines.shape, ds.positions.shape  # (n, n_t), (n, 1) x in m
    ((8, 64), (8, 1))
    >>> r = run(ds, 1500.0, Options(), lambda f: None)
    >>> r.p0.shape, r.p0.dtype, int(r.p0[:, 4].argmax()), r.params["method"]
    ((64, 8), dtype('float32'), 10, 'nedner')
    """
    from fpscan.service.recon.planar import reconstruct_points

    if ds.alines.shape[0] == 0:
        raise ValueError("the input has no A-lines to reconstruct")
    # NEDNER = NUFFT in time (the "ner" temporal step) + type-1 NUFFT over the positions
    o = options  # validated: a field is None only where its default is (the model fills the others)
    return reconstruct_points(ds.alines, ds.positions, ds.dt, sound_speed, weights=ds.weights, grid=ds.grid,
                              method="ner", t0=ds.t0, progress=step, eps=o.eps or DEFAULT_EPS,
                              dtype=o.dtype or DEFAULT_DTYPE, upsample=o.upsample or 1, positivity=bool(o.positivity),
                              n_z=o.n_z, dz=o.dz, device=o.device or DEFAULT_DEVICE)


#: seconds of work per ``transform_units`` unit (float32, the reference 2 cores; ``planar_work``):
#: measured 1.6-3.9e-9 from 256 x 128^2 to 512 x 226^2 (every lattice point a sensor) at load
#: 5, float64 1.1-1.6x; rounded up
WORK_RATE = 4e-9

def warm_up(dtypes: Sequence[str]) -> None:
    """Compile (or load from numba's cache) NEDNER's kernels: 30 scattered A-lines onto a
    64 x 64 grid in each precision.

    Parameters
    ----------
    dtypes : sequence of str
        ``"float32"`` and/or ``"float64"``.

    Examples
    --------
    >>> from fpscan.service.recon.methods import get
    >>> from fpscan.service.recon.methods.nedner import warm_up
    >>> get("nedner").warm_up is warm_up
    True
    """
    import numpy as np

    from fpscan.service.recon.planar import reconstruct_points

    n, dx, dt = 64, 1e-4, 2e-8
    rng = np.random.default_rng(0)
    for d in dtypes:
        pos = rng.uniform(0.0, (n - 1) * dx, (30, 2))
        grid = (np.arange(n) * dx, np.arange(n) * dx)
        reconstruct_points(rng.standard_normal((30, 32)).astype(d), pos, dt, weights=np.full(30, dx * dx),
                           grid=grid, dtype=d, device="cpu")


METHOD = Method(name="nedner", title="NEDNER-NUFFT (any sensor mask)", needs_grid=False, options_model=Options,
                run=run, source="paper §3.2: temporal NUFFT + type-1 NUFFT over the sensor positions",
                peak_memory=peak_model("planar_peak", temporal="nufft", points=True), order=10,
                work=planar_work(WORK_RATE), default_for=("points",), warm_up=warm_up,
                kernel_modules=("fpscan.physics.nufft_kernels", "fpscan.physics.array_kernels"))
