"""The one reconstruction dispatch: a dataset + a method name + options → a `Reconstruction`.

Everything that reconstructs calls :func:`reconstruct` — the job worker
(:mod:`fpscan.service.jobs.work`), ``fpscan recon`` without ``--server``, the live preview
(:mod:`fpscan.service.jobs.preview`) and the experiments (:mod:`fpscan.experiments`) — so the same
input and options give the same volume locally and on the server. Inputs are the
datasets of :mod:`fpscan.service.recon.dataset` (read any file with ``fpscan.service.storage.loader.load_dataset``).

The method vocabulary is :data:`METHODS` (name → :class:`Method`), the registry of
:mod:`fpscan.service.recon.methods`: one module per method with its typed options model (type,
range, unit, default of each option), whether it needs data on a full regular grid, its
peak-memory model and its ``run``. A point dataset covering its whole lattice (a
full-lattice scan) is turned into grid data for the grid methods; grid data are turned
into sensor points for ``nedner``. Adding a method is one new module in
``service/recon/methods/`` (it calls :func:`register`); the HTTP model, the CLI flags,
the web page's fields and the docs table follow from the registry.

Options: each method's own typed model (``fpscan.service.recon.methods.get(method).options_model``, a
``MethodOptions``: type, range, unit and default of each, SI units, ``None`` meaning "the default"),
validated once, at the door (:meth:`Method.check`), and carried typed to the method's ``run``:

- ``sound_speed``: speed of sound in m/s (default: the dataset's), or ``"auto"``: the speed that
  focuses best (:mod:`fpscan.service.autofocus`, Tenenbaum sharpness; ``sound_speed_range`` the
  search interval in m/s, default 1450-1600); the chosen speed, the sharpness curve and the search
  time land in ``params["autofocus"]``; ``force`` accepts a speed outside
  ``fpscan.constants.C_PLAUSIBLE`` (another medium: without it such a value is refused as a likely
  unit mistake, ``fpscan.driver.units.check_speeds``);
- ``dtype``: ``"float32"`` or ``"float64"``, the working and output precision, default
  :data:`DEFAULT_DTYPE` = ``"float32"`` for every method and every caller;
- ``eps``: NUFFT tolerance (``ner``, ``nedner``; default 1e-6);
- ``upsample``: lateral upsampling factor 1..8; ``positivity``: clip p0 < 0 to 0;
- ``n_z``, ``dz``: output depth count and spacing in m; by default every method's one depth grid
  (:func:`fpscan.service.recon.depth.depth_grid`): ``dz`` the lateral pitch (``c·dt`` where that is
  finer), ``n_z`` as deep as the record reaches (``c·t_last``), one given alone keeping the other's
  default (``tv``: its band's spacing, down to the last echo above the noise; ``kwave`` has no
  depth options: k-Wave's own grid, ``n_t`` rows of ``c·dt``);
- ``interp``: k-Wave's interpolation (``kwave``): ``"*nearest"`` (k-Wave's default),
  ``"nearest"``, ``"*linear"``, ``"linear"``, ``"*cubic"``, ``"cubic"``;
- ``lam``, ``max_iter``, ``tol``, ``time_limit``, ``debias``, ``whole_record`` (``tv``).

An earlier release's names (``c``, ``c_range``, ``iterations``) are accepted with a
``DeprecationWarning`` naming the new one
(``fpscan.service.recon.methods.options.DEPRECATED_NAMES``).

Contracts shared with the callers (docs/architecture.md): ``progress(fraction, stage)``
is called with non-decreasing fractions in [0, 1] (stage ``"reconstructing"``; a long
step may repeat its fraction so that a cancel is heard: ``tv`` does every 0.2 s at most);
``should_stop()`` is polled before each of those calls, and when it returns True
:func:`reconstruct` raises :class:`Cancelled`.

Examples
--------
>>> from fpscan.service.pipeline import METHODS, OPTIONS
>>> list(METHODS)[:2], {"linear", "nearest", "cubic", "kwave", "tv"} <= set(METHODS)  # the default first
(['nedner', 'ner'], True)
>>> OPTIONS["eps"]
'NUFFT tolerance (relative accuracy of the non-uniform FFTs) ([1e-14, 0.1]; default 1e-06)'
>>> import fpscan, numpy as np
>>> ds = fpscan.GridDataset(np.zeros((64, 8)), dx=1e-4, dt=1e-4 / 1500, sound_speed=1500.0)
>>> fpscan.reconstruct(ds, "ner", sound_speed=1480).params["sound_speed"]
1480.0
"""
from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from contextvars import ContextVar
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np

from fpscan.service.progress import Progress, forward, span
from fpscan.service.recon import methods as _methods
from fpscan.service.recon.limits import DEFAULT_DTYPE, DTYPES, KWAVE_INTERPS
from fpscan.service.recon.methods import Method, MethodOptions

__all__ = ["METHODS", "OPTIONS", "DEFAULT_DTYPE", "DTYPES", "KWAVE_INTERPS", "Method", "register", "Cancelled", "run_file",
           "Progress", "ShouldStop", "default_method", "option_rules", "check_option_values", "method_options",
           "reconstruct", "tv_problem"]

if TYPE_CHECKING:
    from fpscan.service.plans import Mask, Plan
    from fpscan.service.recon.dataset import GridDataset, PointDataset
    from fpscan.service.recon.reconstruction import Reconstruction
    from fpscan.service.recon.tv.formulation import TvProblem

    Dataset = GridDataset | PointDataset

ShouldStop = Callable[[], bool]
Runner = Callable[..., "Reconstruction"]

#: the method registry (:mod:`fpscan.service.recon.methods`: one module per method) -- the one list
METHODS: dict[str, Method] = _methods.METHODS
register = _methods.register


def _options() -> dict[str, str]:
    """Every option a method may take, with its meaning, range, unit and default (from the
    methods' option models; the speed of sound's, every method's, first)."""
    from fpscan.service.recon.methods.options import SpeedOptions

    out = {name: f.description or "" for name, f in SpeedOptions.model_fields.items() if name != "force"}
    for m in METHODS.values():
        for o in _methods.option_schemas(m):
            if o["name"] in out:
                continue
            rng, unit = _methods.range_text(o["schema"]), o["schema"].get("unit", "")
            said = [unit] if unit not in ("", "1") else []
            said += [f"one of {rng}" if "enum" in o["schema"] else rng] if rng else []
            said.append(f"default {_methods.default_text(o['name'])}")
            out[o["name"]] = f"{o['description']} ({'; '.join(said)})"
    return out


#: every option a method may take, with its meaning (units SI; generated from the registry)
OPTIONS: dict[str, str] = _options()


class Cancelled(Exception):
    """The reconstruction stopped because ``should_stop()`` returned True.

    Raised by :func:`reconstruct` from the first progress step after ``should_stop()``
    returns True (the job worker marks the job cancelled).

    Attributes
    ----------
    args : tuple of str
        The message, ``"reconstruction cancelled"``.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.pipeline import Cancelled, reconstruct
    >>> from fpscan.service.recon.dataset import GridDataset
    >>> ds = GridDataset(np.zeros((64, 8)), dx=1e-4, dt=1e-4 / 1500, sound_speed=1500.0)
    >>> try:
    ...     reconstruct(ds, "ner", should_stop=lambda: True)
    ... except Cancelled as exc:
    ...     print(repr(exc))
    Cancelled('reconstruction cancelled')
    >>> issubclass(Cancelled, ValueError)  # not a refusal of the input
    False
    """


def default_method(dataset: Dataset | str) -> str:
    """The method used when none is asked for -- the one rule for ``fpscan recon``/``unmix``
    (locally and with ``--server``), the API (a request without ``method``) and the job
    worker: the registry's default for the input (``fpscan.service.recon.methods.default_for``: NER for
    grid data, NEDNER for sensor points, any mask).

    ``dataset``: a dataset (its ``kind``) or the kind itself, ``"grid"`` or ``"points"``
    (a stored dataset's ``layout``; a scan file loads as points).

    Parameters
    ----------
    dataset : GridDataset, PointDataset or str
        A dataset of :mod:`fpscan.service.recon.dataset`, or its kind (``"grid"`` / ``"points"``).

    Returns
    -------
    str
        ``default_for("grid")`` for grid data, ``default_for("points")`` for anything else.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.pipeline import default_method
    >>> from fpscan.service.recon.dataset import GridDataset
    >>> ds = GridDataset(np.zeros((64, 8)), dx=1e-4, dt=1e-4 / 1500, sound_speed=1500.0)
    >>> default_method(ds), default_method(ds.to_points())
    ('ner', 'nedner')
    >>> default_method("grid"), default_method("points")
    ('ner', 'nedner')
    """
    from fpscan.service.recon.methods import default_for

    kind = dataset if isinstance(dataset, str) else getattr(dataset, "kind", None)
    return default_for("grid" if kind == "grid" else "points")


def _field_rule(name: str) -> Callable[[Any], Any]:
    """The rule of option ``name``: its field in the methods' option models."""
    method = next(m for m in METHODS.values() if name in m.options_model.model_fields)

    def rule(value: Any) -> Any:
        return getattr(method.check({name: value}), name)

    return rule


def option_rules() -> dict[str, Callable[[Any], Any]]:
    """Each option's rule (value -> checked value, or ``fpscan.service.recon.checks.OptionError``
    naming the option and its range): the option's field in the methods' models
    (:mod:`fpscan.service.recon.methods`), which applies the kernel's own function
    (``fpscan.service.recon.checks``), so every door -- :func:`reconstruct`, ``fpscan recon`` /
    ``unmix`` and ``POST /api/reconstructions`` -- refuses what the kernel would, before any
    work. The speed of sound's fields are checked by every method's model
    (``fpscan.service.recon.methods.options.SpeedOptions``).

    Returns
    -------
    dict
        Option name -> ``rule(value)``, returning the checked value (SI units; e.g. an int
        ``upsample``, a float ``eps``) or raising ``fpscan.service.recon.checks.OptionError``.

    Examples
    --------
    >>> from fpscan.service.pipeline import option_rules
    >>> rules = option_rules()
    >>> {"debias", "dtype", "dz", "eps", "interp", "max_iter", "lam", "n_z", "positivity", "time_limit",
    ...  "tol", "upsample"} <= set(rules)
    True
    >>> rules["upsample"](2.0), rules["eps"]("1e-8")
    (2, 1e-08)
    >>> rules["eps"](5e-15)
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: eps must be in [1e-14, 1e-1], got 5e-15
    """
    return {name: _field_rule(name) for name in _methods.option_fields()}


def check_option_values(options: dict) -> None:
    """Apply :func:`option_rules` to every option given (``None``: the default, passes);
    raises ``fpscan.service.recon.checks.OptionError`` (a ValueError) naming the first refused.

    Parameters
    ----------
    options : dict
        Option name -> value (SI units); names without a rule here (the speed of sound's) pass.

    Raises
    ------
    fpscan.service.recon.checks.OptionError
        The first value its rule refuses.

    Examples
    --------
    >>> from fpscan.service.pipeline import check_option_values
    >>> check_option_values({"eps": 1e-8, "upsample": None, "sound_speed": 1500.0})  # all pass
    >>> check_option_values({"n_z": 1})
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: n_z must be an integer in 2..65536, got 1
    """
    rules = option_rules()
    for name, value in options.items():
        if value is not None and name in rules:
            rules[name](value)


def method_options(method: str, options: dict | MethodOptions | None = None, /, **given: Any) -> MethodOptions:
    """``method``'s options validated by its own model: :meth:`Method.check`, the one validation
    every door runs (this dispatch, ``fpscan recon`` / ``unmix``, ``POST /api/reconstructions``),
    before any work; and where ``device="cuda"`` is asked, whether a CUDA GPU is visible
    (``fpscan.service.recon.device.choose``, as the server's admission asks).

    Parameters
    ----------
    method : str
        A key of :data:`METHODS`.
    options : dict or MethodOptions, optional
        Option name -> value (SI units: ``sound_speed`` in m/s or ``"auto"``,
        ``sound_speed_range`` m/s, ``dz`` m, ``time_limit`` s; or text with a unit);
        ``None`` means the default. An instance of the method's model passes as is.
    **given
        More options.

    Returns
    -------
    MethodOptions
        An instance of the method's model (every field filled).

    Raises
    ------
    fpscan.service.recon.checks.OptionError
        An unknown method or option name, an option ``method`` does not take (naming its
        options: an option that would do nothing is never silently dropped), a value outside its
        rule, a ``sound_speed_range`` without ``sound_speed="auto"``, ``"auto"`` for a method
        that cannot search the speed.
    ValueError
        An implausible speed without ``force`` (``fpscan.driver.units.ImplausibleValue``);
        ``device="cuda"`` where no CUDA GPU is visible (``fpscan.service.recon.device.Unsuited``).

    Examples
    --------
    >>> from fpscan.service.pipeline import method_options
    >>> method_options("nedner", {"upsample": 2.0, "eps": None}, sound_speed=1480.0).model_dump(exclude_defaults=True)
    {'sound_speed': 1480.0, 'upsample': 2}
    >>> method_options("ner", {"lam": 0.1})
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: method 'ner' takes no option lam (its options: sound_speed, sound_speed_range, force, eps, ...)
    >>> method_options("ner", sound_speed_range=(1450.0, 1600.0))
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: sound_speed_range is the autofocus search interval: it needs sound_speed='auto', got None
    """
    checked = _methods.get(method).check(options, **given)
    if getattr(checked, "device", None) == "cuda":  # refused at the door where no GPU is visible, as the admission does
        from fpscan.service.recon.device import choose

        choose("cuda", 0)
    return checked


def reconstruct(dataset: Dataset, method: str, options: dict | MethodOptions | None = None, /, *,
                progress: Progress | None = None, should_stop: ShouldStop | None = None, quiet: bool = False,
                **given: Any) -> Reconstruction:
    """Reconstruct p0 from ``dataset`` with ``method`` (a key of :data:`METHODS`).

    Parameters
    ----------
    dataset : GridDataset or PointDataset
        `fpscan.service.recon.dataset.GridDataset` (``data`` ``(n_t, n_y, n_x)`` / ``(n_t, n_x)``,
        time first, pitch in m, ``dt`` in s) or `PointDataset` (``alines`` ``(n, n_t)`` at
        ``positions`` ``(n, 1)`` / ``(n, 2)`` in m).
    method : str
        ``nedner``, ``ner``, ``linear``, ``nearest``, ``cubic``, ``kwave``, ``tv``, ...
    options : dict or MethodOptions, optional
        The method's options (module docstring): its own model's instance (what a job's record
        holds), or a dict of them; or give them as keywords.
    progress : callable, optional
        ``progress(fraction, stage)``, fractions non-decreasing in [0, 1], and a stage left
        behind never reported again at the same fraction (``fpscan.service.progress.Forward``:
        the method's last stage, e.g. tv's "converged after 53 iterations", stays the stage).
    should_stop : callable, optional
        ``should_stop() -> bool``, polled between steps.
    quiet : bool, optional
        No progress bar in a Jupyter notebook. Without ``progress`` a call in a notebook shows
        one in the cell's output (``fpscan.service.notebook``); elsewhere nothing is shown either way.
    **given
        The method's options as keywords (``sound_speed`` in m/s or ``"auto"``, ``force``,
        ``eps``, ...); ``None`` = default. All are checked by the method's model
        (:func:`method_options`) before any work; an option the method does not take is refused
        naming the method's options.

    Returns
    -------
    Reconstruction
        ``p0`` ``(n_z, n_y, n_x)`` / ``(n_z, n_x)`` with ``z``, ``x``, ``y`` (m), ``params``
        (everything used, the speed of sound as ``sound_speed``) and ``p0_unit`` (``"Pa"`` for
        a calibrated scan, else ``"a.u."``: ``fpscan.service.storage.loader.p0_unit``).

    Raises
    ------
    ValueError
        Naming the problem (unknown method or option name, an option the method does not
        take, a grid method on a sensor mask, no A-lines, bad values -- an option outside
        its rule is ``fpscan.service.recon.checks.OptionError`` -- an implausible speed of sound
        without ``force``, a dataset whose own speed of sound, sample interval, spacings,
        lattice or lateral shift are out of bounds: ``fpscan.service.recon.dataset.check_dataset``;
        a p0 that came out with NaN or infinite values, samples beyond the working precision's range).
    Cancelled
        When ``should_stop()`` returned True.

    Examples
    --------
    A laterally uniform layer at depth row 10 on an 8-sensor line (dz = the pitch = c dt = 0.1 mm):

    >>> import numpy as np
    >>> from fpscan.service.pipeline import reconstruct
    >>> from fpscan.service.recon.dataset import GridDataset
    >>> g = np.zeros((64, 8))  # (n_t, n_x)
    >>> g[10] = 0.5
    >>> ds = GridDataset(g, dx=1e-4, dt=1e-4 / 1500, sound_speed=1500.0)
    >>> seen = []
    >>> r = reconstruct(ds, "ner", progress=lambda fraction, stage: seen.append((fraction, stage)))
    >>> r.p0.shape, r.p0.dtype, int(r.p0[:, 4].argmax()), round(float(r.z[10]), 6), r.p0_unit
    ((64, 8), dtype('float32'), 10, 0.001, 'a.u.')
    >>> seen[0], seen[-1]
    ((0.0, 'reconstructing'), (1.0, 'reconstructing'))

    Grid data go to ``nedner`` as sensor points; the options are checked first:

    >>> r = reconstruct(ds, "nedner", dtype="float64", upsample=2)
    >>> r.p0.shape, r.p0.dtype, r.params["method"]  # x upsampled 2x
    ((64, 16), dtype('float64'), 'nedner')
    >>> reconstruct(ds, "ner", eps=5e-15)
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: eps must be in [1e-14, 1e-1], got 5e-15
    >>> reconstruct(ds, "ner", sound_speed=1.5)
    Traceback (most recent call last):
    ...
    fpscan.driver.units.ImplausibleValue: sound_speed: sound speed 1.5 m/s is implausible for tissue or water ...
    >>> reconstruct(ds, "ner", should_stop=lambda: True)
    Traceback (most recent call last):
    ...
    fpscan.service.pipeline.Cancelled: reconstruction cancelled
    """
    if progress is None and not quiet and not _BAR_SHOWN.get():
        from fpscan.service.notebook import notebook_bar

        bar = notebook_bar(method)
        if bar is not None:  # a Jupyter notebook: one bar for this call, none for the calls inside it
            return _with_bar(bar, partial(reconstruct, dataset, method, options, progress=bar,
                                          should_stop=should_stop, quiet=True, **given), method)
    spec = _methods.get(method)
    opts = method_options(method, options, **given)
    _checked_input(dataset)
    progress = forward(progress)  # the fraction and the stage only move forward, whatever the method says
    if opts.sound_speed == "auto":
        from fpscan.service.autofocus import focus_then_reconstruct

        return focus_then_reconstruct(dataset, spec.name, reconstruct, opts, progress=progress,
                                      should_stop=should_stop)
    c = float(dataset.sound_speed if opts.sound_speed is None else opts.sound_speed)
    from fpscan.service.recon.dataset import GridDataset, PointDataset, p0_unit, wavelength_params

    if spec.needs_grid and isinstance(dataset, PointDataset):
        dataset = dataset.to_grid()
    elif not spec.needs_grid and isinstance(dataset, GridDataset):
        dataset = dataset.to_points()

    def checked(fraction: float, stage: str) -> None:
        if should_stop is not None and should_stop():
            raise Cancelled("reconstruction cancelled")
        if progress is not None:
            progress(fraction, stage)

    # the method's progress: (fraction, stage) or a kernel's (fraction), stage "reconstructing"
    step = span(checked, 0.0, 1.0)
    step(0.0)
    result = spec.run(dataset, c, opts, step)
    _finite_image(result.p0, dataset)
    # the record names the method that ran by its registered name (a method may run another's
    # kernels: the result, volume.h5 and every export say which method the user asked for)
    result.params["method"] = spec.name
    result.params.update(wavelength_params(dataset))  # which excitation wavelength (storage.loader)
    result.p0_unit = p0_unit(dataset)  # Pa for a calibrated scan, else a.u.
    _shift_lateral(result, dataset.lateral_shift)
    step(1.0)
    return result


#: whether a notebook bar is showing this thread's reconstruction (the calls inside it show none)
_BAR_SHOWN: ContextVar[bool] = ContextVar("fpscan_notebook_bar", default=False)


def _with_bar(bar: Any, call: Callable[[], Reconstruction], method: str) -> Reconstruction:
    """``call()`` under a notebook bar (``fpscan.service.notebook.NotebookBar``), which ends on how the
    reconstruction ended (an iterative method's outcome, else "done") or where it stopped."""
    from fpscan.service.recon.methods import outcome

    token = _BAR_SHOWN.set(True)
    try:
        result = call()
    except BaseException:
        bar.close()
        raise
    finally:
        _BAR_SHOWN.reset(token)
    bar.close(outcome(result.params, method) or "done")
    return result


def _load_inputs(paths: list, format: str | None, unmixing: bool, wavelength: int | str | None,
                 wavelengths: Sequence[float] | None, load: dict,
                 plan: Plan | Mask | dict | None) -> tuple[Any, list]:
    """:func:`run_file`'s inputs read: ``(wavelengths, datasets)``, unmixing's (one per wavelength,
    ``fpscan.service.spectral.load_wavelength_datasets``) or one file's (``wavelengths`` None), sampled
    by ``plan`` (``fpscan.service.subsample``) where given."""
    if unmixing:
        if plan is not None:
            raise ValueError("a plan samples one dense input: not with unmix")
        from fpscan.service.spectral import load_wavelength_datasets

        return load_wavelength_datasets(paths, format, wavelengths=wavelengths, **load)
    from fpscan.service.storage.loader import load_wavelengths

    if len(paths) != 1:
        raise ValueError(f"one input file, got {len(paths)} (several only to unmix, one per wavelength)")
    datasets = load_wavelengths(paths[0], format, wavelength=wavelength, **load)
    if plan is not None:
        from fpscan.service.subsample import subsample

        datasets = [subsample(ds, plan) for ds in datasets]
    return None, datasets


def tv_problem(dataset: Dataset, options: dict | MethodOptions | None = None, /, **given: Any) -> TvProblem:
    """The problem ``tv`` solves for ``dataset``, for any solver: the operator A as a
    ``pylops.LinearOperator``, the data g it fits, the warm start, the grid and the automatic λ
    (``fpscan.service.recon.tv.formulation.TvProblem``), made by tv's own set-up on the CPU:

        p0 = argmin_{p >= 0} J(p) = ½ ‖A p − g‖² + λ TV(p)

    (Arridge et al., Phys. Med. Biol. 61 (2016) 8908), so that pylops' and pyproximal's solvers
    run on fpscan's physics and compare with tv by ``objective`` (examples/plot_tv_pyproximal.py).

    Parameters
    ----------
    dataset : GridDataset or PointDataset
        As :func:`reconstruct`'s (grid data become one A-line per grid point).
    options : dict or MethodOptions, optional
        tv's options that set its problem (``sound_speed`` in m/s, ``force``, ``eps``, ``dtype``,
        ``n_z``, ``dz`` in m, ``positivity``, ``lam``, ``whole_record``), checked by tv's model
        as :func:`reconstruct` checks them; or give them as keywords.
    **given
        More options.

    Returns
    -------
    TvProblem
        ``operator`` (``dims`` the image's ``(n_z, n_x)`` / ``(n_z, n_y, n_x)``, ``dimsd`` the
        A-lines' ``(n_points, n_t)``; vectors flattened in C order), ``data`` (g, float64, Pa),
        ``warm_start`` (an image, the working dtype), ``grid``, ``lam`` (Pa), ``positivity``, the
        axes ``z``, ``x``, ``y`` (m, on the data's lateral coordinates), ``gradient`` (TV's ∇),
        ``preconditioner`` (tv's P), ``params``; ``objective(p)`` = J(p) in Pa².

    Raises
    ------
    ValueError
        What :func:`reconstruct` refuses for ``tv``; an option of tv's solver (``max_iter``,
        ``tol``, ``time_limit``, ``debias``, ``device``), or ``sound_speed="auto"`` (the search
        reconstructs: take the speed a ``tv`` reconstruction found, its ``params["sound_speed"]``).

    Examples
    --------
    >>> import numpy as np
    >>> import fpscan
    >>> g = np.zeros((64, 8)); g[10] = 0.5  # (n_t, n_x): a layer at depth row 10
    >>> ds = fpscan.GridDataset(g, dx=1e-4, dt=1e-4 / 1500, sound_speed=1500.0)
    >>> pb = fpscan.tv_problem(ds, n_z=16)
    >>> pb.operator.dims, pb.data.shape, pb.warm_start.dtype, pb.positivity
    ((16, 8), (8, 64), dtype('float32'), True)
    >>> fpscan.tv_problem(ds, max_iter=10)
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: tv_problem takes the options of tv's problem; max_iter sets its solver
    """
    from fpscan.service.recon.checks import OptionError
    from fpscan.service.recon.dataset import GridDataset
    from fpscan.service.recon.methods import tv

    opts = method_options("tv", options, **given)
    asked = opts.model_fields_set if isinstance(options, MethodOptions) else {
        k for k, v in {**(options or {}), **given}.items() if v is not None}
    solver = [k for k in tv.SOLVER_OPTIONS if k in asked]
    if solver:
        raise OptionError(f"tv_problem takes the options of tv's problem; {', '.join(solver)} "
                          f"set{'s' if len(solver) == 1 else ''} its solver")
    if opts.sound_speed == "auto":
        raise OptionError("tv_problem needs the speed of sound in m/s, not 'auto' (the search reconstructs: "
                          "take the params['sound_speed'] of fpscan.reconstruct(dataset, 'tv', sound_speed='auto'))")
    _checked_input(dataset)
    c = float(dataset.sound_speed if opts.sound_speed is None else opts.sound_speed)
    points = dataset.to_points() if isinstance(dataset, GridDataset) else dataset
    assert isinstance(opts, tv.Options)  # `method_options` gives tv's own model
    pb = tv.problem(points, c, opts)
    shift = dataset.lateral_shift
    if shift and any(shift):  # the image on the data's own lateral coordinates, as `reconstruct` puts it
        y = None if pb.y is None or len(shift) < 2 else np.asarray(pb.y, dtype=np.float64) + float(shift[1])
        pb = dataclasses.replace(pb, x=np.asarray(pb.x, dtype=np.float64) + float(shift[0]),
                                 y=pb.y if y is None else y)
    return pb


def _checked_input(dataset: Any) -> None:
    """A reconstruction's input: a dataset whose numbers are within their bounds
    (`fpscan.service.recon.dataset.check_dataset`; a ValueError naming the first that is not)."""
    from fpscan.service.recon.dataset import GridDataset, PointDataset, check_dataset

    if isinstance(dataset, GridDataset):
        check_dataset(dataset)
    elif isinstance(dataset, PointDataset):
        check_dataset(dataset)
    else:
        raise ValueError(f"a reconstruction's input is a GridDataset or PointDataset "
                         f"(fpscan.load_dataset reads one from a file), got {type(dataset).__name__}")


def _finite_image(p0: np.ndarray, dataset: Any) -> None:
    """A ValueError where a method's p0 holds NaN or an infinity (its input was checked finite: the
    samples overflowed the working precision, which the message states with their peak)."""
    from fpscan.service.recon.checks import finite_array

    try:
        finite_array("p0", p0, (np.ndim(p0),))
    except ValueError:
        samples = dataset.data if hasattr(dataset, "data") else dataset.alines
        peak = float(np.max(np.abs(samples)))
        kind = np.dtype(p0.dtype) if np.dtype(p0.dtype).kind == "f" else np.dtype(np.float32)
        raise ValueError(f"p0 holds NaN or infinite values: the samples reach {peak:.3g}, and {kind} holds at most "
                         f"{float(np.finfo(kind).max):.3g}; rescale the samples or reconstruct with dtype "
                         "float64") from None


def _shift_lateral(result: Reconstruction, shift: tuple[float, ...] | None) -> None:
    """Put the image on the data's own lateral coordinates: add ``shift`` ((x,) or (x, y), m;
    ``dataset.lateral_shift``: the file's sensor coordinates or k-Wave's grid origin minus the
    centred axes the methods reconstruct on) to ``result.x``/``result.y``, recorded as
    ``params["lateral_shift_m"]``. The image itself is unchanged (the inversion is
    shift-invariant); nothing happens where ``shift`` is None or zero."""
    if not shift or not any(shift):
        return
    result.x = np.asarray(result.x, dtype=np.float64) + float(shift[0])
    if result.y is not None and len(shift) > 1:
        result.y = np.asarray(result.y, dtype=np.float64) + float(shift[1])
    result.params["lateral_shift_m"] = [float(v) for v in shift]


def run_file(inputs: str | os.PathLike | Sequence[str | os.PathLike],
             out_dir: str | os.PathLike | Callable[[str], str | os.PathLike],
             method: str | None = None, *, format: str | None = None, wavelength: int | str | None = None,
             wavelengths: Sequence[float] | None = None, unmix: dict | None = None, load: dict | None = None,
             input_id: str = "", progress: Progress | None = None, should_stop: ShouldStop | None = None,
             on_loaded: Callable[[Dataset, str], Any] | None = None, plan: Plan | Mask | dict | None = None,
             options: dict | MethodOptions | None = None, **given: Any) -> dict:
    """Read a file, reconstruct it and write its result folder: the one orchestration of the job
    worker (``fpscan.service.jobs.work``), ``fpscan recon`` and ``fpscan unmix`` (locally), so that a
    file gives the same folder whoever runs it.

    Three shapes of work, by the arguments:

    - one volume (default): the file read at ``wavelength`` (an index; None: the first) with
      ``fpscan.service.storage.loader.load_wavelengths``, reconstructed by :func:`reconstruct`,
      written by ``fpscan.service.storage.results.write_result`` (``volume.h5`` + MIPs);
    - every wavelength (``wavelength="all"``): one volume each, same method and options
      (``fpscan.service.spectral.reconstruct_wavelengths``), written by
      ``fpscan.service.spectral.write_wavelength_results`` (the first at the top, ``wavelength_<k>/``);
    - unmixing (``unmix`` given: ``threshold``, ``fluence``): every wavelength of one
      multi-wavelength scan file, or of one file per wavelength (``inputs`` a list, with
      ``wavelengths``), reconstructed and unmixed (``fpscan.service.spectral.reconstruct_and_unmix``:
      ``unmix.h5``, ``so2.png`` and one folder per wavelength).

    Parameters
    ----------
    inputs : path or sequence of paths
        The file; several only with ``unmix`` (one per wavelength).
    out_dir : path or callable
        The result folder (an existing one is replaced), or ``out_dir(method) -> path`` of the
        method chosen (``fpscan recon``'s default ``<input>-<method>/``).
    method : str, optional
        A key of :data:`METHODS`; None: :func:`default_method` of the data as loaded.
    format : str, optional
        The inputs' format (``fpscan.service.formats``); None: detected from the content.
    wavelength : int or "all", optional
        Of a multi-wavelength file (not with ``unmix``).
    wavelengths : sequence of float, optional
        m, one per input with ``unmix`` (default: what each file records).
    unmix : dict, optional
        ``{"threshold": THb fraction in [0, 1), "fluence": J/m² per wavelength or None}``.
    load : dict, optional
        The format's load options (``dt`` s, ``dx``, ``dy`` m, ``key``, ``sound_speed`` m/s, ``force``).
    input_id : str, optional
        Recorded in the result (the dataset id, the file's name).
    progress : callable, optional
        ``progress(fraction, stage)``: ``"loading"`` at 0, the reconstruction's own stages
        on [0.2, 0.9] (unmixing: [0.2, 0.95]), ``"writing"`` at 0.9, ``"done"`` at 1; the
        fraction and the stage only move forward (``fpscan.service.progress.Forward``).
    should_stop : callable, optional
        As :func:`reconstruct`.
    on_loaded : callable, optional
        ``on_loaded(dataset, method)`` after loading, before any reconstruction (the first
        wavelength's dataset and the method chosen): the server's memory admission raises
        there to refuse the work; the command line says what it reconstructs.
    plan : fpscan.service.plans.Plan, fpscan.service.plans.Mask or dict, optional
        Dense input sampled by this plan's (or mask's, or plan document's: ``fpscan.load_plan``) sensor points before reconstructing
        (``fpscan.service.subsample.subsample``: a replay scan's A-lines); not with ``unmix``.
    options : dict or MethodOptions, optional
        The method's options, as :func:`reconstruct` (its own model's instance, e.g. a job record's;
        or a dict); checked before the input is read where ``method`` is given.
    **given
        The method's options as keywords (``sound_speed`` in m/s or ``"auto"``, ``force``, ...).

    Returns
    -------
    dict
        ``method``, ``shape``, ``max``, ``planes``, ``params_used``, ``sound_speed`` (m/s), ``timings``
        (``load_s``, ``reconstruct_s``, ``write_s``; unmixing also ``unmix_s``), and where they
        apply ``autofocus``, ``points_used``, ``outcome`` (an iterative method's one line on
        how it ended, ``fpscan.service.progress.outcome``), ``wavelengths`` (a row per wavelength:
        ``index``, ``nm``, ``shape``, ``max``), ``unmix``, ``so2_median``, ``masked_fraction``.

    Raises
    ------
    ValueError
        What loading, :func:`reconstruct`, ``on_loaded`` or the writers refuse (with the reason).
    Cancelled
        When ``should_stop()`` returned True.
    FileNotFoundError
        A missing input.

    Examples
    --------
    A laterally uniform layer on an 8-sensor line, saved as a NumPy array in k-Wave's layout
    ``(n_t, n_x)``; the method defaults to the data's (``ner`` for grid data):

    >>> import tempfile
    >>> from pathlib import Path
    >>> import numpy as np
    >>> from fpscan.service.pipeline import run_file
    >>> tmp = Path(tempfile.mkdtemp())
    >>> g = np.zeros((64, 8))
    >>> g[10] = 0.5
    >>> np.save(tmp / "line.npy", g)
    >>> s = run_file(tmp / "line.npy", tmp / "out", load={"dt": 1e-4 / 1500, "dx": 1e-4})  # s, m
    >>> s["method"], s["shape"], sorted(p.name for p in (tmp / "out").iterdir())
    ('ner', [64, 8], ['mip_xz.png', 'volume.h5'])
    """
    import time

    from fpscan.service.recon.methods import outcome

    paths = [inputs] if isinstance(inputs, str | os.PathLike) else list(inputs)
    progress = forward(progress)  # the job's fraction and stage only move forward (fpscan.service.progress.Forward)
    load = {k: v for k, v in (load or {}).items() if v is not None}
    opts = None if method is None else method_options(method, options, **given)  # refused before any reading
    if unmix is not None:
        from fpscan.service.recon.unmix import check_unmix_options

        check_unmix_options(unmix.get("threshold", 0.1), unmix.get("fluence"))
    t0 = time.perf_counter()
    if progress is not None:
        progress(0.0, "loading")
    wl, datasets = _load_inputs(paths, format, unmix is not None, wavelength, wavelengths, load, plan)
    if unmix is not None:  # the fluences against the wavelengths found, before any is reconstructed
        check_unmix_options(unmix.get("threshold", 0.1), unmix.get("fluence"), len(datasets))
    method = method or default_method(datasets[0])
    if opts is None:
        opts = method_options(method, options, **given)
    if on_loaded is not None:
        on_loaded(datasets[0], method)
    if callable(out_dir):
        out_dir = out_dir(method)
    t1 = time.perf_counter()
    run = span(progress, 0.2, 0.95 if unmix is not None else 0.9)
    if unmix is not None:
        from fpscan.service.spectral import reconstruct_and_unmix

        summary = reconstruct_and_unmix(out_dir, datasets, wl, method, input_id=input_id,
                                        threshold=float(unmix.get("threshold", 0.1)), fluence=unmix.get("fluence"),
                                        progress=run, should_stop=should_stop, reconstruct=reconstruct, options=opts)
        summary["timings"]["load_s"] = t1 - t0
        summary["unmix"]["threshold"] = float(unmix.get("threshold", 0.1))
        first = summary["params"]
    else:
        if wavelength == "all":
            from fpscan.service.spectral import reconstruct_wavelengths, write_wavelength_results

            recons = reconstruct_wavelengths(datasets, method, reconstruct=reconstruct, progress=run,
                                             should_stop=should_stop, options=opts)
        else:
            recons = [reconstruct(datasets[0], method, opts, progress=run, should_stop=should_stop)]
        t2 = time.perf_counter()
        if progress is not None:
            progress(0.9, "writing")
        if wavelength == "all":
            summary = write_wavelength_results(out_dir, recons, input_id=input_id)
        else:
            from fpscan.service.storage.results import write_result

            summary = write_result(out_dir, recons[0], input_id=input_id)
        summary["timings"] = {"load_s": t1 - t0, "reconstruct_s": t2 - t1, "write_s": time.perf_counter() - t2}
        first = recons[0].params
        summary["sound_speed"] = first.get("sound_speed")
    summary["method"] = method
    if "autofocus" in first:
        summary["autofocus"] = first["autofocus"]
    if datasets[0].kind == "points":
        summary["points_used"] = int(datasets[0].alines.shape[0])
    ended = outcome(first, method)
    if ended:
        summary["outcome"] = ended
    if progress is not None:
        progress(1.0, "done")
    return summary
