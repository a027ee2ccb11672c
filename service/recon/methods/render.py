"""The renderings of the methods' options: per option its JSON schema as the methods and
formats endpoints and the web page read it (:func:`option_schemas`, :func:`option_fields`),
its range and default in words (:func:`range_text`, :func:`default_text`) and the Markdown
tables of docs/methods.md (:func:`docs_table`, ``scripts/methods_doc.py``), all generated from
the registry (:data:`~.registry.METHODS`).

Importing this module needs no numpy.
"""
from __future__ import annotations

from typing import Any

from pydantic import BaseModel

from fpscan.service.recon.methods.options import SpeedOptions
from fpscan.service.recon.methods.registry import METHODS, Method

#: the speed of sound's fields, every method's (``SpeedOptions``): the lists of a method's own options leave them out
SPEED_FIELDS: tuple[str, ...] = tuple(SpeedOptions.model_fields)

__all__ = ["SPEED_FIELDS", "option_fields", "option_schemas", "range_text", "docs_table", "default_text"]


def option_fields() -> dict[str, Any]:
    """Every option of the registered methods (name -> pydantic ``FieldInfo``, the first
    method's that takes it), in the order the methods list them. Their rules agree
    (:func:`register`); their defaults may differ (tv: positivity on).

    Returns
    -------
    dict
        Option name -> pydantic ``FieldInfo`` (``default``, ``description``,
        ``json_schema_extra`` with the SI ``unit``); the speed of sound's fields, every method's
        (:data:`SPEED_FIELDS`), are not among them.

    Examples
    --------
    >>> from fpscan.service.recon.methods import option_fields
    >>> fields = option_fields()
    >>> list(fields)[:6]  # the first method's (nedner) first, then each later method's new ones
    ['eps', 'dtype', 'upsample', 'positivity', 'n_z', 'dz']
    >>> {"interp", "lam", "max_iter", "tol", "time_limit", "debias"} <= set(fields)  # kwave's, tv's
    True
    >>> fields["dz"].json_schema_extra["unit"], fields["positivity"].default  # nedner's default
    ('m', False)
    """
    out: dict[str, Any] = {}
    for m in METHODS.values():
        for name, f in m.options_model.model_fields.items():
            if name not in SPEED_FIELDS:
                out.setdefault(name, f)
    return out


def option_schemas(method: Method | type[BaseModel]) -> list[dict[str, Any]]:
    """``method``'s options (or those of an options model: a file format's load options) as the
    methods and formats endpoints and the web page read them: per
    option ``name``, ``description``, ``default`` (this method's), and ``schema``: the JSON
    schema of a value (``type``, ``minimum``/``maximum``/``exclusiveMinimum``, ``enum``)
    with ``unit`` (SI), ``quantity`` (``length``/``time``: text with a unit accepted) and
    ``display_unit`` (the unit a form shows the value in, where it is not ``unit``).

    Parameters
    ----------
    method : Method or pydantic model class
        A registered method (:func:`get`), or an options model.

    Returns
    -------
    list of dict
        One per field of its options model, in the model's order (the speed of sound's fields,
        :data:`SPEED_FIELDS`, are not among them: they are every method's, listed once).

    Examples
    --------
    >>> from fpscan.service.recon.methods import get, option_schemas
    >>> [o["name"] for o in option_schemas(get("kwave"))]
    ['dtype', 'positivity', 'interp']
    >>> eps = option_schemas(get("ner"))[0]
    >>> eps["name"], eps["default"], eps["schema"]
    ('eps', 1e-06, {'maximum': 0.1, 'minimum': 1e-14, 'type': 'number', 'unit': '1'})
    >>> dz = option_schemas(get("ner"))[-2]
    >>> dz["default"], dz["schema"]["unit"], dz["schema"]["quantity"]  # None: derived (c dt)
    (None, 'm', 'length')
    """
    model = method.options_model if isinstance(method, Method) else method
    props = model.model_json_schema()["properties"]
    out = []
    for name, p in props.items():
        if name in SPEED_FIELDS and isinstance(method, Method):
            continue
        value = next((b for b in p.get("anyOf", []) if b.get("type") != "null"), None) or \
            {k: v for k, v in p.items() if k not in ("anyOf", "default", "description", "title")}
        extra = {k: p[k] for k in ("unit", "display_unit", "quantity", "flag", "derived") if k in p}
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
    >>> from fpscan.service.recon.methods import range_text
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
    >>> from fpscan.service.recon.methods import docs_table
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
                     f"{', '.join(f'`{o}`' for o in ('sound_speed', *(o for o in m.options if o not in SPEED_FIELDS)))} | "
                     f"{m.title}: {m.source} |")
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
    ``"down to c·t_last, ..."`` (a ``None`` default: the field's ``derived``), ``"false (tv: true)"`` (the most
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
    >>> from fpscan.service.recon.methods import default_text
    >>> default_text("eps"), default_text("upsample")
    ('1e-06', '1')
    >>> default_text("n_z")  # a None default: the field's ``derived``, per method where they differ
    "down to c·t_last, as deep as the record reaches (tv: down to the record's last echo above the noise)"
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
