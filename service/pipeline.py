"""The one reconstruction dispatch: a dataset + a method name + options → a `Reconstruction`.

Everything that reconstructs calls :func:`reconstruct` — the job worker
(:mod:`service.jobs.work`), ``fpscan recon`` without ``--server``, the live preview
(:mod:`service.preview`) and the experiments (:mod:`service.experiments`) — so the same
input and options give the same volume locally and on the server. Inputs are the
datasets of :mod:`service.storage.datasets` (read any file with its ``load_dataset``).

The method vocabulary is :data:`METHODS` (name → :class:`Method`): what each method is,
whether it needs data on a full regular grid, and which options it takes. A point dataset
covering its whole lattice (a full-lattice scan) is turned into grid data for the grid
methods; grid data are turned into sensor points for ``nedner``. Adding a method is one
:func:`register` call with its runner.

Options (SI units; ``None`` means "the default"):

- ``c``: speed of sound in m/s (default: the dataset's), or ``"auto"``: the speed that
  focuses best (:mod:`service.autofocus`, Tenenbaum sharpness; ``c_range`` the search
  interval in m/s, default 1450-1600); the chosen c, the sharpness curve and the search
  time land in ``params["autofocus"]``;
- ``dtype``: ``"float32"`` or ``"float64"``, the working and output precision, default
  :data:`DEFAULT_DTYPE` = ``"float32"`` for every method and every caller;
- ``eps``: NUFFT tolerance (``ner``, ``nedner``; default 1e-6);
- ``upsample``: lateral upsampling factor 1..8; ``positivity``: clip p0 < 0 to 0;
- ``n_z``, ``dz``: output depth count and spacing in m (default ``n_t`` and ``c·dt``);
- ``interp``: k-Wave's interpolation (``kwave``): ``"*nearest"`` (k-Wave's default),
  ``"nearest"``, ``"*linear"``, ``"linear"``, ``"*cubic"``, ``"cubic"``.

A ``c`` (and each end of ``c_range``) outside 1000-2000 m/s is refused as a likely unit
mistake (``driver.units.check_speeds``, the rule of the CLI, the API and the web form)
unless :func:`reconstruct` is called with ``force=True`` (another medium).

Contracts shared with the callers (docs/architecture.md): ``progress(fraction, stage)``
is called with increasing fractions in [0, 1] (stage ``"reconstructing"``);
``should_stop()`` is polled between the steps of the reconstruction, and when it returns
True :func:`reconstruct` raises :class:`Cancelled`.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np

from driver.constants import C_AUTOFOCUS_RANGE

if TYPE_CHECKING:
    from service.recon.dataset import GridDataset, PointDataset
    from service.recon.reconstruction import Reconstruction

    Dataset = GridDataset | PointDataset

Progress = Callable[[float, str], None]
ShouldStop = Callable[[], bool]
Runner = Callable[..., "Reconstruction"]

DEFAULT_DTYPE = "float32"
DTYPES = ("float32", "float64")
KWAVE_INTERPS = ("*nearest", "nearest", "*linear", "linear", "*cubic", "cubic")

#: every option a method may take, with its meaning (units SI)
OPTIONS: dict[str, str] = {
    "c": "speed of sound, m/s, or 'auto': the c of sharpest focus (service.autofocus; default: the dataset's)",
    "c_range": f"autofocus search interval (c_min, c_max), m/s (default {C_AUTOFOCUS_RANGE[0]:g}-{C_AUTOFOCUS_RANGE[1]:g})",
    "dtype": f"working and output precision, one of {', '.join(DTYPES)} (default {DEFAULT_DTYPE})",
    "eps": "NUFFT tolerance in [1e-14, 1e-1] (default 1e-6)",
    "upsample": "lateral upsampling factor 1..8 (default 1)",
    "positivity": "clip negative p0 to 0 (default false; tv: true)",
    "n_z": "output depth samples, 2..65536 (default n_t)",
    "dz": "output depth spacing, m, in [1e-9, 0.1] (default c·dt)",
    "interp": f"k-Wave interpolation, one of {', '.join(KWAVE_INTERPS)} (default *nearest)",
    "lam": "TV weight λ in the data's units, in [0, 1e30] (tv; default: from the estimated noise level)",
    "iterations": "maximum iterations, 1..100000 (tv; default 60)",
    "time_limit": "wall-time limit of the solver, s, in (0, 604800] (tv; default 3600, the server's setting "
                  "tv_time_limit_s caps it): when reached the result says converged false, stop reason 'time limit'",
    "debias": "refit tv's amplitudes by least squares on its support after the solve (tv; default false)",
}

_COMMON = ("c", "dtype", "upsample", "positivity", "n_z", "dz")


class Cancelled(Exception):
    """The reconstruction stopped because ``should_stop()`` returned True."""


@dataclass(frozen=True)
class Method:
    """One reconstruction method.

    ``name``: the word users type; ``title``: one line for lists (web page, ``--help``);
    ``needs_grid``: True when it needs data on a full regular grid (a full lattice);
    ``options``: the option names it takes (:data:`OPTIONS`); ``run(dataset, c, options,
    progress)`` → `Reconstruction`, given a grid dataset when ``needs_grid`` else a point
    dataset, ``c`` in m/s, the options (``dtype`` as a NumPy dtype, no ``c``) and a
    ``progress(fraction)`` callable; ``source``: where the algorithm comes from;
    ``defaults``: this method's own defaults of options (e.g. ``tv``: positivity on), used
    when the caller leaves them unset and listed with the method (``GET
    /api/reconstructions/methods``, so the web form starts from them)."""

    name: str
    title: str
    needs_grid: bool
    options: tuple[str, ...]
    run: Runner
    source: str = ""
    defaults: dict[str, Any] = field(default_factory=dict)


#: the method vocabulary, in the order lists show it
METHODS: dict[str, Method] = {}


def register(method: Method) -> Method:
    """Add ``method`` to :data:`METHODS` (its options must be known in :data:`OPTIONS`)."""
    unknown = set(method.options) - set(OPTIONS)
    if unknown:
        raise ValueError(f"unknown options {sorted(unknown)} for method {method.name!r}")
    if set(method.defaults) - set(method.options):
        raise ValueError(f"defaults {sorted(set(method.defaults) - set(method.options))} are no options of "
                         f"method {method.name!r}")
    METHODS[method.name] = method
    return method


def default_method(dataset: Any) -> str:
    """The method used when none is asked for -- the one rule for ``fpscan recon``/``unmix``
    (locally and with ``--server``), the API (a request without ``method``) and the job
    worker: ``"ner"`` for grid data, ``"nedner"`` for sensor points (any mask).

    ``dataset``: a dataset (its ``kind``) or the kind itself, ``"grid"`` or ``"points"``
    (a stored dataset's ``layout``; a scan file loads as points)."""
    kind = dataset if isinstance(dataset, str) else getattr(dataset, "kind", None)
    return "ner" if kind == "grid" else "nedner"


def _dtype(value: Any) -> np.dtype:
    from service.recon.checks import OptionError

    try:
        dt = np.dtype(DEFAULT_DTYPE if value is None else value)
    except TypeError:
        dt = None
    if dt is None or dt.name not in DTYPES:
        raise OptionError(f"dtype must be one of {', '.join(DTYPES)}, got {value!r}")
    return dt


def _check_interp(value: Any) -> str:
    if value not in KWAVE_INTERPS:
        from service.recon.checks import OptionError

        raise OptionError(f"interp must be one of {', '.join(KWAVE_INTERPS)}, got {value!r}")
    return str(value)


def _check_bool(name: str) -> Callable[[Any], bool]:
    def check(value: Any) -> bool:
        if not isinstance(value, (bool, np.bool_)) and not (isinstance(value, int) and value in (0, 1)):
            from service.recon.checks import OptionError

            raise OptionError(f"{name} must be true or false, got {value!r}")
        return bool(value)

    return check


def option_rules() -> dict[str, Callable[[Any], Any]]:
    """Each option's rule (value -> checked value, or ``service.recon.checks.OptionError``
    naming the option and its range): the very functions the kernels apply
    (``service.recon.checks``), so every door -- :func:`reconstruct`, ``fpscan recon`` /
    ``unmix`` and ``POST /api/reconstructions`` -- refuses what the kernel would, before any
    work. ``c`` and ``c_range`` have their own rules (:func:`reconstruct`,
    ``driver.units.check_speeds``, ``service.autofocus.check_c_range``)."""
    from service.recon import checks

    return {"eps": checks.check_eps, "upsample": checks.check_upsample, "n_z": checks.check_n_z,
            "dz": checks.check_dz, "lam": checks.check_lam, "iterations": checks.check_iterations,
            "time_limit": checks.check_time_limit, "dtype": _dtype, "interp": _check_interp,
            "positivity": _check_bool("positivity"), "debias": _check_bool("debias")}


def check_option_values(options: dict) -> None:
    """Apply :func:`option_rules` to every option given (``None``: the default, passes);
    raises ``service.recon.checks.OptionError`` (a ValueError) naming the first refused."""
    rules = option_rules()
    for name, value in options.items():
        if value is not None and name in rules:
            rules[name](value)


def method_options(method: str, options: dict) -> dict:
    """The options ``method`` takes, from ``options``, each checked by its rule
    (:func:`option_rules`); ``None`` values (the defaults) are left out. Raises
    ValueError naming the problem: an unknown method; a name that is no option at all
    (:data:`OPTIONS`); an option ``method`` does not take (``OptionError`` naming the
    method's options: an option that would do nothing is never silently dropped); a value
    outside its rule; a ``c_range`` without ``c="auto"`` or outside
    :func:`service.autofocus.check_c_range`. ``force`` (:func:`reconstruct`'s flag, not a
    method's option) passes and is left out. Returns a new dict."""
    from service.recon.checks import OptionError

    spec = METHODS.get(method)
    if spec is None:
        raise OptionError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    unknown = sorted(set(options) - set(OPTIONS) - {"force"})  # force: reconstruct's own flag
    if unknown:
        raise OptionError(f"unknown option {', '.join(unknown)} (options: {', '.join(OPTIONS)})")
    foreign = sorted(k for k, v in options.items() if v is not None and k in OPTIONS and k not in spec.options
                     and k != "c_range")
    if foreign:
        raise OptionError(f"method {method!r} takes no option {', '.join(foreign)} "
                          f"(its options: {', '.join(spec.options)})")
    check_option_values(options)
    if options.get("c_range") is not None:  # never silently unused
        if options.get("c") != "auto":
            raise OptionError(f"c_range is the autofocus search interval: it needs c='auto', got c={options.get('c')!r}")
        from service.autofocus import check_c_range

        check_c_range(options["c_range"])
    return {k: v for k, v in options.items() if v is not None and k in spec.options}


def reconstruct(dataset: Dataset, method: str, *, progress: Progress | None = None,
                should_stop: ShouldStop | None = None, force: bool = False, **options: Any) -> Reconstruction:
    """Reconstruct p0 from ``dataset`` with ``method`` (a key of :data:`METHODS`).

    Parameters
    ----------
    dataset : `service.storage.datasets.GridDataset` (``data`` ``(n_t, n_y, n_x)`` /
        ``(n_t, n_x)``) or `PointDataset` (``alines`` ``(n, n_t)`` at ``positions``).
    method : ``nedner``, ``ner``, ``linear``, ``nearest``, ``cubic``, ``kwave``, ...
    progress : optional ``progress(fraction, stage)``.
    should_stop : optional ``should_stop() -> bool``, polled between steps.
    force : accept a ``c`` (or ``c_range``) outside 1000-2000 m/s (a medium other than
        tissue or water); without it such a value is a ValueError naming the likely unit
        mistake (``driver.units.ImplausibleValue``).
    **options : the method's options (module docstring); ``None`` = default; each is
        checked by its rule (:func:`method_options`) before any work, and an option the
        method does not take is refused naming the method's options.

    Returns
    -------
    `Reconstruction`: ``p0`` ``(n_z, n_y, n_x)`` / ``(n_z, n_x)`` with ``z``, ``x``, ``y``
    (m), ``params`` (everything used) and ``p0_unit`` (``"Pa"`` for a calibrated scan,
    else ``"a.u."``: ``service.storage.datasets.p0_unit``).

    Raises
    ------
    ValueError naming the problem (unknown method or option name, an option the method
    does not take, a grid method on a sensor mask, no A-lines, bad values -- an option
    outside its rule is ``service.recon.checks.OptionError`` -- an implausible ``c``
    without ``force``);
    Cancelled when ``should_stop()`` returned True.
    """
    spec = METHODS.get(method)
    if spec is None:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    opts = {**spec.defaults, **method_options(method, options)}
    from driver.units import check_speeds

    check_speeds(c=opts.get("c"), c_range=options.get("c_range"), force=force)
    if isinstance(opts.get("c"), str):
        if opts["c"] != "auto":
            raise ValueError(f"c must be a speed of sound in m/s or 'auto', got {opts['c']!r}")
        from service.autofocus import focus_then_reconstruct

        rest = {k: v for k, v in options.items() if k not in ("c", "c_range")}
        # the speeds tried lie within c_range, checked above
        return focus_then_reconstruct(dataset, method, partial(reconstruct, force=True),
                                      c_range=options.get("c_range"), options_of=lambda m: METHODS[m].options,
                                      progress=progress, should_stop=should_stop, **rest)
    opts["dtype"] = _dtype(opts.get("dtype"))
    c = opts.pop("c", None)
    c = float(dataset.c if c is None else c)
    from service.recon.dataset import GridDataset, PointDataset, p0_unit, wavelength_params

    if spec.needs_grid and isinstance(dataset, PointDataset):
        dataset = dataset.to_grid()
    elif not spec.needs_grid and isinstance(dataset, GridDataset):
        dataset = dataset.to_points()

    def step(fraction: float, stage: str = "reconstructing") -> None:
        if should_stop is not None and should_stop():
            raise Cancelled("reconstruction cancelled")
        if progress is not None:
            progress(float(fraction), stage)

    step(0.0)
    result = spec.run(dataset, c, opts, step)
    result.params.update(wavelength_params(dataset))  # which excitation wavelength (storage.datasets)
    result.p0_unit = p0_unit(dataset)  # Pa for a calibrated scan, else a.u.
    step(1.0)
    return result


# -- the methods ------------------------------------------------------------------------
def _run_points(ds: PointDataset, c: float, opts: dict, step: Callable[[float], None]) -> Reconstruction:
    from service.recon import reconstruct_points

    if ds.alines.shape[0] == 0:
        raise ValueError("the input has no A-lines to reconstruct")
    # NEDNER = NUFFT in time (the "ner" temporal step) + type-1 NUFFT over the positions
    return reconstruct_points(ds.alines, ds.positions, ds.dt, c, weights=ds.weights, grid=ds.grid,
                              method="ner", t0=ds.t0, progress=step, **opts)


def _grid_runner(name: str) -> Runner:
    def run(ds: GridDataset, c: float, opts: dict, step: Callable[[float], None]) -> Reconstruction:
        from service.recon import reconstruct_grid

        dy = ds.dy if ds.data.ndim == 3 else None
        return reconstruct_grid(ds.data, ds.dx, ds.dt, c, method=name, dy=dy, t0=ds.t0, progress=step, **opts)

    return run


def _run_kwave(ds: GridDataset, c: float, opts: dict, step: Callable[[float], None]) -> Reconstruction:
    from driver.physics.axes import centred_axis
    from service.recon import kspace_line_recon, kspace_plane_recon
    from service.recon.reconstruction import Reconstruction

    interp = opts.get("interp", "*nearest")
    if interp not in KWAVE_INTERPS:
        raise ValueError(f"interp must be one of {', '.join(KWAVE_INTERPS)}, got {interp!r}")
    if ds.t0:
        raise ValueError("method 'kwave' needs sample 0 at t = 0 (k-Wave's convention); this input has "
                         f"t0 = {ds.t0} s: use 'ner'")
    dtype, positivity = opts["dtype"], bool(opts.get("positivity", False))
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
    params = dict(method="kwave", interp=interp, dt=ds.dt, c=c, dx=ds.dx, dy=None if y is None else ds.dy or ds.dx,
                  dtype=dtype.name, dz=c * ds.dt, n_z=n_t, positivity=positivity, t0=0.0, n_t=n_t,
                  data_shape=list(data.shape),
                  source="kspaceLineRecon" if y is None else "kspacePlaneRecon")
    return Reconstruction(p0.astype(dtype, copy=False), np.arange(n_t) * (c * ds.dt),
                          centred_axis(data.shape[-1], ds.dx), y, params)


def _run_tv(ds: PointDataset, c: float, opts: dict, step: Callable[..., None]) -> Reconstruction:
    from service.recon import reconstruct_tv
    from service.recon.tv import DEFAULT_MAX_ITER

    if ds.alines.shape[0] == 0:
        raise ValueError("the input has no A-lines to reconstruct")
    opts = dict(opts)
    iterations = opts.pop("iterations", DEFAULT_MAX_ITER)
    positivity = bool(opts.pop("positivity"))  # tv's default: on (its Method.defaults)
    # the progress stage names the iteration ("iteration k/N"), shown by job progress
    return reconstruct_tv(ds.alines, ds.dt, c, positions=ds.positions, weights=ds.weights, grid=ds.grid,
                          t0=ds.t0, max_iter=iterations, positivity=positivity, progress=step, **opts)


register(Method("nedner", "NEDNER-NUFFT (any sensor mask)", False, ("eps", *_COMMON), _run_points,
                "paper §3.2: temporal NUFFT + type-1 NUFFT over the sensor positions"))
register(Method("ner", "NER-NUFFT (full regular grid)", True, ("eps", *_COMMON), _grid_runner("ner"),
                "paper §3.1: temporal NUFFT, lateral FFT"))
register(Method("linear", "FFT + linear interpolation (k-Wave style)", True, _COMMON, _grid_runner("linear"),
                "FFT on the regular frequency grid + linear interpolation"))
register(Method("nearest", "FFT + nearest-neighbour interpolation", True, _COMMON, _grid_runner("nearest"),
                "FFT on the regular frequency grid + nearest-neighbour interpolation"))
register(Method("cubic", "FFT + cubic (pchip) interpolation", True, _COMMON, _grid_runner("cubic"),
                "FFT on the regular frequency grid + pchip interpolation"))
register(Method("kwave", "k-Wave compatible (kspaceLineRecon / kspacePlaneRecon)", True,
                ("c", "dtype", "positivity", "interp"), _run_kwave,
                "k-Wave kspaceLineRecon / kspacePlaneRecon (reference/KWAVE_RECON_NOTES.md)"))
register(Method("tv", "model-based: TV + positivity on the exact model (iterative; sparse, noisy scans)", False,
                ("eps", "lam", "iterations", "time_limit", "c", "dtype", "positivity", "n_z", "dz", "debias"), _run_tv,
                "½‖A p0 − g‖²_W + λ TV(p0), p0 ≥ 0, NER-preconditioned FISTA (Arridge et al., PMB 61 (2016) 8908)",
                defaults={"positivity": True}))
