"""``tv``: model-based reconstruction, ½‖A p0 − g‖² + λ TV(p0) with p0 ≥ 0, solved by
NER-preconditioned FISTA on the exact planar model (kernel:
:func:`fpscan.service.recon.tv.reconstruct_tv`; Arridge et al., PMB 61 (2016) 8908)."""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Annotated, Any

from pydantic import BeforeValidator, Field

from fpscan.service.progress import IterationStage, Shown
from fpscan.service.recon.limits import (
    DEFAULT_DEVICE,
    DEFAULT_DTYPE,
    DEFAULT_EPS,
    DEFAULT_MAX_ITER,
    DEFAULT_TIME_LIMIT,
    DEFAULT_TOL,
    ITERATIONS_RANGE,
    LAM_RANGE,
    TIME_LIMIT_MAX,
    TOL_RANGE,
)
from fpscan.service.recon.methods.options import (
    NZ,
    DepthOptions,
    DeviceOption,
    Dz,
    Flag,
    MethodOptions,
    NufftOptions,
    kernel_rule,
)
from fpscan.service.recon.methods.registry import Method

if TYPE_CHECKING:
    from fpscan.service.progress import Progress
    from fpscan.service.recon.dataset import PointDataset
    from fpscan.service.recon.reconstruction import Reconstruction
    from fpscan.service.recon.tv.formulation import TvProblem
    from fpscan.service.recon.tv.grid import TvGrid

__all__ = ["Options", "run", "problem", "problem_arguments", "SOLVER_OPTIONS", "declared_bandwidth", "BANDWIDTH_KEY", "PAIR_RATE", "SETUP_PAIRS", "grid",
           "check_depth", "work", "peak_memory", "MEMORY_CALIBRATION", "warm_up", "SUMMARY", "STOP_WAITS_FOR", "METHOD"]

Lam = Annotated[Annotated[float, Field(ge=LAM_RANGE[0], le=LAM_RANGE[1])] | None,
                BeforeValidator(kernel_rule("check_lam"))]
Iterations = Annotated[Annotated[int, Field(ge=ITERATIONS_RANGE[0], le=ITERATIONS_RANGE[1])] | None,
                       BeforeValidator(kernel_rule("check_max_iter"))]
Tol = Annotated[Annotated[float, Field(ge=TOL_RANGE[0], le=TOL_RANGE[1])] | None,
                BeforeValidator(kernel_rule("check_tol"))]
TimeLimit = Annotated[Annotated[float, Field(gt=0, le=TIME_LIMIT_MAX)] | None,
                      BeforeValidator(kernel_rule("check_time_limit"))]


class Options(DeviceOption, DepthOptions, MethodOptions, NufftOptions):
    """Options of ``tv`` (SI units; λ in the data's units).

    Attributes
    ----------
    eps : float
        NUFFT tolerance in [1e-14, 1e-1] (default 1e-6).
    dtype : {"float32", "float64"}
        Working and output precision (default ``"float32"``).
    n_z : int or None
        Output depth samples, 2..65536 (None: down to the depth of the record's last echo above
        the noise; ``fpscan.service.recon.tv.grid``).
    dz : float or None
        Output depth spacing in m, [1e-9, 0.1] (None: the lateral pitch (an isotropic grid at
        the band c / (2 pitch) the pitch resolves, or c / (2 f) at a declared sensor band f), c dt
        where that band reaches the record's Nyquist frequency). One given alone keeps the
        other's default (every method's rule, ``fpscan.service.recon.depth``, with tv's band and
        depth).
    positivity : bool
        Constrain p0 >= 0 (default True).
    lam : float or None
        TV weight λ >= 0 in the data's units (Pa for data in Pa); None (default): from the
        estimated noise level (``fpscan.service.recon.tv``).
    max_iter : int
        The iteration cap of the solver (default ``DEFAULT_MAX_ITER``; ``iterations``, an earlier
        release's name, is accepted with a ``DeprecationWarning``).
    time_limit : float
        Wall-time limit of the solver in s, in (0, 1 week] (default ``DEFAULT_TIME_LIMIT``).
    debias : bool
        Refit the amplitudes by least squares on the support after the solve (default False).
    whole_record : bool
        Keep the whole record, and by default image its whole depth (default False: the image
        ends at the last echo and the record is kept until the farthest sensor hears its last
        row; ``fpscan.service.recon.tv.grid``).

    Examples
    --------
    >>> from pydantic import ValidationError
    >>> from fpscan.service.recon.methods.tv import Options
    >>> o = Options(lam=0.01, time_limit="60")
    >>> o.lam, o.time_limit, o.positivity, "upsample" in Options.model_fields  # time_limit in s
    (0.01, 60.0, True, False)
    >>> try:
    ...     Options(lam=-1)
    ... except ValidationError as exc:
    ...     print(exc.errors()[0]["msg"])
    Value error, lam (the TV weight λ) must be in [0, 1e+30], got -1
    """

    positivity: Flag("positivity") = Field(True, description="constrain p0 >= 0")  # type: ignore[valid-type]
    # the depth grid's rule with tv's own depth and band (fpscan.service.recon.tv.grid)
    n_z: NZ = Field(None, description=DepthOptions.model_fields["n_z"].description,
                    json_schema_extra={"unit": "1", "derived": "down to the record's last echo above the noise"})
    dz: Dz = Field(None, description=DepthOptions.model_fields["dz"].description,
                   json_schema_extra={"unit": "m", "display_unit": "µm", "quantity": "length",
                                      "derived": "the lateral pitch, c·dt where that is finer, c/(2 f) at a "
                                                 "declared sensor band f"})
    lam: Lam = Field(None, description="TV weight λ in the data's units",
                     json_schema_extra={"unit": "data units",
                                        "derived": "from the noise level and the warm start's misfit, "
                                                   "at least a floor set by the warm start's peak"})
    max_iter: Iterations = Field(DEFAULT_MAX_ITER, description="the iteration cap of the solver",
                                 json_schema_extra={"unit": "1"})
    tol: Tol = Field(DEFAULT_TOL, description="stopping threshold: stop when the image's relative change "
                     "per iteration, ‖x_k − x_k−1‖ / ‖x_k‖, stays below tol for 3 iterations at λ "
                     "(0: run every iteration); smaller runs longer and stops nearer the minimiser (half the "
                     "default: 1.1-1.5x the iterations on sparse noisy scans), but never before λ's continuation "
                     "ends + 3 iterations, where a noiseless scan stops whatever tol (docs/tv-measurements.md)",
                     json_schema_extra={"unit": "1"})
    time_limit: TimeLimit = Field(DEFAULT_TIME_LIMIT, description="wall-time limit of the solver (the server's "
                                  "setting time_limit_s caps it): when reached the result says converged false, "
                                  "stop reason 'time limit'", json_schema_extra={"unit": "s", "quantity": "time"})
    debias: Flag("debias") = Field(False, description="refit the amplitudes by least squares on the "  # type: ignore[valid-type]
                                   "support after the solve")
    whole_record: Flag("whole_record") = Field(  # type: ignore[valid-type]
        False, description="keep the whole record and image its whole depth: by default the image ends at the "
        "last echo above the noise and the record is kept until the farthest sensor hears that depth (3-D; a "
        "line keeps its whole record), after which the model predicts silence")


def run(ds: PointDataset, sound_speed: float, options: Options, step: Progress) -> Reconstruction:
    """Model-based reconstruction of A-lines ``ds.alines`` ``(n, n_t)`` at ``ds.positions``
    (m), ``sound_speed`` in m/s; the progress stage names the iteration (``"iteration k/N"``).
    ValueError when there are no A-lines.

    Parameters
    ----------
    ds : PointDataset
        ``alines`` ``(n, n_t)`` at ``positions`` ``(n, 1)`` x / ``(n, 2)`` (x, y) in m,
        ``weights`` (the NEDNER warm start's), ``grid``, ``dt`` and ``t0`` in s.
    sound_speed : float
        Speed of sound, m/s.
    options : Options
        The validated options.
    step : callable
        ``step(fraction, stage)`` with increasing fractions in (0, 1] (a long step may
        repeat its fraction so that a cancel is heard); it may raise to cancel.

    Returns
    -------
    Reconstruction
        p0 ``(n_z, n_x)`` / ``(n_z, n_y, n_x)`` on the warm start's grid, axes in m;
        ``params`` as ``fpscan.service.recon.tv.reconstruct_tv``'s (``lam``, ``iterations``,
        ``stop_reason``, ...).

    Raises
    ------
    ValueError
        No A-lines, or what ``reconstruct_tv`` refuses.

    References
    ----------
    .. [1] S. Arridge, P. Beard, M. Betcke, B. Cox, N. Huynh, F. Lucka, O. Ogunlade, E. Zhang,
       "Accelerated high-resolution photoacoustic tomography via compressed sensing", Phys.
       Med. Biol. 61 (2016) 8908.
    .. [2] A. Beck, M. Teboulle, "A fast iterative shrinkage-thresholding algorithm for linear
       inverse problems", SIAM J. Imaging Sci. 2 (2009) 183.

    Examples
    --------
    A 3 x 3 block (the exact forward model, `fpscan.physics.forward`) seen by 16 sensors:

    >>> import numpy as np
    >>> from fpscan.physics.forward import forward_grid
    >>> from fpscan.service.recon.dataset import GridDataset
    >>> from fpscan.service.recon.methods.tv import Options, run
    >>> p0 = np.zeros((12, 16))  # (n_z, n_x), pitch 0.1 mm
    >>> p0[5:8, 7:10] = 1.0
    >>> g = forward_grid(p0, dx=1e-4, dz=1e-4, dt=1e-4 / 1500, n_t=24, c=1500.0)
    >>> ds = GridDataset(g, dx=1e-4, dt=1e-4 / 1500, sound_speed=1500.0).to_points()
    >>> stages = []
    >>> r = run(ds, 1500.0, Options(max_iter=5, n_z=12), lambda fraction, stage: stages.append(stage))
    >>> r.p0.shape, r.p0.dtype, bool(r.p0.min() >= 0), r.params["iterations"]
    ((12, 16), dtype('float32'), True, 5)
    >>> stages[0], stages[-1]
    ('warm start', 'iteration 5/5')
    """
    from fpscan.service.recon.tv.reconstruct import reconstruct_tv

    o = options  # validated: a field is None only where its default is (the model fills the others)
    return reconstruct_tv(**problem_arguments(ds, sound_speed, o), max_iter=o.max_iter or DEFAULT_MAX_ITER,
                          tol=DEFAULT_TOL if o.tol is None else o.tol, time_limit=o.time_limit or DEFAULT_TIME_LIMIT,
                          debias=bool(o.debias), device=o.device or DEFAULT_DEVICE, progress=_saying_why(step))


#: tv's options that set its solver or where it runs, not its problem (`problem` takes none of them)
SOLVER_OPTIONS = ("max_iter", "tol", "time_limit", "debias", "device")


def problem(ds: PointDataset, sound_speed: float, options: Options) -> TvProblem:
    """The problem tv solves for ``ds`` (``fpscan.service.recon.tv.reconstruct.tv_problem``): the operator,
    the data, the warm start, the grid and λ that `run` with the same options solves, built on
    the CPU by its own set-up.

    Parameters
    ----------
    ds : PointDataset
        As `run`'s.
    sound_speed : float
        Speed of sound, m/s.
    options : Options
        The validated options (`SOLVER_OPTIONS` play no part).

    Returns
    -------
    TvProblem
        ``fpscan.service.recon.tv.formulation.TvProblem``.

    Raises
    ------
    ValueError
        No A-lines, or what ``tv_problem`` refuses.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.forward import forward_grid
    >>> from fpscan.service.recon.dataset import GridDataset
    >>> from fpscan.service.recon.methods.tv import Options, problem
    >>> p0 = np.zeros((12, 16)); p0[5:8, 7:10] = 1.0
    >>> g = forward_grid(p0, dx=1e-4, dz=1e-4, dt=1e-4 / 1500, n_t=24, c=1500.0)
    >>> pb = problem(GridDataset(g, dx=1e-4, dt=1e-4 / 1500, sound_speed=1500.0).to_points(), 1500.0,
    ...              Options(n_z=12))
    >>> pb.operator.dims, pb.data.shape, pb.operator.dtype  # A-lines (n_points, n_t); tv's float32
    ((12, 16), (16, 24), dtype('float32'))
    """
    from fpscan.service.recon.tv.reconstruct import tv_problem

    return tv_problem(**problem_arguments(ds, sound_speed, options))


def problem_arguments(ds: PointDataset, sound_speed: float, o: Options) -> dict[str, Any]:
    """`reconstruct_tv`'s and ``tv_problem``'s arguments that set the problem: the data and the
    options (one owner for `run` and `problem`).

    Parameters
    ----------
    ds : PointDataset
        As `run`'s.
    sound_speed : float
        Speed of sound, m/s.
    o : Options
        The validated options.

    Returns
    -------
    dict
        ``data``, ``dt`` (s), ``c`` (m/s), ``positions``, ``weights``, ``grid``, ``t0`` (s),
        ``positivity``, ``lam``, ``whole_record``, ``eps``, ``dtype``, ``n_z``, ``dz`` (m),
        ``bandwidth`` (Hz or None).

    Raises
    ------
    ValueError
        No A-lines.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.dataset import GridDataset
    >>> from fpscan.service.recon.methods.tv import Options, problem_arguments
    >>> ds = GridDataset(np.zeros((8, 2)), dx=1e-4, dt=1e-8, sound_speed=1500.0).to_points()
    >>> a = problem_arguments(ds, 1480.0, Options())
    >>> a["c"], a["dtype"], a["positivity"], a["lam"]
    (1480.0, 'float32', True, None)
    """
    if ds.alines.shape[0] == 0:
        raise ValueError("the input has no A-lines to reconstruct")
    return dict(data=ds.alines, dt=ds.dt, c=sound_speed, positions=ds.positions, weights=ds.weights, grid=ds.grid,
                t0=ds.t0, positivity=bool(o.positivity), lam=o.lam, whole_record=bool(o.whole_record),
                eps=o.eps or DEFAULT_EPS, dtype=o.dtype or DEFAULT_DTYPE, n_z=o.n_z, dz=o.dz,
                bandwidth=declared_bandwidth(ds.meta))


#: the dataset's ``meta`` key of a sensor bandwidth the scan declares, Hz
BANDWIDTH_KEY = "sensor_bandwidth_hz"


def declared_bandwidth(meta: dict | None) -> float | None:
    """The sensor bandwidth a dataset's metadata declares (``meta["sensor_bandwidth_hz"]``,
    Hz), which tv then works at instead of the band it reads off the data
    (``fpscan.service.recon.tv.grid``); None when it declares none.

    Parameters
    ----------
    meta : dict or None
        The dataset's metadata.

    Returns
    -------
    float or None
        Hz.

    Raises
    ------
    ValueError
        A declared value that is not a number in [1e3, 1e12] Hz
        (``fpscan.service.recon.checks.check_bandwidth``).

    Examples
    --------
    >>> from fpscan.service.recon.methods.tv import declared_bandwidth
    >>> declared_bandwidth({"sensor_bandwidth_hz": 2.2e7}), declared_bandwidth({})
    (22000000.0, None)
    """
    value = (meta or {}).get(BANDWIDTH_KEY)
    if value is None:
        return None
    from fpscan.service.recon.checks import check_bandwidth

    return check_bandwidth(value)


#: seconds of work per operator pair and unit (the padded grid's ``M log2 M``, ``M`` its
#: points), float32 on the reference 2 cores: a pair measured 0.57 s at 256 x 64^2 (15 % mask,
#: padded to 257 x 200^2: 2.4e-9) and 5.2 s at 512 x 64^2 (513 x 324^2: 3.7e-9) at load 5, and
#: 6.5 s at the paper's 1024 x 226^2 (1025 x 450^2: 1.1e-9, idle; docs/performance.md); the
#: TV step of each iteration is counted in it (benchmarks/bench_work_estimate.py)
PAIR_RATE = 3.5e-9
#: operator pairs besides one per iteration: the power iterations (2), the noise image's
#: adjoint, the first residual (measured: 6 pairs for 3 iterations) and the set-up's other
#: steps, the equivalent of 2 more
SETUP_PAIRS = 5.0
#: the debias refit's iterations (``fpscan.service.recon.tv``)
DEBIAS_ITERATIONS = 10


def grid(n_t: int, dt: float, c: float, *, dz: float | None = None, n_z: int | None = None,
         t0: float = 0.0, bandwidth: float | None = None, record_facts: dict | None = None,
         whole_record: bool = False, dx: float | None = None, n_x: int = 1, n_y: int = 1) -> tuple[float, int]:
    """The image grid of tv for a record: ``(dz, n_z)`` (m, rows) as tv chooses it
    (``fpscan.service.recon.tv.grid.tv_grid``: from a stored dataset's ``record_facts``, else the
    whole, full-band record's or a declared ``bandwidth``'s in Hz, the largest it can pick), the
    grid the work estimate and the depth rule read.

    Parameters
    ----------
    n_t : int
        Samples per A-line.
    dt, c : float
        Sample interval (s), speed of sound (m/s).
    dz, n_z : optional
        As asked (None: the default).
    t0 : float, optional
        Time of sample 0, s.
    bandwidth : float, optional
        A declared sensor bandwidth, Hz.
    record_facts : dict, optional
        What the record holds above its noise, as a stored dataset's record keeps it
        (``fpscan.service.recon.tv.grid.RecordFacts.as_dict``); one that does not fit the record is
        ignored (the whole record is sized).
    whole_record : bool, optional
        tv's option: the whole record and its depth.
    dx : float, optional
        The lateral pitch of the ``n_x`` × ``n_y`` lattice, m: the band it resolves (without it,
        the record's own band: the finest grid tv may choose).
    n_x, n_y : int, optional
        The lattice (the sensors' reach: its diagonal).

    Returns
    -------
    tuple
        ``(dz, n_z)``.

    Raises
    ------
    ValueError
        What the depth axis refuses (``dz``, ``n_z`` out of range; a ``dz`` too fine to reach
        the last sample).

    Examples
    --------
    >>> from fpscan.service.recon.methods.tv import grid
    >>> grid(256, 4e-8, 1500.0)  # c dt, n_t
    (6e-05, 256)
    >>> dz, n_z = grid(1024, 8e-9, 1500.0, bandwidth=20e6)  # a 20 MHz sensor: a coarser grid
    >>> round(dz * 1e6, 2), n_z
    (37.5, 328)
    >>> dz, n_z = grid(1024, 8e-9, 1500.0, dx=60e-6, n_x=226, n_y=226)  # the band 60 µm resolves: isotropic
    >>> round(dz * 1e6, 2), n_z
    (60.0, 205)
    """
    from fpscan.service.recon.planar import depth_axis  # the depth axis's own checks (range, reach)

    chosen = _chosen_grid(n_t, dt, c, dz=dz, n_z=n_z, t0=t0, bandwidth=bandwidth, record_facts=record_facts,
                          whole_record=whole_record, dx=dx, n_x=n_x, n_y=n_y)
    depth_axis(int(n_t), float(dt), float(c), chosen.dz, chosen.n_z, float(t0 or 0.0))
    return float(chosen.dz), int(chosen.n_z)


def _chosen_grid(n_t: int, dt: float, c: float, *, dz: float | None, n_z: int | None, t0: float | None,
                 bandwidth: float | None, record_facts: dict | None, whole_record: bool,
                 dx: float | None = None, n_x: int = 1, n_y: int = 1) -> TvGrid:
    """The grid tv picks (`fpscan.service.recon.tv.grid.tv_grid`) for a record known by its stored facts
    (`grid`'s parameters; ``dx`` the lateral pitch in m of the ``n_x`` × ``n_y`` lattice: the
    band it resolves, and its diagonal as the sensors' reach, the most any mask on it needs; a
    line keeps its whole record, as `fpscan.service.recon.tv` keeps it)."""
    from fpscan.service.recon.tv.grid import RecordFacts, tv_grid

    facts = None
    if record_facts is not None:
        try:
            facts = RecordFacts.from_dict(record_facts)
        except ValueError:
            facts = None
        if facts is not None and facts.n_t != int(n_t):  # not this record's: size the whole record
            facts = None
    pitch = float(dx) if dx and math.isfinite(float(dx)) and float(dx) > 0 else None
    reach = None if pitch is None or int(n_y) <= 1 else math.hypot((int(n_x) - 1) * pitch, (int(n_y) - 1) * pitch)
    return tv_grid(int(n_t), float(dt), float(c), bandwidth=bandwidth, dz=dz, n_z=n_z, t0=float(t0 or 0.0),
                   whole_record=bool(whole_record), facts=facts, pitch=pitch, reach=reach)


def check_depth(n_t: int, dt: float, c: float, dz: float, n_z: int, t0: float = 0.0) -> None:
    """Refuse an image deeper than the record can hear: its last row ``(n_z - 1) dz`` beyond
    ``c (t0 + (n_t - 1) dt)``, the depth of the last sample. The model-based operator pads
    its grid by the image's depth and its lateral reach by ``max(dx, dz)``, so such rows only
    cost (an image of 256 rows of 0.1 m took 5.3 GB and 23 minutes for 27 iterations).

    Parameters
    ----------
    n_t : int
        Samples per A-line.
    dt, c : float
        Sample interval (s), speed of sound (m/s).
    dz, n_z : float, int
        The image's depth spacing (m) and rows.
    t0 : float, optional
        Time of sample 0, s.

    Raises
    ------
    fpscan.service.recon.checks.OptionError
        The image is deeper than the record; the message names both and the most rows.

    Examples
    --------
    >>> from fpscan.service.recon.methods.tv import check_depth
    >>> check_depth(256, 4e-8, 1500.0, 6e-5, 256)  # the default grid reaches the last sample
    >>> check_depth(256, 4e-8, 1500.0, 0.1, 256)
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: tv's image would reach 25.5 m deep (n_z = 256 rows of dz = 0.1 m), deeper ...
    """
    reach = float(c) * (float(t0 or 0.0) + (int(n_t) - 1) * float(dt))
    depth = (int(n_z) - 1) * float(dz)
    if depth > reach * (1 + 1e-9) + 1e-15:
        from fpscan.service.recon.checks import OptionError

        most = int(reach / float(dz) * (1 + 1e-9)) + 1
        fix = f"at this dz use n_z <= {most}, or a smaller dz" if most >= 2 else "use a smaller dz"
        raise OptionError(f"tv's image would reach {depth:.3g} m deep (n_z = {n_z} rows of dz = {dz:.3g} m), deeper "
                          f"than the record can hear: c (t0 + (n_t - 1) dt) = {reach:.3g} m; {fix} "
                          f"(c dt = {float(c) * float(dt):.3g} m)")


def work(n_t: int, n_x: int, n_y: int = 1, *, dtype: Any = "float32", n_points: int | None = None,
         dx: float | None = None, dt: float | None = None, c: float | None = None, t0: float | None = 0.0,
         options: dict | None = None, record_facts: dict | None = None, bandwidth: float | None = None,
         **_: Any) -> float:
    """The work of tv: seconds on the reference 2 cores for its operator pairs on its padded grid
    (:data:`PAIR_RATE`: one per iteration up to ``max_iter``, the debias refit's, and
    :data:`SETUP_PAIRS`), the iterations' share capped by ``time_limit`` (s; the solver stops
    there), plus the NEDNER warm start. The grid is :func:`grid`'s, padded as the operator
    pads it (``fpscan.physics.grid_sizes.pad_sizes``); an image deeper than the record is
    refused (:func:`check_depth`).

    Parameters
    ----------
    n_t, n_x, n_y : int
        The input's samples and lateral grid.
    dtype : str, optional
        ``"float32"`` or ``"float64"``.
    n_points : int, optional
        Sensors.
    dx, dt, c, t0 : float, optional
        Pitch (m), sample interval (s), speed of sound (m/s), time of sample 0 (s); without
        ``dx``/``dt`` the warm start's estimate alone is counted.
    options : dict, optional
        tv's options as asked (``dz``, ``n_z``, ``max_iter``, ``time_limit``, ``debias``,
        ``whole_record``).
    record_facts, bandwidth : optional
        The stored dataset's facts and declared sensor bandwidth (Hz), as :func:`grid`'s.

    Returns
    -------
    float
        Seconds.

    Raises
    ------
    fpscan.service.recon.checks.OptionError
        An image deeper than the record; ``ValueError`` for a grid the depth axis refuses.

    Examples
    --------
    >>> from fpscan.service.recon.methods.tv import work
    >>> s = work(256, 64, 64, n_points=600, dx=1e-4, dt=3.3e-8, c=1500.0, options={"max_iter": 100})
    >>> 30 < s < 600  # measured: 0.57 s a pair there
    True
    """
    from fpscan.service.recon.limits import DEFAULT_MAX_ITER, DEFAULT_TIME_LIMIT
    from fpscan.service.recon.methods.nedner import WORK_RATE as WARM_RATE
    from fpscan.service.recon.methods.work import FLOAT64_WORK, planar_work

    o = dict(options or {})
    warm = planar_work(WARM_RATE)(n_t, n_x, n_y, n_points=n_points, dtype="float64")
    if not (dx and dt and c):
        return warm
    chosen = _chosen_grid(n_t, dt, c, dz=o.get("dz"), n_z=o.get("n_z"), t0=t0, bandwidth=bandwidth,
                          record_facts=record_facts, whole_record=bool(o.get("whole_record")), dx=dx, n_x=n_x,
                          n_y=n_y)
    from fpscan.service.recon.planar import depth_axis

    depth_axis(int(n_t), float(dt), float(c), chosen.dz, chosen.n_z, float(t0 or 0.0))  # the depth axis's checks
    check_depth(n_t, dt, c, chosen.dz, chosen.n_z, t0 or 0.0)
    from fpscan.physics.grid_sizes import pad_sizes

    points = math.prod(pad_sizes((chosen.n_z, n_y, n_x), dx, chosen.dz, chosen.dt, chosen.n_t, c, t0 or 0.0))
    pair = PAIR_RATE * points * math.log2(max(points, 2)) * (FLOAT64_WORK if str(dtype) == "float64" else 1.0)
    iterations = int(o.get("max_iter") or DEFAULT_MAX_ITER) + (DEBIAS_ITERATIONS if o.get("debias") else 0)
    limit = float(o.get("time_limit") or DEFAULT_TIME_LIMIT)
    return warm + SETUP_PAIRS * pair + min(iterations * pair, limit)


def peak_memory(n_t: int, n_x: int, n_y: int = 1, *, n_z: int | None = None, dtype: Any = "float32",
                n_points: int | None = None, dx: float | None = None, dt: float | None = None,
                c: float | None = None, dz: float | None = None, t0: float | None = 0.0,
                options: dict | None = None, record_facts: dict | None = None, bandwidth: float | None = None,
                **_: Any) -> int:
    """The peak memory of tv in bytes on the grid it will choose
    (``fpscan.service.recon.memory.model_based_peak`` of the operator's samples and tv's image; the
    memory admission, ``fpscan.service.jobs.admission.estimate_memory``): with a stored dataset's
    ``record_facts`` the image down to the last echo and the record kept for it, resampled to the band, as tv cuts
    and resamples it (``fpscan.service.recon.tv.grid``), else the whole, full-band record (the
    largest grid tv may choose).

    Parameters
    ----------
    n_t, n_x, n_y : int
        The input's samples and lateral grid.
    n_z : int, optional
        The working depth rows the admission counts (used without ``dx``, ``dt``, ``c``).
    dtype : str, optional
        ``"float32"`` or ``"float64"``.
    n_points : int, optional
        Sensors.
    dx, dt, c, dz, t0 : float, optional
        Pitch (m), sample interval (s), speed of sound (m/s), depth spacing asked (m), time of
        sample 0 (s).
    options : dict, optional
        tv's options as asked (``n_z``, ``dz``, ``whole_record``).
    record_facts, bandwidth : optional
        As :func:`grid`'s.

    Returns
    -------
    int
        Bytes.

    Examples
    --------
    A record whose echoes end at a third of it (stored facts) needs less than the whole:

    >>> from fpscan.service.recon.methods.tv import peak_memory
    >>> kw = dict(dx=6e-5, dt=8e-9, c=1500.0, n_points=400)
    >>> facts = {"n_t": 768, "signal_n_t": 256, "sigma": 0.01}
    >>> peak_memory(768, 96, 96, record_facts=facts, **kw) < peak_memory(768, 96, 96, **kw)
    True
    >>> peak_memory(768, 96, 96, record_facts=facts, options={"whole_record": True}, **kw) == peak_memory(
    ...     768, 96, 96, **kw)
    True
    """
    from fpscan.service.recon.memory import model_based_peak

    o = dict(options or {})
    if not (dx and dt and c):
        return model_based_peak(n_t, n_x, n_y, n_z=n_z, dtype=dtype, n_points=n_points)
    chosen = _chosen_grid(n_t, dt, c, dz=o.get("dz") or dz, n_z=o.get("n_z"), t0=t0, bandwidth=bandwidth,
                          record_facts=record_facts, whole_record=bool(o.get("whole_record")), dx=dx, n_x=n_x,
                          n_y=n_y)
    # the rows the NEDNER warm start works on: no sample of the kept record may fold back through
    # the depth period (``fpscan.service.jobs.admission.working_depth_rows``'s rule on the kept record)
    reach = c * (float(t0 or 0.0) + (chosen.n_t - 1) * chosen.dt) / chosen.dz
    rows = max(chosen.n_z, int(reach) + 2) if math.isfinite(reach) else chosen.n_z
    return model_based_peak(chosen.n_t, n_x, n_y, n_z=chosen.n_z, dtype=dtype, n_points=n_points, dx=dx,
                            dt=chosen.dt, c=c, dz=chosen.dz, warm_rows=rows, band=chosen.band)


#: the memory admission's margin on tv's model (``fpscan.service.recon.memory.model_based_peak``, itself
#: calibrated): with it the estimate is 1.06-1.14 of the peak measured on five full-size scans (the
#: paper's, cut and whole record, and the three full-size members of tv's phantom family) and
#: 1.09-1.38 on the smaller cases of tests/service/test_memory_admission.py (measured after a warm-up
#: on a smaller input; docs/performance.md; 1.15 before the solver's TV part worked in place, 1.45
#: when the factor also had to cover the planar methods). The planar methods' models count their
#: arrays phase by phase and need no factor (measured within 4-10 % at upsample 1-8; docs/api.md).
MEMORY_CALIBRATION = 1.05


def warm_up(dtypes: Sequence[str]) -> None:
    """Compile (or load from numba's cache) the model-based operator's and solver's kernels
    (``fpscan.service.recon.operator``, on a grid and at points, its A-lines as given and in the
    working precision; ``fpscan.physics.array_kernels``; ``fpscan.service.recon.tv``'s ``prox``,
    ``stores``, ``fista`` and ``preconditioner``; ``fpscan.physics.forward``; the first imports
    pylops and pyproximal: seconds) on a 4 x 6 x 6 image in each precision.

    Parameters
    ----------
    dtypes : sequence of str
        ``"float32"`` and/or ``"float64"``.

    Examples
    --------
    >>> from fpscan.service.recon.methods import get
    >>> from fpscan.service.recon.methods.tv import warm_up
    >>> get("tv").warm_up is warm_up
    True
    """
    import numpy as np

    from fpscan.constants import C_DEFAULT
    from fpscan.physics.axes import centred_axis
    from fpscan.physics.forward import forward_grid
    from fpscan.service.recon.operator import PlanarOperator
    from fpscan.service.recon.tv import fista, preconditioner, prox, stores

    dx, dt = 1e-4, 2e-8
    axis = centred_axis(6, dx)
    nodes = np.array([[axis[0], axis[0]], [axis[2], axis[1]], [axis[5], axis[3]]])
    for d in dtypes:  # the model-based operator runs its transforms in the working precision
        op = PlanarOperator((4, 6, 6), dx, C_DEFAULT * dt, dt, 32, dtype=d, device="cpu")
        op.adjoint(op.forward(np.ones((4, 6, 6))))
        at_points = PlanarOperator((4, 6, 6), dx, C_DEFAULT * dt, dt, 32, positions=nodes, dtype=d, device="cpu")
        for data in (np.ones((3, 32)), np.ones((3, 32), dtype=d)):  # A-lines as given and in the working precision
            at_points.adjoint(data)
        v = np.ones((4, 6, 6), dtype=d)  # the TV part's compiled sweeps (2-D images run as 3-D views)
        prox.tv_prox(v, 0.1, True, None, None)
        prox.tv_prox_stored(v, 0.1, True, None, [prox.tv_prox_stored(v, 0.1, True, None, [None])[1]])  # stored dual
        prox.tv_norm(v)
        preconditioner.apply_weight(preconditioner.ner_weight(v.shape, dx, C_DEFAULT * dt), v)  # P's kernel
        preconditioner.apply_weight(preconditioner.ner_weight((6, 8, 8), dx, C_DEFAULT * dt), v)  # on a padded grid
        flat = v.ravel()  # the solver's in-place vector kernels
        fista.axpy(flat, flat, 0.5)
        move = stores.store_move(flat, flat, flat, 1.0, np.zeros(flat.size, dtype=np.int16), 0.0, 1.0)
        stores.extrapolate_fixed(flat, move[0], 0.5)
        fista.difference_norm(flat, flat)
        fista.difference_norm(flat, flat.astype(np.float64))  # A x against the data (float64)
        stores.gain_lower_bound(flat, stores.store_gradient(v))  # the last gradient's 16-bit wait
        fista.moves(flat, flat, flat, 1.0, move[0], 0.5, 0.5)
        dual = np.zeros((3, 4, 6, 6), dtype=d)  # the dual's wait between iterations
        stores.restore_dual(stores.store_dual(dual), dual.dtype)
    forward_grid(np.ones((4, 6, 6)), dx, C_DEFAULT * dt, dt, 32)


#: what tv's result summary shows after its outcome (``Method.summary``): λ, given or automatic
#: (with the reason when the automatic λ is 0), and the residual against the data's noise
SUMMARY = (
    Shown("lam", "λ", title="λ (TV weight)", id="lambda", flag="lam_auto", words=("given", "automatic"),
          note="lam_note"),
    Shown("residual", "residual", title="Residual", format="percent", suffix=" of the data",
          also=(("noise_share", "noise"),)),
)

#: what tv's stopping rule waits for while λ still falls (``Method.stop_waits_for``): the
#: progress line then reads "(stops below 0.005 once λ has settled)"
STOP_WAITS_FOR = "λ has settled"


def _saying_why(step: Progress) -> Progress:
    """``step`` with :data:`STOP_WAITS_FOR` on each iteration stage whose rule is not armed yet."""
    def report(fraction: float, stage: str) -> None:
        if isinstance(stage, IterationStage) and not stage.armed:
            stage = stage.waiting_for(STOP_WAITS_FOR)
        step(fraction, stage)

    return report


METHOD = Method(
    name="tv", title="model-based: TV + positivity on the exact model (iterative; sparse, noisy scans)",
    needs_grid=False, options_model=Options, run=run,
    source="½‖A p0 − g‖² + λ TV(p0), p0 ≥ 0, NER-preconditioned FISTA (Arridge et al., PMB 61 (2016) 8908)",
    peak_memory=peak_memory, order=50, work=work, iterative=True, time_limited=True, warm_up=warm_up,
    kernel_modules=("fpscan.physics.nufft_kernels", "fpscan.physics.array_kernels", "fpscan.service.recon.tv.prox", "fpscan.service.recon.tv.stores",
                    "fpscan.service.recon.tv.fista", "fpscan.service.recon.tv.preconditioner"), warm_in_background=True,
    memory_calibration=MEMORY_CALIBRATION, holds_input=True, summary=SUMMARY, stop_waits_for=STOP_WAITS_FOR)
