"""The reconstruction methods: one module per method, one registry.

Each module of this package (``ner``, ``nedner``, ``interp``, ``kwave``, ``tv``, and
whatever comes next) defines its typed options model (a :class:`~.options.MethodOptions`
with each option's type, range, unit and default), its ``run`` (calling the kernels of
:mod:`service.recon`: ``planar``, ``kwave``, ``tv``) and its peak-memory model in a
:class:`Method` (``METHOD``), which is named by an entry point of the group ``fpscan.methods`` (fpscan's own in its
``pyproject.toml``; another package's in its own: a plugin, docs/plugins.md). The package
registers every entry point's method on first import (``service.plugins.load_group``), so a
new method is one new file and its entry point: the dispatch
(:func:`service.pipeline.reconstruct`), the HTTP request model
(``service.api.models.ReconParams``, the union of the methods' options), ``GET
/api/reconstructions/methods`` (each option's JSON schema: the web page's fields), the
flags of ``fpscan recon`` / ``unmix`` and the docs table (:func:`docs_table`) are generated
from :data:`METHODS`.

``run(dataset, c, options, progress)``: ``dataset`` a ``service.recon.dataset.GridDataset``
when the method ``needs_grid``, else a ``PointDataset`` (the pipeline converts); ``c`` in
m/s; ``options`` the validated options as a dict (every field, defaults filled; ``dtype``
a NumPy dtype; ``None`` for "derived from the data", e.g. ``n_z``); ``progress`` a
``service.progress.Span``: ``progress(fraction, stage)`` or a kernel's ``progress(fraction)``
(stage "reconstructing"), fractions in [0, 1]. Returns a ``service.recon.reconstruction.Reconstruction``.

Importing this package needs no numpy (the command line of a client-only install builds its
flags from it); the kernels load when a method runs.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel, ValidationError

from service.plugins import load_group, put_in_order
from service.recon.methods.options import MethodOptions

__all__ = ["Method", "METHODS", "register", "get", "option_schemas", "option_fields", "docs_table",
           "peak_model", "estimate_peak_memory", "default_for", "INPUT_KINDS", "FLOAT64_WORK", "PLANAR_WORK_RATE", "transform_units", "planar_work", "MethodOptions",
           "default_text", "describe_error", "range_text"]

Runner = Callable[..., Any]


def peak_model(model: str, **fixed: Any) -> Callable[..., int]:
    """A method's peak-memory model: the model ``model`` of ``service.recon.memory`` with the
    keywords ``fixed`` (what the method's kernels do), imported on the first call (this package
    loads without numpy).

    Parameters
    ----------
    model : str
        A model of ``service.recon.memory``: ``"planar_peak"``, ``"kwave_peak"``,
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
    >>> from service.recon.memory import planar_peak
    >>> from service.recon.methods import peak_model
    >>> peak = peak_model("planar_peak", temporal="nufft")
    >>> peak(64, 8, dtype="float32") == planar_peak(64, 8, dtype="float32", temporal="nufft")
    True
    >>> peak(256, 64, 64) > peak(64, 8)  # bytes grow with the input
    True
    """
    def peak(n_t: int, n_x: int, n_y: int = 1, **kw: Any) -> int:
        from service.recon import memory

        return int(getattr(memory, model)(n_t, n_x, n_y, **{**kw, **fixed}))

    return peak


def estimate_peak_memory(n_t: int, n_x: int, n_y: int = 1, *, method: str | None = None, **kw: Any) -> int:
    """Estimated peak memory in bytes of a reconstruction by ``method``: the method's own model
    (``service.recon.methods.get(method).memory``).

    Parameters
    ----------
    n_t : int
        Samples per A-line.
    n_x, n_y : int
        Lateral grid (``n_y = 1`` in 2-D).
    method : str, optional
        A registered method (``service.recon.methods.METHODS``); None: the default for a
        full lattice (``service.recon.methods.default_for("grid")``).
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
    service.recon.checks.OptionError
        An unknown method.

    Examples
    --------
    >>> import numpy as np
    >>> from service.recon import estimate_peak_memory
    >>> est = estimate_peak_memory(256, 64, 64)  # (n_t, n_y, n_x) = (256, 64, 64), float64 NER
    >>> est > 256 * 64 * 64 * 8  # more than the input
    True
    >>> estimate_peak_memory(256, 64, 64, dtype=np.float32) < est
    True
    """
    return get(method or default_for("grid")).memory(n_t, n_x, n_y, **kw)


#: the work estimates' reference: seconds on 2 cores of the machine they were measured on
#: (AMD EPYC Zen 4, AVX-512, shared with other work: load average 4-6); float64 costs this
#: factor more than float32 (measured 1.1-2.4, planar methods at 256 x 128^2 to 512 x 226^2)
FLOAT64_WORK = 1.6


def transform_units(n_t: int, n_x: int, n_y: int = 1, *, n_z: int | None = None, upsample: int = 1) -> float:
    """The work unit of the planar methods: ``N log2 N`` for the transform grid they work on,
    ``N`` = the working depth rows (at least ``n_t``, at a fast DCT-I length) times the
    lateral transform sizes (``service.recon.memory.padded_lateral``), an upsampled inverse
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
    >>> from service.recon.methods import transform_units
    >>> transform_units(256, 128, 128) > transform_units(256, 64, 64) > 0
    True
    """
    import math

    from driver.physics.fast_lengths import fast_dct1_rows
    from service.recon.memory import padded_lateral

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
    >>> from service.recon.methods import planar_work
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
        bytes at its peak (the memory admission, ``service.jobs.admission``; a model of
        ``service.recon.memory``, :func:`peak_model`); None (default): NER's,
        ``service.recon.memory.planar_peak``.
    order : int
        Position in lists (smaller first).
    work : callable or None
        ``work(n_t, n_x, n_y, *, n_z, upsample, dtype, n_points, dx, dt, c, t0, options,
        record_facts, bandwidth, **_)`` ->
        seconds on the reference 2 cores (:data:`FLOAT64_WORK`; the work admission,
        ``service.jobs.admission.estimate_work``); it may raise ``OptionError`` for options
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
        each dtype name of ``dtypes`` (``service.recon.warmup.warm_up``, ``fpscan warmup``, a job
        worker before its first job); None: nothing of its own to warm.
    kernel_modules : tuple of str
        The modules holding its numba kernels (``service.recon.warmup.cache_dirs``).
    warm_in_background : bool
        Its warm-up is slow (pylops' import: seconds): a job worker runs it in the background
        after it is ready for jobs (``service.jobs.work.warm_up``).
    memory_calibration : float
        Its admission class: the factor the memory admission applies to :attr:`peak_memory`
        (``service.jobs.admission.estimate_memory``; 1 for a model measured within its margin).
    holds_input : bool
        It keeps the input as loaded beside its working copy (the memory admission counts it even
        in the working precision).
    options : tuple of str
        The option names it takes: ``c`` and its model's fields.
    defaults : dict
        Its options' defaults (those that are values; ``None``: derived from the data).

    Examples
    --------
    >>> from service.recon.methods import get
    >>> m = get("nedner")
    >>> m.name, m.needs_grid, m.options
    ('nedner', False, ('c', 'eps', 'dtype', 'upsample', 'positivity', 'n_z', 'dz'))
    >>> m.defaults
    {'eps': 1e-06, 'dtype': 'float32', 'upsample': 1, 'positivity': False}
    >>> m.check({"upsample": 2, "dz": "2e-5"}).dz  # m
    2e-05
    >>> m.check({"eps": 5e-15})
    Traceback (most recent call last):
    ...
    service.recon.checks.OptionError: eps must be in [1e-14, 1e-1], got 5e-15
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
        raises ``service.recon.checks.OptionError`` (a ValueError) with the first refusal,
        in the kernel rule's words (``eps must be in [1e-14, 1e-1], got 5e-15``).

        Examples
        --------
        >>> from service.recon.methods import get
        >>> get("ner").check({"upsample": 2.0, "positivity": None}).model_dump()
        {'eps': 1e-06, 'dtype': 'float32', 'upsample': 2, 'positivity': False, 'n_z': None, 'dz': None}
        >>> get("ner").check({"lam": 0.1})
        Traceback (most recent call last):
        ...
        service.recon.checks.OptionError: unknown option lam
        """
        try:
            return self.options_model.model_validate(options)
        except ValidationError as exc:
            from service.recon.checks import OptionError

            raise OptionError(describe_error(exc)) from None

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
    >>> from service.recon.methods import describe_error, get
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


#: seconds per :func:`transform_units` unit of a planar method that states none (float32)
PLANAR_WORK_RATE = 3e-9

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
    >>> from service.recon.methods import METHODS, Method, MethodOptions, register
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
    service.recon.checks.OptionError
        No method of that name; the message lists the methods.

    Examples
    --------
    >>> from service.recon.methods import get
    >>> get("kwave").title
    'k-Wave compatible (kspaceLineRecon / kspacePlaneRecon)'
    >>> get("fbp")
    Traceback (most recent call last):
    ...
    service.recon.checks.OptionError: method must be one of nedner, ner, ..., got 'fbp'
    """
    spec = METHODS.get(name)
    if spec is None:
        from service.recon.checks import OptionError

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
    >>> from service.recon.methods import default_for
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


def option_fields() -> dict[str, Any]:
    """Every option of the registered methods (name -> pydantic ``FieldInfo``, the first
    method's that takes it), in the order the methods list them. Their rules agree
    (:func:`register`); their defaults may differ (tv: positivity on).

    Returns
    -------
    dict
        Option name -> pydantic ``FieldInfo`` (``default``, ``description``,
        ``json_schema_extra`` with the SI ``unit``); ``c`` is not among them.

    Examples
    --------
    >>> from service.recon.methods import option_fields
    >>> fields = option_fields()
    >>> list(fields)[:6]  # the first method's (nedner) first, then each later method's new ones
    ['eps', 'dtype', 'upsample', 'positivity', 'n_z', 'dz']
    >>> {"interp", "lam", "iterations", "tol", "time_limit", "debias"} <= set(fields)  # kwave's, tv's
    True
    >>> fields["dz"].json_schema_extra["unit"], fields["positivity"].default  # nedner's default
    ('m', False)
    """
    out: dict[str, Any] = {}
    for m in METHODS.values():
        for name, f in m.options_model.model_fields.items():
            out.setdefault(name, f)
    return out


def option_schemas(method: Method | type[BaseModel]) -> list[dict[str, Any]]:
    """``method``'s options (or those of an options model: a file format's load options) as the
    methods and formats endpoints and the web page read them: per
    option ``name``, ``description``, ``default`` (this method's), and ``schema``: the JSON
    schema of a value (``type``, ``minimum``/``maximum``/``exclusiveMinimum``, ``enum``)
    with ``unit`` (SI) and ``quantity`` (``length``/``time``: text with a unit accepted).

    Parameters
    ----------
    method : Method or pydantic model class
        A registered method (:func:`get`), or an options model.

    Returns
    -------
    list of dict
        One per field of its options model, in the model's order (``c`` is not among them).

    Examples
    --------
    >>> from service.recon.methods import get, option_schemas
    >>> [o["name"] for o in option_schemas(get("kwave"))]
    ['dtype', 'positivity', 'interp']
    >>> eps = option_schemas(get("ner"))[0]
    >>> eps["name"], eps["default"], eps["schema"]
    ('eps', 1e-06, {'maximum': 0.1, 'minimum': 1e-14, 'type': 'number', 'unit': '1'})
    >>> dz = option_schemas(get("ner"))[-1]
    >>> dz["default"], dz["schema"]["unit"], dz["schema"]["quantity"]  # None: derived (c dt)
    (None, 'm', 'length')
    """
    model = method.options_model if isinstance(method, Method) else method
    props = model.model_json_schema()["properties"]
    out = []
    for name, p in props.items():
        value = next((b for b in p.get("anyOf", []) if b.get("type") != "null"), None) or \
            {k: v for k, v in p.items() if k not in ("anyOf", "default", "description", "title")}
        extra = {k: p[k] for k in ("unit", "quantity", "flag", "derived") if k in p}
        out.append({"name": name, "description": p.get("description", ""), "default": p.get("default"),
                    "schema": {**{k: v for k, v in value.items() if k != "title"}, **extra}})
    return out


def range_text(schema: dict) -> str:
    """A value schema's range in words: ``[1e-14, 0.1]``, ``1..8``, ``(0, 604800]``, the choices.

    Parameters
    ----------
    schema : dict
        A value's JSON schema (``option_schemas(m)[i]["schema"]``).

    Returns
    -------
    str
        Closed ``[lo, hi]`` / open-below ``(lo, hi]`` for numbers, ``lo..hi`` for integers,
        the choices in backticks, ``"true / false"`` for a flag, ``""`` when unbounded.

    Examples
    --------
    >>> from service.recon.methods import range_text
    >>> range_text({"type": "number", "minimum": 1e-14, "maximum": 0.1})
    '[1e-14, 0.1]'
    >>> range_text({"type": "number", "exclusiveMinimum": 0, "maximum": 604800})  # s
    '(0, 604800]'
    >>> range_text({"type": "integer", "minimum": 1, "maximum": 8})
    '1..8'
    >>> range_text({"enum": ["float32", "float64"]}), range_text({"type": "boolean"})
    ('`float32`, `float64`', 'true / false')
    """
    lo, hi = schema.get("minimum", schema.get("exclusiveMinimum")), schema.get("maximum")
    if "enum" in schema:
        return ", ".join(f"`{v}`" for v in schema["enum"])
    if lo is None and hi is None:
        return "true / false" if schema.get("type") == "boolean" else ""
    left = "(" if "exclusiveMinimum" in schema else "["
    return f"{left}{lo:g}, {hi:g}]" if schema.get("type") == "number" else f"{lo}..{hi}"


def docs_table() -> str:
    """Markdown: one table of the methods (name, input, options, source) and one of the
    options (range, unit, default per method, meaning), generated from :data:`METHODS`
    (docs/methods.md holds its current rendering; a test checks it).

    Returns
    -------
    str
        The two Markdown tables, separated by a blank line, ending in a newline.

    Examples
    --------
    >>> from service.recon.methods import docs_table
    >>> table = docs_table().splitlines()
    >>> table[0]
    '| method | input | options | source |'
    >>> table[2].split(" | ")[:2]
    ['| `nedner`', 'any sensor points']
    >>> next(row for row in table if row.startswith("| `eps`"))
    '| `eps` | [1e-14, 0.1] | 1 | `1e-06` | NUFFT tolerance (relative accuracy of the non-uniform FFTs) |'
    """
    lines = ["| method | input | options | source |", "|---|---|---|---|"]
    for m in METHODS.values():
        lines.append(f"| `{m.name}` | {'full grid' if m.needs_grid else 'any sensor points'} | "
                     f"{', '.join(f'`{o}`' for o in m.options)} | {m.title}: {m.source} |")
    lines += ["", "| option | range | unit | default | meaning |", "|---|---|---|---|---|"]
    per: dict[str, dict] = {}
    for m in METHODS.values():
        for o in option_schemas(m):
            row = per.setdefault(o["name"], {"o": o, "defaults": {}})
            row["defaults"][m.name] = o["default"]
    for name, row in per.items():
        o = row["o"]
        lines.append(f"| `{name}` | {range_text(o['schema'])} | {o['schema'].get('unit', '')} | "
                     f"{default_text(name, code=True)} | {o['description']} |")
    return "\n".join(lines) + "\n"


def default_text(name: str, *, code: bool = False) -> str:
    """The default of option ``name`` in words, per method where they differ: ``"1e-06"``,
    ``"n_t"`` (a ``None`` default: the field's ``derived``), ``"false (tv: true)"`` (the most
    common first).

    Parameters
    ----------
    name : str
        An option of a registered method (:func:`option_fields`).
    code : bool, optional
        Put the values (not the derived words) in Markdown backticks (the docs table).

    Returns
    -------
    str

    Raises
    ------
    IndexError
        No registered method takes ``name``.

    Examples
    --------
    >>> from service.recon.methods import default_text
    >>> default_text("eps"), default_text("n_z"), default_text("dz")
    ('1e-06', 'n_t', 'c·dt')
    >>> default_text("positivity")  # doctest: +ELLIPSIS
    'false (...tv...: true)'
    >>> default_text("positivity", code=True)  # doctest: +ELLIPSIS
    '`false` (...tv...: `true`)'
    """
    by_value: dict[str, list[str]] = {}
    for m in METHODS.values():
        f = m.options_model.model_fields.get(name)
        if f is not None:
            v = f.default
            derived = (f.json_schema_extra or {}).get("derived", "from the data") \
                if isinstance(f.json_schema_extra, dict) else "from the data"
            shown = str(derived) if v is None else (str(v).lower() if isinstance(v, bool) else str(v))
            by_value.setdefault(f"`{shown}`" if code and v is not None else shown, []).append(m.name)
    ordered = sorted(by_value.items(), key=lambda kv: -len(kv[1]))
    first = ordered[0][0]
    rest = "; ".join(f"{', '.join(ms)}: {v}" for v, ms in ordered[1:])
    return f"{first} ({rest})" if rest else first


# every method, fpscan's own and the plugins' (service.plugins; at the end: a method module
# imports this package's names)
load_group("fpscan.methods", Method, register)
