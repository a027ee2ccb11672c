"""The method registry: the :class:`Method` record, the vocabulary :data:`METHODS`,
:func:`register`, :func:`get` and :func:`default_for` (the package ``fpscan.service.recon.methods``
re-exports them and fills :data:`METHODS` from the entry points of ``fpscan.methods``).

Importing this module needs no numpy.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from pydantic import ValidationError

from fpscan.service.plugins import put_in_order
from fpscan.service.progress import Shown
from fpscan.service.progress import outcome as outcome_line
from fpscan.service.recon.methods.options import MethodOptions
from fpscan.service.recon.methods.work import PLANAR_WORK_RATE, peak_model, planar_work

__all__ = ["Method", "Runner", "METHODS", "register", "get", "default_for", "INPUT_KINDS", "describe_error", "outcome",
           "estimate_peak_memory"]

#: ``run(dataset, c, options, progress)`` -> ``Reconstruction`` (the package's docstring)
Runner = Callable[..., Any]


@dataclass(frozen=True)
class Method:
    """One reconstruction method.

    Parameters
    ----------
    name, title, needs_grid, options_model, run, source, peak_memory, order, work, ...
        As the attributes below.

    Attributes
    ----------
    name : str
        The word users type (``--method``, the API's ``method``).
    title : str
        One line for lists (web page, ``--help``).
    needs_grid : bool
        True when it needs data on a full regular grid (a full lattice).
    options_model : type
        Its options (a :class:`MethodOptions` subclass: type, range, unit and default of
        each; ``c``, the speed of sound in m/s, is every method's and not in it).
    run : callable
        ``run(dataset, c, options, progress)`` -> ``Reconstruction`` (module docstring).
    source : str
        Where the algorithm comes from.
    peak_memory : callable or None
        ``peak_memory(n_t, n_x, n_y, *, n_z, upsample, dtype, n_points, dx, dt, c, dz, t0,
        options, record_facts, bandwidth, **_)`` ->
        bytes at its peak (the memory admission, ``fpscan.service.jobs.admission``; a model of
        ``fpscan.service.recon.memory``, :func:`peak_model`); None (default): NER's,
        ``fpscan.service.recon.memory.planar_peak``.
    order : int
        Position in lists (smaller first).
    work : callable or None
        ``work(n_t, n_x, n_y, *, n_z, upsample, dtype, n_points, dx, dt, c, t0, options,
        record_facts, bandwidth, **_)`` ->
        seconds on the reference 2 cores (:data:`FLOAT64_WORK`; the work admission,
        ``fpscan.service.jobs.admission.estimate_work``); it may raise ``OptionError`` for options
        the input cannot carry (tv: an image deeper than the record can hear). None
        (default): :func:`planar_work` at :data:`PLANAR_WORK_RATE`.
    iterative : bool
        An iterative solver (seconds to hours): ``c = "auto"`` searches the sound speed with the
        default direct method of the input (:func:`default_for`) and then runs it once.
    time_limited : bool
        It takes a ``time_limit`` option (s) that the server's ``time_limit_s`` setting caps (its
        default, and the most a request may ask).
    cancellable : bool
        Its run reports progress between steps or iterations (``progress``), each a point where a
        cancel or stop request (``should_stop``) ends it within a step.
    default_for : tuple of str
        The inputs it is the default method for: ``"grid"`` (a full lattice), ``"points"`` (any
        sensor mask); :func:`default_for`.
    warm_up : callable or None
        ``warm_up(dtypes)``: compile (or load from numba's cache) its kernels on tiny data in
        each dtype name of ``dtypes`` (``fpscan.service.recon.warmup.warm_up``, ``fpscan warmup``, a job
        worker before its first job); None: nothing of its own to warm.
    kernel_modules : tuple of str
        The modules holding its numba kernels (``fpscan.service.recon.warmup.cache_dirs``).
    warm_in_background : bool
        Its warm-up is slow (pylops' import: seconds): a job worker runs it in the background
        after it is ready for jobs (``fpscan.service.jobs.work.warm_up``).
    memory_calibration : float
        Its admission class: the factor the memory admission applies to :attr:`peak_memory`
        (``fpscan.service.jobs.admission.estimate_memory``; 1 for a model measured within its margin).
    holds_input : bool
        It keeps the input as loaded beside its working copy (the memory admission counts it even
        in the working precision).
    summary : tuple of fpscan.service.progress.Shown
        The fields of its result's parameters it shows after its outcome, in order: the CLI's
        and the notebook's line (:func:`outcome`) and the web page's summary rows (``GET
        /api/reconstructions/methods``); tv: λ ("(automatic)" / "(given)") and the residual.
    stop_waits_for : str
        What its stopping rule waits for while it is not armed (an ``IterationStage`` with
        ``armed=False``), in words the progress line ends on after "once" (tv: ``"λ has
        settled"``; ``fpscan.service.progress.describe_iteration``); "" for none.
    options : tuple of str
        The option names it takes: ``c`` and its model's fields.
    defaults : dict
        Its options' defaults (those that are values; ``None``: derived from the data).

    Examples
    --------
    >>> from fpscan.service.recon.methods import get
    >>> m = get("nedner")
    >>> m.name, m.needs_grid, m.options
    ('nedner', False, ('c', 'eps', 'dtype', 'upsample', 'positivity', 'n_z', 'dz', 'device'))
    >>> m.defaults
    {'eps': 1e-06, 'dtype': 'float32', 'upsample': 1, 'positivity': False, 'device': 'auto'}
    >>> m.check({"upsample": 2, "dz": "2e-5"}).dz  # m
    2e-05
    >>> m.check({"eps": 5e-15})
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: eps must be in [1e-14, 1e-1], got 5e-15
    >>> m.memory(64, 8) > 0  # bytes
    True
    """

    name: str
    title: str
    needs_grid: bool
    options_model: type[MethodOptions]
    run: Runner
    source: str = ""
    peak_memory: Callable[..., int] | None = None
    order: int = 100
    work: Callable[..., float] | None = None
    iterative: bool = False
    time_limited: bool = False
    cancellable: bool = True
    default_for: tuple[str, ...] = ()
    warm_up: Callable[[Sequence[str]], None] | None = None
    kernel_modules: tuple[str, ...] = ()
    warm_in_background: bool = False
    memory_calibration: float = 1.0
    holds_input: bool = False
    summary: tuple[Shown, ...] = ()
    stop_waits_for: str = ""

    @property
    def options(self) -> tuple[str, ...]:
        """The option names it takes: ``c`` and its model's fields."""
        return ("c", *self.options_model.model_fields)

    @property
    def defaults(self) -> dict[str, Any]:
        """Its options' defaults (those that are values; ``None``: derived from the data)."""
        return {k: f.default for k, f in self.options_model.model_fields.items() if f.default is not None}

    def check(self, options: dict) -> MethodOptions:
        """``options`` (names of its model; ``None`` = the default) validated by its model;
        raises ``fpscan.service.recon.checks.OptionError`` (a ValueError) with the first refusal,
        in the kernel rule's words (``eps must be in [1e-14, 1e-1], got 5e-15``).

        Examples
        --------
        >>> from fpscan.service.recon.methods import get
        >>> get("ner").check({"upsample": 2.0, "positivity": None}).model_dump()
        {'eps': 1e-06, 'dtype': 'float32', 'upsample': 2, 'positivity': False, 'n_z': None, 'dz': None, 'device': 'auto'}
        >>> get("ner").check({"lam": 0.1})
        Traceback (most recent call last):
        ...
        fpscan.service.recon.checks.OptionError: unknown option lam
        """
        try:
            return self.options_model.model_validate(options)
        except ValidationError as exc:
            from fpscan.service.recon.checks import OptionError

            raise OptionError(describe_error(exc)) from None

    def upsample(self, options: dict) -> int:
        """The lateral upsampling factor of its image for the request's ``options``: their
        ``upsample`` where it takes that option (the planar methods), else 1.

        Examples
        --------
        >>> from fpscan.service.recon.methods import get
        >>> get("ner").upsample({"upsample": 2}), get("kwave").upsample({"upsample": 2}), get("ner").upsample({})
        (2, 1, 1)
        """
        return int(options.get("upsample", 1) or 1) if "upsample" in self.options else 1

    def memory(self, n_t: int, n_x: int, n_y: int = 1, **kw: Any) -> int:
        """Peak bytes (:attr:`peak_memory`)."""
        return (self.peak_memory or peak_model("planar_peak"))(n_t, n_x, n_y, **kw)

    def estimate_work(self, n_t: int, n_x: int, n_y: int = 1, **kw: Any) -> float:
        """Seconds of work on the reference 2 cores (:attr:`work`)."""
        return float((self.work or planar_work(PLANAR_WORK_RATE))(n_t, n_x, n_y, **kw))


def describe_error(exc: ValidationError) -> str:
    """The first error of ``exc`` as one line naming the option (the rule's own words).

    Parameters
    ----------
    exc : pydantic.ValidationError
        A refusal of a method's options model.

    Returns
    -------
    str
        The kernel rule's message (``"eps must be in [1e-14, 1e-1], got 5e-15"``), else
        ``"<option>: <pydantic's message>"``, or ``"unknown option <name>"``.

    Examples
    --------
    >>> from pydantic import BaseModel, ValidationError
    >>> from fpscan.service.recon.methods import describe_error, get
    >>> for bad in ({"upsample": 9}, {"frobnicate": 1}):
    ...     try:
    ...         get("ner").options_model.model_validate(bad)
    ...     except ValidationError as exc:
    ...         print(describe_error(exc))
    upsample must be an integer in 1..8, got 9
    unknown option frobnicate
    """
    err = exc.errors()[0]
    name = ".".join(str(p) for p in err["loc"]) or "options"
    msg = str(err["msg"]).removeprefix("Value error, ")
    if err["type"] == "extra_forbidden":
        return f"unknown option {name}"
    return msg if msg.startswith(name) else f"{name}: {msg}"


#: the method vocabulary (name -> Method), in the order lists show it
METHODS: dict[str, Method] = {}


def register(method: Method) -> Method:
    """Add ``method`` to :data:`METHODS` (kept in ``order``). Raises ValueError when an
    option it shares with a registered method has another type or range there (the
    generated HTTP model and CLI flag hold one rule per option name).

    Parameters
    ----------
    method : Method
        The method; one of the same name is replaced.

    Returns
    -------
    Method
        ``method`` itself (a method module keeps it as ``METHOD``).

    Raises
    ------
    ValueError
        ``options_model`` is not a :class:`MethodOptions` subclass, or an option it shares
        with a registered method has another type or range there.

    Examples
    --------
    A toy method (then removed, leaving the registry as it was):

    >>> from pydantic import Field
    >>> from fpscan.service.recon.methods import METHODS, Method, MethodOptions, register
    >>> class ToyOptions(MethodOptions):
    ...     pass
    >>> toy = register(Method("toy", "a toy", False, ToyOptions, run=print, order=1000))
    >>> list(METHODS)[-1], toy.options
    ('toy', ('c', 'dtype'))
    >>> del METHODS["toy"]

    An option named like another method's must keep its rule:

    >>> class Clash(MethodOptions):
    ...     eps: float = Field(1e-3, ge=0.0)
    >>> register(Method("clash", "a clash", False, Clash, run=print))
    Traceback (most recent call last):
    ...
    ValueError: method 'clash': option eps differs from method 'nedner''s (...): one rule per option name
    >>> "clash" in METHODS
    False
    """
    if not (isinstance(method.options_model, type) and issubclass(method.options_model, MethodOptions)):
        raise ValueError(f"method {method.name!r}: options_model must be a MethodOptions subclass")
    others = {n: m for n, m in METHODS.items() if n != method.name}
    mine = _rules(method.options_model)
    for other in others.values():
        theirs = _rules(other.options_model)
        for name in set(mine) & set(theirs):
            if mine[name] != theirs[name]:
                raise ValueError(f"method {method.name!r}: option {name} differs from method {other.name!r}'s "
                                 f"({mine[name]} vs {theirs[name]}): one rule per option name")
    put_in_order(METHODS, method.name, method, lambda m: m.order)
    return method


def get(name: str) -> Method:
    """The method called ``name``; ``OptionError`` (a ValueError) listing them otherwise.

    Parameters
    ----------
    name : str
        A key of :data:`METHODS`.

    Returns
    -------
    Method

    Raises
    ------
    fpscan.service.recon.checks.OptionError
        No method of that name; the message lists the methods.

    Examples
    --------
    >>> from fpscan.service.recon.methods import get
    >>> get("kwave").title
    'k-Wave compatible (kspaceLineRecon / kspacePlaneRecon)'
    >>> get("fbp")
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: method must be one of nedner, ner, ..., got 'fbp'
    """
    spec = METHODS.get(name)
    if spec is None:
        from fpscan.service.recon.checks import OptionError

        raise OptionError(f"method must be one of {', '.join(METHODS)}, got {name!r}")
    return spec


#: the kinds of input a method may be the default for (:attr:`Method.default_for`)
INPUT_KINDS = ("grid", "points")


def default_for(kind: str) -> str:
    """The default method for an input of ``kind``: the first registered method (in list order)
    that declares it in :attr:`Method.default_for`.

    Parameters
    ----------
    kind : {"grid", "points"}
        ``"grid"``: A-lines on a full regular lattice; ``"points"``: A-lines at any sensor points
        (a sensor mask).

    Returns
    -------
    str
        The method's name.

    Raises
    ------
    ValueError
        An unknown ``kind``, or no registered method is the default for it.

    Examples
    --------
    >>> from fpscan.service.recon.methods import default_for
    >>> default_for("grid"), default_for("points")
    ('ner', 'nedner')
    """
    if kind not in INPUT_KINDS:
        raise ValueError(f"kind must be one of {INPUT_KINDS}, got {kind!r}")
    for method in METHODS.values():
        if kind in method.default_for:
            return method.name
    raise ValueError(f"no registered method is the default for {kind} input")


def _rules(model: type[MethodOptions]) -> dict[str, str]:
    """Each field's rule, as its JSON schema without default/description/title."""
    out = {}
    for name, schema in model.model_json_schema()["properties"].items():
        out[name] = repr({k: v for k, v in sorted(schema.items()) if k not in ("default", "description", "title")})
    return out


def outcome(params: dict, method: str | None = None) -> str | None:
    """One line on how an iterative reconstruction ended (:func:`fpscan.service.progress.outcome`),
    with the fields its method declares (:attr:`Method.summary`).

    Parameters
    ----------
    params : dict
        The reconstruction's parameters (a ``Reconstruction``'s, or a result's
        ``params_used``).
    method : str, optional
        The method's name (default ``params["method"]``); an unregistered one shows no
        fields of its own.

    Returns
    -------
    str or None
        The line; None for a method without iterations.

    Examples
    --------
    >>> from fpscan.service.recon.methods import outcome
    >>> outcome({"method": "tv", "converged": True, "stop_reason": "converged", "iterations": 37,
    ...          "max_iter": 100, "iterate_change": 0.0041, "tol": 0.005, "lam": 0.0123, "lam_auto": True,
    ...          "residual": 0.031, "noise_share": 0.030})
    'tv: converged after 37 iterations (image change 0.0041 < 0.005); λ 0.0123 (automatic); residual 3.1 % of the data, noise 3.0 %'
    >>> outcome({"method": "ner"}) is None
    True
    """
    spec = METHODS.get(str(method or params.get("method") or ""))
    return outcome_line(params, method, spec.summary if spec is not None else ())


def estimate_peak_memory(n_t: int, n_x: int, n_y: int = 1, *, method: str | None = None, **kw: Any) -> int:
    """Estimated peak memory in bytes of a reconstruction by ``method``: the method's own model
    (``fpscan.service.recon.methods.get(method).memory``).

    Parameters
    ----------
    n_t : int
        Samples per A-line.
    n_x, n_y : int
        Lateral grid (``n_y = 1`` in 2-D).
    method : str, optional
        A registered method (``fpscan.service.recon.methods.METHODS``); None: the default for a
        full lattice (``fpscan.service.recon.methods.default_for("grid")``).
    **kw
        The model's keywords: ``n_z`` (output depth samples), ``upsample``, ``dtype``
        (float32/float64), ``n_points`` (sensors of point data), ``dx`` (m), ``dt`` (s), ``c``
        (m/s), ``dz`` (m), ``square`` (dy = dx; None unknown).

    Returns
    -------
    int
        Bytes at the peak.

    Raises
    ------
    fpscan.service.recon.checks.OptionError
        An unknown method.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon import estimate_peak_memory
    >>> est = estimate_peak_memory(256, 64, 64)  # (n_t, n_y, n_x) = (256, 64, 64), float64 NER
    >>> est > 256 * 64 * 64 * 8  # more than the input
    True
    >>> estimate_peak_memory(256, 64, 64, dtype=np.float32) < est
    True
    """
    return get(method or default_for("grid")).memory(n_t, n_x, n_y, **kw)
