"""Mask kinds, declared once: one pydantic parameter model per kind.

``KINDS`` maps each kind's name to its ``MaskKind``: the parameter model, the mask function
(first argument: the lattice), a label, and accepted aliases. Everything else derives from
it: ``make_mask`` (validation of parameters), the HTTP API's request schema
(``fpscan.service.api.models``: a union keyed on ``kind``, so OpenAPI lists each kind's
parameters), the ``/api/plans/kinds`` endpoint the web page builds its form from, and the
``fpscan plan <kind>`` subcommands and flags (``clients/cli/plan.py``). Adding a kind means
adding its model and its entry here (plus its mask function).

Units: parameters are SI. Each physical field declares its unit in its JSON schema
(``json_schema_extra={"unit": "m"}`` via ``length()``; ``display_unit`` is what a form
shows by default), so unit parsing can hook in at one place: ``field_units(model)``.
Range checks that guarantee bounded work belong to the mask functions.

The parameter models' docstrings are each kind's one-line description (``MaskKind.description``,
shown by ``fpscan plan --help`` and ``/api/plans/kinds``), so their examples are here:

>>> from fpscan.service.plans.kinds import (EquiangularParams, EquispacedParams, EquisteradianParams,
...     FullParams, HexagonalParams, PoissonParams, PointsParams, RandomParams)
>>> FullParams().mask_kwargs()
{}
>>> EquispacedParams(interval=5, n_per_side=(41, 41)).mask_kwargs()
{'interval': 5, 'n_per_side': (41, 41)}
>>> HexagonalParams(spacing="240um").mask_kwargs()  # m
{'spacing': 0.00024}
>>> RandomParams(n_points=200)
RandomParams(n_points=200, seed=0)
>>> PoissonParams(min_distance=2.4e-4).mask_kwargs()
{'min_distance': 0.00024, 'seed': 0}
>>> PointsParams(indices=[[0, 0], [4, 4]]).mask_kwargs()
{'indices': [(0, 0), (4, 4)]}
>>> EquiangularParams(depth=1.2e-3, n_points=32).mask_kwargs()
{'depth': 0.0012, 'n_points': 32}
>>> EquisteradianParams(depth="3.6 mm", n_points=1625, poi=("1mm", 0)).mask_kwargs()
{'depth': 0.0036, 'n_points': 1625, 'poi': (0.001, 0.0)}
>>> FullParams(spacing=1e-4)
Traceback (most recent call last):
...
pydantic_core._pydantic_core.ValidationError: 1 validation error for FullParams
spacing
  Extra inputs are not permitted ...
"""
from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

if TYPE_CHECKING:
    from fpscan.service.plans.lattice import Lattice
    from fpscan.service.plans.mask import Mask

__all__ = ["KINDS", "MaskKind", "MaskParams", "make_mask", "resolve_kind", "kind_fields",
           "field_units", "si_params", "length", "FullParams", "EquispacedParams", "HexagonalParams", "RandomParams",
           "PoissonParams", "PointsParams", "EquiangularParams", "EquisteradianParams"]


def length(description: str, *, display_unit: str = "mm", **constraints: Any) -> Any:
    """A pydantic length field in m, for a kind's parameter model.

    Parameters
    ----------
    description : str
        The field's description (shown by the CLI and the web form).
    display_unit : str, optional
        The unit a form shows by default (``"mm"``, ``"µm"``); values stay in m.
    **constraints
        Passed to ``pydantic.Field`` (``gt=0``, ``default=None``, ``examples=[...]``, ...).

    Returns
    -------
    pydantic.fields.FieldInfo
        A ``Field`` whose JSON schema carries ``unit: "m"`` and ``display_unit``.

    Examples
    --------
    >>> from fpscan.service.plans.kinds import length
    >>> f = length("depth of the point of interest, m", gt=0)
    >>> f.json_schema_extra
    {'unit': 'm', 'display_unit': 'mm'}
    >>> f.metadata
    [Gt(gt=0)]
    """
    return Field(description=description, json_schema_extra={"unit": "m", "display_unit": display_unit},
                 **constraints)



class MaskParams(BaseModel):
    """Base of every kind's parameter model: unknown parameters and NaN/inf are refused.

    Lengths typed with a unit (``"3.6mm"``) are converted to m for every field that declares
    a unit (``field_units``); bare numbers are SI.

    Attributes
    ----------
    model_config : pydantic.ConfigDict
        ``extra="forbid"``, ``allow_inf_nan=False``.

    Raises
    ------
    pydantic.ValidationError
        (a ValueError) naming the field, on construction with bad parameters.

    Examples
    --------
    >>> from fpscan.service.plans.kinds import EquisteradianParams, MaskParams
    >>> issubclass(EquisteradianParams, MaskParams)
    True
    >>> EquisteradianParams(depth="3.6 mm", n_points=1625).mask_kwargs()  # unset poi left out
    {'depth': 0.0036, 'n_points': 1625}
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _units(cls, data: Any) -> Any:
        """Values typed with a unit to SI (:func:`si_params`)."""
        return si_params(cls, data)

    def mask_kwargs(self) -> dict:
        """The keyword arguments of the kind's mask function (unset optional ones left out).

        Returns
        -------
        dict
            SI units.

        Examples
        --------
        >>> from fpscan.service.plans.kinds import PoissonParams
        >>> PoissonParams(min_distance="240um").mask_kwargs()
        {'min_distance': 0.00024, 'seed': 0}
        """
        return {k: v for k, v in self.model_dump().items() if v is not None}


class FullParams(MaskParams):
    """Every lattice point; weight pitch² each."""


class EquispacedParams(MaskParams):
    """Equispaced sub-grid: every ``interval``-th lattice point, ``n_per_side`` per side,
    centred on the lattice (paper §6: 41 × 41 at interval 5)."""

    interval: int = Field(ge=1, description="lattice points from one sensor to the next", examples=[4])
    n_per_side: int | tuple[int, int] | None = Field(
        None, title="Points per side", description="points per side (n, or n_x n_y); default as many as fit")

    @model_validator(mode="after")
    def _counts(self) -> EquispacedParams:
        n = self.n_per_side
        for v in (n if isinstance(n, tuple) else (n,)):
            if v is not None and v < 1:
                raise ValueError(f"n_per_side must be >= 1, got {v}")
        return self


class HexagonalParams(MaskParams):
    """Hexagonal arrangement snapped to the lattice (2-D lattices)."""

    spacing: float = length("neighbour distance, m (at least one pitch)", display_unit="µm", gt=0,
                            examples=[240e-6])


class RandomParams(MaskParams):
    """Distinct lattice points drawn uniformly (numpy PCG64, seeded)."""

    n_points: int = Field(ge=1, title="Number of points", description="number of points", examples=[200])
    seed: int = Field(0, ge=0, le=2**64 - 1, description="random seed (0 to 2^64 - 1)")


class PoissonParams(MaskParams):
    """Poisson-disc: seeded random points no closer than ``min_distance``."""

    min_distance: float = length("minimum distance between points, m", title="Minimum distance",
                                 display_unit="µm", gt=0, examples=[240e-6])
    seed: int = Field(0, ge=0, le=2**64 - 1, description="random seed (0 to 2^64 - 1)")
    n_points: int | None = Field(None, ge=1, title="Number of points", description="stop after this many points (default: no cap)")


class PointsParams(MaskParams):
    """A user's point list: ``points`` (x, y) in m snapped to the lattice, or lattice
    ``indices`` (i_x, i_y); exactly one of them. Kept in the given order by default."""

    # the schema states the rule below: exactly one of them given (not null)
    model_config = ConfigDict(json_schema_extra={"oneOf": [
        {"required": [a], "properties": {a: {"type": "array"}, b: {"type": "null"}}}
        for a, b in (("points", "indices"), ("indices", "points"))]})

    points: list[tuple[float, float]] | None = length(
        "points (x, y) in m, snapped to the nearest lattice point", default=None, display_unit="mm")
    indices: list[tuple[int, int]] | None = Field(None, title="Lattice indices", description="lattice indices (i_x, i_y), 0-based",
                                                  examples=[[[0, 0], [4, 4], [8, 2]]])

    @model_validator(mode="after")
    def _one(self) -> PointsParams:
        if (self.points is None) == (self.indices is None):
            raise ValueError("give exactly one of points (m) or indices")
        return self


class EquiangularParams(MaskParams):
    """Equiangular (2-D line lattice): equal angles seen from a point of interest;
    weights ∝ r² (paper §5.1)."""

    depth: float = length("depth of the point of interest below the sensor line, m (at most 1 m; the mask also refuses a depth at which the aperture subtends under 1 mrad)",
                          gt=0, le=1.0, examples=[1.2e-3])
    n_points: int = Field(ge=1, title="Number of points", description="requested number of points", examples=[32])
    poi: float | None = length("lateral position x of the point of interest, m (default: the centre)",
                               title="Point of interest", default=None)


class EquisteradianParams(MaskParams):
    """Equi-steradian (3-D): rings of equal solid angle seen from a point of interest;
    weights ∝ r³ (paper appendix)."""

    depth: float = length("depth of the point of interest below the sensor plane, m (at most 1 m; the mask also refuses a depth at which the aperture subtends under 1 mrad)",
                          gt=0, le=1.0, examples=[1.2e-3])
    n_points: int = Field(ge=1, title="Number of points", description="requested number of points", examples=[200])
    poi: tuple[float, float] | None = length(
        "lateral position (x, y) of the point of interest, m (default: the centre)", title="Point of interest",
        default=None)


@dataclass(frozen=True)
class MaskKind:
    """One mask kind, as ``KINDS`` declares it.

    Parameters
    ----------
    name, params, impl, label, aliases, poi_depth
        As the attributes below.

    Attributes
    ----------
    name : str
        The kind's name (``"equisteradian"``, ...).
    params : type of MaskParams
        Its parameter model (SI units).
    impl : str
        The mask function, ``"module:function"`` in this package, first argument the lattice;
        loaded on first use so that the models are cheap to import.
    label : str
        A label for forms and help.
    aliases : tuple of str
        Other names the kind is accepted under.
    poi_depth : bool
        The kind's ``depth`` parameter is the depth of a point of interest (m), judged by the
        plausibility rules (``fpscan.service.plans.plan.check_plausible_request``).
    function : callable
        The mask function ``function(lattice, **params) -> Mask``.
    description : str
        The parameter model's docstring on one line (served to the CLI and the web form).

    Examples
    --------
    >>> from fpscan.service.plans import KINDS
    >>> k = KINDS["equisteradian"]
    >>> k.function.__name__, k.poi_depth
    ('equisteradian_mask', True)
    >>> KINDS["equispaced"].aliases
    ('subgrid', 'grid')
    """

    name: str
    params: type[MaskParams]
    impl: str
    label: str
    aliases: tuple[str, ...] = ()
    poi_depth: bool = False

    @property
    def function(self) -> Callable[..., Mask]:
        """The mask function ``function(lattice, **params) -> Mask``."""
        module, fn = self.impl.split(":")
        return getattr(importlib.import_module(f".{module}", __package__), fn)

    @property
    def description(self) -> str:
        """The parameter model's docstring on one line."""
        return " ".join((self.params.__doc__ or "").split())


#: The mask kinds, in the order forms offer them.
KINDS: dict[str, MaskKind] = {k.name: k for k in (
    MaskKind("equisteradian", EquisteradianParams, "angular:equisteradian_mask",
             "Equi-steradian (3-D, rings around a point of interest)", poi_depth=True),
    MaskKind("equiangular", EquiangularParams, "angular:equiangular_mask",
             "Equiangular (2-D line, around a point of interest)", poi_depth=True),
    MaskKind("full", FullParams, "grids:full_mask", "Full lattice"),
    MaskKind("equispaced", EquispacedParams, "grids:subgrid_mask", "Equispaced sub-grid", ("subgrid", "grid")),
    MaskKind("hexagonal", HexagonalParams, "grids:hexagonal_mask", "Hexagonal", ("hex",)),
    MaskKind("random", RandomParams, "grids:random_mask", "Random (seeded)"),
    MaskKind("poisson", PoissonParams, "grids:poisson_mask", "Poisson-disc (seeded)", ("poisson-disc",)),
    MaskKind("points", PointsParams, "grids:points_mask", "User point list", ("user",)),
)}


def __getattr__(name: str) -> Any:
    """``MASK_KINDS``: kind name -> mask function, built on first use (PEP 562)."""
    if name == "MASK_KINDS":
        return {n: k.function for n, k in KINDS.items()}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


_ALIASES = {alias: k.name for k in KINDS.values() for alias in k.aliases}


def resolve_kind(kind: Any) -> MaskKind:
    """The ``MaskKind`` of a kind name or alias (case-insensitive).

    Parameters
    ----------
    kind : str
        A name in ``KINDS`` or one of the aliases.

    Returns
    -------
    MaskKind

    Raises
    ------
    ValueError
        Not a string, or an unknown kind (naming the known kinds).

    Examples
    --------
    >>> from fpscan.service.plans import resolve_kind
    >>> resolve_kind("Hex").name, resolve_kind("grid").name
    ('hexagonal', 'equispaced')
    >>> resolve_kind("spiral")
    Traceback (most recent call last):
    ...
    ValueError: unknown mask kind 'spiral'; known: equisteradian, equiangular, full, equispaced, ...
    """
    if not isinstance(kind, str):
        raise ValueError(f"mask kind must be a string, got {kind!r}")
    name = _ALIASES.get(kind.lower(), kind.lower())
    if name not in KINDS:
        raise ValueError(f"unknown mask kind {kind!r}; known: {', '.join(KINDS)}")
    return KINDS[name]


def _parse_unit(text: str, kind: str, name: str) -> float:
    from fpscan.driver.units import parse_quantity

    return parse_quantity(text, kind, name=name)


#: the kind of quantity (``fpscan.driver.units.KINDS``) of each SI unit a field may declare
_UNIT_KINDS = {"m": "length", "s": "time", "Hz": "frequency", "m/s": "speed"}


def si_params(model: type[BaseModel], data: Any) -> Any:
    """A kind's parameters with every value typed with a unit (``"3.6mm"``, ``"-2 mm"``,
    ``"240 µm"``) in SI, read by the one unit parser (``fpscan.driver.units.parse_quantity``),
    for every field of ``model`` that declares a unit (:func:`field_units`): a number, each of
    a point of interest's 1-2 numbers, or each coordinate of a list of (x, y) pairs. Bare
    numbers are SI and pass unchanged; anything else is left to the model's validation.
    The parameter models run it before validating (and the HTTP API before its plausibility
    rules, so a depth typed as ``"3600 mm"`` is named a unit mistake).

    Parameters
    ----------
    model : type of pydantic.BaseModel
        A kind's parameter model (:class:`MaskParams` subclass).
    data : Any
        The parameters as given (a dict; anything else is returned unchanged).

    Returns
    -------
    Any
        ``data``, or a copy with the typed values in SI units.

    Raises
    ------
    ValueError
        A text that is not a number with a unit of the field's kind, naming the field.

    Examples
    --------
    >>> from fpscan.service.plans.kinds import EquisteradianParams, PointsParams, si_params
    >>> si_params(EquisteradianParams, {"depth": "3.6 mm", "poi": ["1mm", 0], "n_points": 9})
    {'depth': 0.0036, 'poi': [0.001, 0], 'n_points': 9}
    >>> si_params(PointsParams, {"points": [["0.3 mm", "-0.15mm"], [0, 1e-4]]})
    {'points': [[0.0003, -0.00015], [0, 0.0001]]}
    """
    if not isinstance(data, dict):
        return data
    out = None
    for name, unit in field_units(model).items():
        v, kind = data.get(name), _UNIT_KINDS.get(unit)
        if kind is None or v is None:
            continue

        def one(x: Any, name: str = name, kind: str = kind) -> Any:
            return _parse_unit(x, kind, name) if isinstance(x, str) else x

        if isinstance(v, str):
            new: Any = one(v)
        elif isinstance(v, (list, tuple)) and len(v) <= 2 and any(isinstance(x, str) for x in v):
            new = [one(x) for x in v]  # a point of interest (x) or (x, y)
        elif isinstance(v, (list, tuple)) and any(isinstance(p, (list, tuple)) and any(isinstance(x, str) for x in p)
                                                  for p in v):
            new = [[one(x) for x in p] if isinstance(p, (list, tuple)) and len(p) <= 2 else p for p in v]  # pairs
        else:
            continue
        out = dict(data) if out is None else out
        out[name] = new
    return data if out is None else out


def field_units(model: type[BaseModel]) -> dict[str, str]:
    """Field name -> SI unit for the fields of a model that declare one.

    Parameters
    ----------
    model : type of pydantic.BaseModel
        A parameter model (e.g. a kind's ``MaskParams`` subclass).

    Returns
    -------
    dict of str to str
        Field name -> unit (``"m"``, ``"s"``, ``"Hz"``, ``"m/s"``).

    Examples
    --------
    >>> from fpscan.service.plans.kinds import EquisteradianParams, RandomParams, field_units
    >>> field_units(EquisteradianParams)
    {'depth': 'm', 'poi': 'm'}
    >>> field_units(RandomParams)
    {}
    """
    out = {}
    for name, f in model.model_fields.items():
        extra = f.json_schema_extra if isinstance(f.json_schema_extra, dict) else {}
        if "unit" in extra:
            out[name] = str(extra["unit"])
    return out


def _widget(prop: dict) -> str:
    """How a form/CLI takes a JSON-schema property: number, integer, numbers (1-2 numbers
    on one line) or pairs (a list of (a, b) pairs)."""
    options = prop.get("anyOf", [prop])
    types = {o.get("type") for o in options if o.get("type") != "null"}
    arrays = [o for o in options if o.get("type") == "array"]
    if any(a.get("items", {}).get("type") == "array" or "items" in a and "prefixItems" in a["items"]
           for a in arrays):
        return "pairs"
    if arrays:
        return "numbers"
    return "integer" if types == {"integer"} else "number"


def _leaf_types(prop: Any) -> set:
    """The scalar JSON types (number, integer, ...) anywhere inside a property schema."""
    if isinstance(prop, list):
        return set().union(*(_leaf_types(p) for p in prop)) if prop else set()
    if not isinstance(prop, dict):
        return set()
    found = set()
    if prop.get("type") not in (None, "array", "object", "null"):
        found.add(prop["type"])
    for key in ("anyOf", "items", "prefixItems"):
        if key in prop:
            found |= _leaf_types(prop[key])
    return found


def kind_fields(kind: str) -> list[dict]:
    """The parameters of a mask kind as plain descriptors.

    Derived from the kind's model's JSON schema; the CLI and the web form are built from
    these. widget: ``number``/``integer`` (one value), ``numbers`` (one or more values on one
    line; ``scalar``: a single value is taken as a number), ``pairs`` (a list of (a, b) pairs).

    Parameters
    ----------
    kind : str
        A kind name or alias.

    Returns
    -------
    list of dict
        One per parameter, in the model's order, with keys ``name``, ``title``,
        ``description``, ``widget``, ``integer``, ``required``, ``scalar``, ``default``,
        ``example``, ``unit`` (SI, or None), ``display_unit``, ``minimum``,
        ``exclusive_minimum``.

    Raises
    ------
    ValueError
        An unknown kind.

    Examples
    --------
    >>> from fpscan.service.plans import kind_fields
    >>> [f["name"] for f in kind_fields("poisson")]
    ['min_distance', 'seed', 'n_points']
    >>> f = kind_fields("hexagonal")[0]
    >>> f["widget"], f["unit"], f["display_unit"], f["required"], f["exclusive_minimum"]
    ('number', 'm', 'µm', True, 0)
    """
    model = resolve_kind(kind).params
    schema = model.model_json_schema()
    required = set(schema.get("required", ()))
    out = []
    for name, prop in schema.get("properties", {}).items():
        widget = _widget(prop)
        options = prop.get("anyOf", [prop])
        integer = _leaf_types(prop) == {"integer"}
        bounds = [o for o in options if "minimum" in o or "exclusiveMinimum" in o]
        out.append({
            "name": name, "title": prop.get("title", name), "description": prop.get("description", ""),
            "widget": widget, "integer": bool(integer), "required": name in required,
            "scalar": any(o.get("type") in ("number", "integer") for o in options),
            "default": prop.get("default"), "example": (prop.get("examples") or [None])[0],
            "unit": prop.get("unit"), "display_unit": prop.get("display_unit"),
            "minimum": bounds[0].get("minimum") if bounds else None,
            "exclusive_minimum": bounds[0].get("exclusiveMinimum") if bounds else None,
        })
    return out


def make_mask(kind: str, lattice: Lattice | dict, **params: Any) -> Mask:
    """Make a sensor mask of a named kind, its parameters checked by the kind's model.

    Parameters
    ----------
    kind : str
        A name in ``KINDS`` or an alias.
    lattice : Lattice or dict
        The scanner lattice, or a dict with ``n_x``, ``n_y``, ``pitch`` (m).
    **params
        The kind's parameters, SI units (or texts with a unit for lengths, ``"3.6mm"``); see
        the kind's parameter model (``KINDS[kind].params``).

    Returns
    -------
    Mask

    Raises
    ------
    ValueError
        Unknown kind, unknown, missing or ill-typed parameters (pydantic's ValidationError is
        a ValueError), and every bad value the kind's function rejects.

    Examples
    --------
    >>> from fpscan.service.plans import Lattice, make_mask
    >>> make_mask("subgrid", {"n_x": 9, "n_y": 9, "pitch": 1e-4}, interval=4).obtained_points
    9
    >>> make_mask("equisteradian", Lattice(41, 41, 1e-4), depth="2mm", n_points=50).obtained_points
    53
    >>> make_mask("random", Lattice(9, 9, 1e-4))
    Traceback (most recent call last):
    ...
    ValueError: mask 'random' needs parameter(s): n_points
    """
    from fpscan.service.plans.lattice import Lattice

    if not isinstance(lattice, Lattice):
        if isinstance(lattice, dict):
            try:
                lattice = Lattice(**lattice)
            except TypeError as exc:
                raise ValueError(f"lattice must have n_x, n_y and pitch: {exc}") from None
        else:
            raise ValueError(f"lattice must be a Lattice or a dict, got {type(lattice).__name__}")
    k = resolve_kind(kind)
    plain = {key: (v.tolist() if hasattr(v, "tolist") else v) for key, v in params.items()}  # numpy -> lists
    try:
        checked = k.params.model_validate(plain)
    except ValidationError as exc:
        raise ValueError(_reason(exc, k)) from None
    return k.function(lattice, **checked.mask_kwargs())


def _reason(exc: ValidationError, k: MaskKind) -> str:
    """One line naming what is wrong with a kind's parameters."""
    errors = exc.errors()
    missing = [str(e["loc"][0]) for e in errors if e["type"] == "missing" and e["loc"]]
    if missing:
        return f"mask {k.name!r} needs parameter(s): {', '.join(missing)}"
    unknown = [str(e["loc"][0]) for e in errors if e["type"] == "extra_forbidden" and e["loc"]]
    if unknown:
        allowed = ", ".join(k.params.model_fields) or "none"
        return f"unknown parameter(s) for mask {k.name!r}: {', '.join(unknown)}; allowed: {allowed}"
    parts = []
    for e in errors:
        loc = ".".join(str(p) for p in e["loc"]) or "params"
        msg = "non-finite value (NaN or infinity)" if e["type"] == "finite_number" else e["msg"]
        parts.append(f"{loc}: {msg}")
    return f"mask {k.name!r}: " + "; ".join(parts)
