"""The reconstruction methods: one module per method, one registry.

Each module of this package (``ner``, ``nedner``, ``interp``, ``kwave``, ``tv``, and
whatever comes next) defines its typed options model (a :class:`~.options.MethodOptions`
with each option's type, range, unit and default), its ``run`` (calling the kernels of
:mod:`service.recon`: ``planar``, ``kwave``, ``tv``), its peak-memory model and calls
:func:`register`. The package imports every module in it (but ``options`` and private
ones) on first import, so a new method is one new file here: the dispatch
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

import importlib
import pkgutil
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pydantic import ValidationError

from service.recon.methods.options import MethodOptions

__all__ = ["Method", "METHODS", "register", "get", "option_schemas", "option_fields", "docs_table",
           "planar_memory", "MethodOptions", "default_text", "describe_error", "range_text"]

Runner = Callable[..., Any]


def planar_memory(method: str) -> Callable[..., int]:
    """The peak-memory model of ``method`` in ``service.recon.checks.estimate_peak_memory``
    (bytes; ``(n_t, n_x, n_y=1, *, n_z, upsample, dtype, n_points, dx, dt, c, dz)``)."""
    def peak(n_t: int, n_x: int, n_y: int = 1, **kw: Any) -> int:
        from service.recon.checks import estimate_peak_memory

        return estimate_peak_memory(n_t, n_x, n_y, method=method, **kw)

    return peak


@dataclass(frozen=True)
class Method:
    """One reconstruction method.

    Parameters
    ----------
    name : the word users type (``--method``, the API's ``method``).
    title : one line for lists (web page, ``--help``).
    needs_grid : True when it needs data on a full regular grid (a full lattice).
    options_model : its options (a :class:`MethodOptions` subclass: type, range, unit and
        default of each; ``c`` is every method's and not in it).
    run : ``run(dataset, c, options, progress)`` → ``Reconstruction`` (module docstring).
    source : where the algorithm comes from.
    peak_memory : ``peak_memory(n_t, n_x, n_y, *, n_z, upsample, dtype, n_points, dx, dt, c,
        dz)`` → bytes at its peak (the memory admission, ``service.jobs.admission``); default
        :func:`planar_memory` of ``name``.
    order : position in lists (smaller first).
    """

    name: str
    title: str
    needs_grid: bool
    options_model: type[MethodOptions]
    run: Runner
    source: str = ""
    peak_memory: Callable[..., int] | None = None
    order: int = 100

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
        in the kernel rule's words (``eps must be in [1e-14, 1e-1], got 5e-15``)."""
        try:
            return self.options_model.model_validate(options)
        except ValidationError as exc:
            from service.recon.checks import OptionError

            raise OptionError(describe_error(exc)) from None

    def memory(self, n_t: int, n_x: int, n_y: int = 1, **kw: Any) -> int:
        """Peak bytes (:attr:`peak_memory`)."""
        return (self.peak_memory or planar_memory(self.name))(n_t, n_x, n_y, **kw)


def describe_error(exc: ValidationError) -> str:
    """The first error of ``exc`` as one line naming the option (the rule's own words)."""
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
    generated HTTP model and CLI flag hold one rule per option name)."""
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
    METHODS[method.name] = method
    ordered = sorted(METHODS.values(), key=lambda m: m.order)
    METHODS.clear()
    METHODS.update((m.name, m) for m in ordered)
    return method


def get(name: str) -> Method:
    """The method called ``name``; ``OptionError`` (a ValueError) listing them otherwise."""
    spec = METHODS.get(name)
    if spec is None:
        from service.recon.checks import OptionError

        raise OptionError(f"method must be one of {', '.join(METHODS)}, got {name!r}")
    return spec


def _rules(model: type[MethodOptions]) -> dict[str, str]:
    """Each field's rule, as its JSON schema without default/description/title."""
    out = {}
    for name, schema in model.model_json_schema()["properties"].items():
        out[name] = repr({k: v for k, v in sorted(schema.items()) if k not in ("default", "description", "title")})
    return out


def option_fields() -> dict[str, Any]:
    """Every option of the registered methods (name -> pydantic ``FieldInfo``, the first
    method's that takes it), in the order the methods list them. Their rules agree
    (:func:`register`); their defaults may differ (tv: positivity on)."""
    out: dict[str, Any] = {}
    for m in METHODS.values():
        for name, f in m.options_model.model_fields.items():
            out.setdefault(name, f)
    return out


def option_schemas(method: Method) -> list[dict[str, Any]]:
    """``method``'s options as the methods endpoint and the web page read them: per
    option ``name``, ``description``, ``default`` (this method's), and ``schema``: the JSON
    schema of a value (``type``, ``minimum``/``maximum``/``exclusiveMinimum``, ``enum``)
    with ``unit`` (SI) and ``quantity`` (``length``/``time``: text with a unit accepted)."""
    props = method.options_model.model_json_schema()["properties"]
    out = []
    for name, p in props.items():
        value = next((b for b in p.get("anyOf", []) if b.get("type") != "null"), None) or \
            {k: v for k, v in p.items() if k not in ("anyOf", "default", "description", "title")}
        extra = {k: p[k] for k in ("unit", "quantity", "flag", "derived") if k in p}
        out.append({"name": name, "description": p.get("description", ""), "default": p.get("default"),
                    "schema": {**{k: v for k, v in value.items() if k != "title"}, **extra}})
    return out


def range_text(schema: dict) -> str:
    """A value schema's range in words: ``[1e-14, 0.1]``, ``1..8``, ``(0, 604800]``, the choices."""
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
    (docs/methods.md holds its current rendering; a test checks it)."""
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
    common first)."""
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


def _discover() -> None:
    """Import every method module of this package (they register themselves)."""
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda i: i.name):
        if info.name != "options" and not info.name.startswith("_"):
            importlib.import_module(f"{__name__}.{info.name}")


_discover()
