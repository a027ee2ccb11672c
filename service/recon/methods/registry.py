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

from fpscan.service.plugins import PluginRegistry, put_in_order
from fpscan.service.progress import Shown
from fpscan.service.progress import outcome as outcome_line
from fpscan.service.recon.methods.options import DEPRECATED_NAMES, MethodOptions, SpeedOptions
from fpscan.service.recon.methods.work import undeclared_peak, undeclared_work

__all__ = ["Method", "Runner", "METHODS", "register", "get", "default_for", "INPUT_KINDS", "describe_error", "outcome",
           "estimate_peak_memory"]

#: ``run(dataset, sound_speed, options, progress)`` -> ``Reconstruction`` (the package's docstring)
Runner = Callable[..., Any]


@dataclass(frozen=True, kw_only=True)
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
        each; the speed of sound, ``sound_speed``, is every method's).
    run : callable
        ``run(dataset, sound_speed, options, progress)`` -> ``Reconstruction``: ``sound_speed``
        the speed of sound resolved to m/s, ``options`` an instance of ``options_model``
        (the package's docstring).
    source : str
        Where the algorithm comes from.
    peak_memory : callable or None
        ``peak_memory(n_t, n_x, n_y, *, n_z, upsample, dtype, n_points, dx, dt, c, dz, t0,
        options, record_facts, bandwidth, **_)`` ->
        bytes at its peak (the memory admission, ``fpscan.service.jobs.admission``; a model of
        ``fpscan.service.recon.memory``, :func:`peak_model`); None (default, a method that
        declares none): the conservative rule
        ``fpscan.service.recon.methods.work.undeclared_peak`` (never another method's model).
    order : int
        Position in lists (smaller first).
    work : callable or None
        ``work(n_t, n_x, n_y, *, n_z, upsample, dtype, n_points, dx, dt, c, t0, options,
        record_facts, bandwidth, **_)`` ->
        seconds on the reference 2 cores (:data:`FLOAT64_WORK`; the work admission,
        ``fpscan.service.jobs.admission.estimate_work``); it may raise ``OptionError`` for options
        the input cannot carry (tv: an image deeper than the record can hear). None
        (default, a method that declares none): the conservative rule
        ``fpscan.service.recon.methods.work.undeclared_work``.
    iterative : bool
        An iterative solver (seconds to hours): ``sound_speed="auto"`` searches the speed with the
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
        The option names it takes: its model's fields.
    defaults : dict
        Its options' defaults (those that are values; ``None``: derived from the data).

    Examples
    --------
    >>> from fpscan.service.recon.methods import get
    >>> m = get("nedner")
    >>> m.name, m.needs_grid, m.options
    ('nedner', False, ('sound_speed', 'sound_speed_range', 'force', 'eps', 'dtype', 'upsample', 'positivity', 'n_z', 'dz', 'device'))
    >>> m.defaults
    {'eps': 1e-06, 'force': False, 'dtype': 'float32', 'upsample': 1, 'positivity': False, 'device': 'auto'}
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

    def __repr__(self) -> str:
        """One line: the name, title, what input it needs and what it is (never its callables).

        Examples
        --------
        >>> from fpscan.service.recon.methods import METHODS
        >>> METHODS["ner"]
        Method(ner: 'NER-NUFFT (full regular grid)', needs a full grid, options: sound_speed, ...)
        """
        from fpscan.wire.brief import one_line

        kind = "iterative" if self.iterative else ("needs a full grid" if self.needs_grid else "any sensor mask")
        source = f", from {self.source}" if self.source and self.source != "builtin" else ""
        shown = ", ".join(self.options[:1]) + (", ..." if len(self.options) > 1 else "")
        return one_line(f"Method({self.name}: {self.title!r}, {kind}, options: {shown or 'none'}{source})")

    @property
    def options(self) -> tuple[str, ...]:
        """The option names it takes: its model's fields, the speed of sound's first."""
        fields = tuple(self.options_model.model_fields)
        speed = tuple(SpeedOptions.model_fields)
        return (*speed, *(f for f in fields if f not in speed))

    @property
    def defaults(self) -> dict[str, Any]:
        """Its options' defaults (those that are values; ``None``: derived from the data)."""
        return {k: f.default for k, f in self.options_model.model_fields.items() if f.default is not None}

    def check(self, options: dict | MethodOptions | None = None, /, **given: Any) -> MethodOptions:
        """Its options validated by its model: the one validation of a request's options at every
        door (the library's :func:`fpscan.service.pipeline.reconstruct`, ``fpscan recon`` and
        ``POST /api/reconstructions``); the result is what a job's record holds and the method's
        ``run`` receives.

        Parameters
        ----------
        options : dict or MethodOptions, optional
            Option name -> value (SI units, or text with a unit for a length, time or speed;
            ``None`` = the default); an instance of :attr:`options_model` is returned as is.
        **given
            More options (the library's keywords).

        Returns
        -------
        MethodOptions
            An instance of :attr:`options_model`, every field filled.

        Raises
        ------
        fpscan.service.recon.checks.OptionError
            (a ValueError) The first refusal, in the kernel rule's words (``eps must be in
            [1e-14, 1e-1], got 5e-15``); an option of another method (naming this one's); a
            name no method takes; ``sound_speed="auto"`` for a method that cannot search it
            (it takes no depth grid, ``dz`` and ``n_z``, and is not iterative); another
            method's options instance.

        Examples
        --------
        >>> from fpscan.service.recon.methods import get
        >>> get("ner").check({"upsample": 2.0, "positivity": None}, sound_speed=1480).model_dump(exclude_defaults=True)
        {'sound_speed': 1480.0, 'upsample': 2}
        >>> get("ner").check({"lam": 0.1})
        Traceback (most recent call last):
        ...
        fpscan.service.recon.checks.OptionError: method 'ner' takes no option lam (its options: sound_speed, sound_speed_range, force, eps, ...)
        """
        from fpscan.service.recon.checks import OptionError

        if isinstance(options, MethodOptions):
            if given or not isinstance(options, self.options_model):
                raise OptionError(f"method {self.name!r} takes its own options ({self.options_model.__name__}), "
                                  f"got {type(options).__name__}{' and keywords' if given else ''}")
            return options
        data = {**(options or {}), **given}
        self.refuse_foreign(data)
        try:
            checked = self.options_model.model_validate(data)
        except ValidationError as exc:
            err = exc.errors()[0]
            original = (err.get("ctx") or {}).get("error")
            if not err["loc"] and isinstance(original, ValueError):  # a rule across fields, as it was raised
                raise original from None
            raise OptionError(describe_error(exc)) from None
        self.refuse_search(checked)
        return checked

    def refuse_search(self, options: MethodOptions) -> None:
        """Refuse ``sound_speed="auto"`` where this method cannot search the speed of sound: the
        search reconstructs every speed tried on one depth grid (``dz``, ``n_z``), which a direct
        method must take (an iterative one searches with the input's default direct method).

        Parameters
        ----------
        options : MethodOptions
            Its validated options.

        Raises
        ------
        fpscan.service.recon.checks.OptionError
            ``"auto"`` for a method that cannot search.

        Examples
        --------
        >>> from fpscan.service.recon.methods import get
        >>> get("kwave").refuse_search(get("kwave").options_model(sound_speed="auto"))
        Traceback (most recent call last):
        ...
        fpscan.service.recon.checks.OptionError: method 'kwave' cannot search the speed of sound (sound_speed 'auto'): ...
        """
        if options.sound_speed == "auto" and not self.iterative and not {"dz", "n_z"} <= set(self.options):
            from fpscan.service.recon.checks import OptionError

            raise OptionError(f"method {self.name!r} cannot search the speed of sound (sound_speed 'auto'): the "
                              "search reconstructs every speed tried on one depth grid (dz, n_z), which it does not "
                              f"take; give the speed of sound in m/s, or search with {default_for('grid')} first")

    def refuse_foreign(self, options: dict) -> None:
        """Refuse an option of another method (an option that would do nothing is never silently
        dropped), naming this method's options.

        Parameters
        ----------
        options : dict
            Option name -> value; ``None`` values pass (the default).

        Raises
        ------
        fpscan.service.recon.checks.OptionError
            A name another registered method takes and this one does not; more names than all
            registered methods take together, earlier names included (at once, so that a body of
            thousands of unknown names is not refused name by name, a validation error each).

        Examples
        --------
        >>> from fpscan.service.recon.methods import get
        >>> get("tv").refuse_foreign({"lam": 0.1, "upsample": None})
        >>> get("ner").refuse_foreign({"lam": 0.1})
        Traceback (most recent call last):
        ...
        fpscan.service.recon.checks.OptionError: method 'ner' takes no option lam (its options: sound_speed, sound_speed_range, force, eps, ...)
        >>> get("kwave").refuse_foreign({f"opt{i}": i for i in range(5000)})
        Traceback (most recent call last):
        ...
        fpscan.service.recon.checks.OptionError: method 'kwave' takes no option 'opt0', 'opt1', 'opt2', ...: 5000 names no method takes (its options: ...)
        """
        mine = set(self.options)
        known = {name for m in METHODS.values() for name in m.options}  # once: a body may hold thousands of names
        foreign = sorted(k for k, v in options.items() if v is not None and DEPRECATED_NAMES.get(k, k) not in mine
                         and DEPRECATED_NAMES.get(k, k) in known)
        if foreign:
            from fpscan.service.recon.checks import OptionError

            raise OptionError(f"method {self.name!r} takes no option {', '.join(foreign)} "
                              f"(its options: {', '.join(self.options)})")
        if len(options) > len(known) + len(DEPRECATED_NAMES):  # more than every method's names (None values
            # included: a default): names no method takes, refused at once rather than one validation error each
            from fpscan.service.recon.checks import OptionError

            unknown = [k for k in options if DEPRECATED_NAMES.get(k, k) not in known]
            named = ", ".join(repr(k)[:40] for k in unknown[:3])
            raise OptionError(f"method {self.name!r} takes no option {named}{', ...' if len(unknown) > 3 else ''}: "
                              f"{len(unknown)} names no method takes (its options: {', '.join(self.options)})")

    def upsample(self, options: dict | MethodOptions) -> int:
        """The lateral upsampling factor of its image for the request's ``options``: their
        ``upsample`` where it takes that option (the planar methods), else 1.

        Examples
        --------
        >>> from fpscan.service.recon.methods import get
        >>> get("ner").upsample({"upsample": 2}), get("kwave").upsample({"upsample": 2}), get("ner").upsample({})
        (2, 1, 1)
        """
        value = getattr(options, "upsample", None) if isinstance(options, MethodOptions) else options.get("upsample")
        return int(value or 1) if "upsample" in self.options else 1

    def memory(self, n_t: int, n_x: int, n_y: int = 1, **kw: Any) -> int:
        """Peak bytes (:attr:`peak_memory`)."""
        return (self.peak_memory or undeclared_peak)(n_t, n_x, n_y, **kw)

    def estimate_work(self, n_t: int, n_x: int, n_y: int = 1, **kw: Any) -> float:
        """Seconds of work on the reference 2 cores (:attr:`work`)."""
        return float((self.work or undeclared_work)(n_t, n_x, n_y, **kw))


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
    name = ".".join(str(p) for p in err["loc"])
    msg = str(err["msg"]).removeprefix("Value error, ")
    if not name:  # a rule across fields says what it checks
        return msg
    if err["type"] == "extra_forbidden":
        return f"unknown option {name}"
    return msg if msg.startswith(name) else f"{name}: {msg}"


#: the method vocabulary (name -> Method), in the order lists show it: fpscan's own, registered in
#: code, and the plugins' (entry points of ``fpscan.methods``, read on the first lookup or listing)
METHODS: PluginRegistry[Method] = PluginRegistry("fpscan.methods")


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
    >>> toy = register(Method(name="toy", title="a toy", needs_grid=False, options_model=ToyOptions, run=print,
    ...                       order=1000))
    >>> list(METHODS)[-1], toy.options
    ('toy', ('sound_speed', 'sound_speed_range', 'force', 'dtype'))
    >>> del METHODS["toy"]

    An option named like another method's must keep its rule:

    >>> class Clash(MethodOptions):
    ...     eps: float = Field(1e-3, ge=0.0)
    >>> register(Method(name="clash", title="a clash", needs_grid=False, options_model=Clash, run=print))
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
    'k-Wave compatible (kspaceLineRecon / kspacePlaneRecon; their own depth grid, n_t rows of c·dt)'
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
    """Each field's rule, as its JSON schema without default/description/title (and ``derived``, the words of
    a method's own default: tv's depth grid)."""
    out = {}
    for name, schema in model.model_json_schema()["properties"].items():
        out[name] = repr({k: v for k, v in sorted(schema.items())
                          if k not in ("default", "description", "title", "derived")})
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
