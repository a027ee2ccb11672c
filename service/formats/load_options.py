"""The load options a file format declares (``Format.options``): typed pydantic models, as the
methods' options are (``fpscan.service.recon.methods.options``), from which the surfaces are generated —
the upload form of ``POST /api/datasets`` (its fields), ``GET /api/formats`` (each format's
options with their value schema: the web page shows the fields the chosen format takes), the
flags of ``fpscan recon`` / ``unmix`` (``fpscan.clients.cli.recon_options.add_load_flags``) — and every
door refuses an option the chosen format does not take (:func:`check_load_options`).

The mix-ins: :class:`GridSpacing` (``dt``, ``dx``, ``dy``: a k-Wave style array's sampling),
:class:`ArrayKey` (``key``: the array's path in an HDF5 or MAT-file), :class:`ArrayAxes`
(``axes``: the order of a bare array's axes) and
:class:`WavelengthChoice` (``wavelength``: one excitation wavelength of a multi-wavelength
file). A format module declares ``options=`` with one of them or a model combining several.
Field metadata as the methods' (``unit``; ``display_unit``: the web page's unit; ``quantity``: text
with a unit accepted). The speed of sound is every input's
(``fpscan.service.recon.methods.options.SpeedOptions``), not a load option.
"""
from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, model_validator

__all__ = ["KEY_MAX", "WAVELENGTH_MAX", "AXIS_NAMES", "Positive", "LoadOptions", "GridSpacing", "ArrayKey", "ArrayAxes",
           "WavelengthChoice", "KwaveOptions", "NpyOptions", "axes_order", "load_option_fields", "load_option_schemas",
           "check_load_options"]

#: the longest ``key`` accepted (an HDF5 path or a MAT-file variable name)
KEY_MAX = 200
#: the highest wavelength index accepted (a multi-wavelength file's)
WAVELENGTH_MAX = 1023
#: the names an ``axes`` option may use -> the axis (``sensor`` is k-Wave's name of a line of sensors: x, 2-D only)
AXIS_NAMES = {"t": "t", "time": "t", "y": "y", "x": "x", "sensor": "x"}



def _positive(name: str) -> Any:
    """The rule of ``fpscan.service.recon.checks.positive`` as a before-validator (None passes): the
    words every door already uses (``dt must be a finite number > 0, got -1``)."""
    def check(value: Any) -> Any:
        if value is None:
            return None
        from fpscan.service.recon.checks import positive

        return positive(name, value)

    return BeforeValidator(check)


def Positive(name: str) -> Any:  # a type, as the methods' Flag(...)
    """``float > 0 | None`` checked by :func:`_positive` (the field's type in a model).

    Parameters
    ----------
    name : str
        The option's name, in the refusal (``dt must be a finite number > 0, got -1``).

    Returns
    -------
    typing.Annotated
        The field's type: a number > 0 (JSON schema ``exclusiveMinimum: 0``) or None.
    """
    return Annotated[Annotated[float, Field(gt=0)] | None, _positive(name)]


class LoadOptions(BaseModel):
    """The base of a format's load options: unknown names, NaN and infinities refused; a value
    None (JSON null) is the default.

    Attributes
    ----------
    (none of its own; see the mix-ins)

    Examples
    --------
    >>> from fpscan.service.formats.load_options import LoadOptions
    >>> LoadOptions.model_validate({}).model_dump()
    {}
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)

    @model_validator(mode="before")
    @classmethod
    def _null_is_the_default(cls, data: Any) -> Any:
        """``None`` (JSON null, an empty form field) means "the default": such entries are dropped."""
        if isinstance(data, dict):
            return {k: v for k, v in data.items() if v is not None}
        return data


class GridSpacing(LoadOptions):
    """The sampling of an array in k-Wave layout (time first), overriding the file's own.

    Attributes
    ----------
    dt : float or None
        Sample interval in s, > 0.
    dx : float or None
        Lateral spacing along x in m, > 0.
    dy : float or None
        Lateral spacing along y in m (default dx).

    Examples
    --------
    >>> from fpscan.service.formats.load_options import GridSpacing
    >>> GridSpacing(dt=2e-8, dx=1e-4).dy is None
    True
    """

    dt: Positive("dt") = Field(  # type: ignore[valid-type]
        None, description="sample interval, e.g. 20ns (bare numbers are SI)",
        json_schema_extra={"unit": "s", "display_unit": "ns", "quantity": "time"})
    dx: Positive("dx") = Field(  # type: ignore[valid-type]
        None, description="lateral spacing along x, e.g. 100um",
        json_schema_extra={"unit": "m", "display_unit": "µm", "quantity": "length"})
    dy: Positive("dy") = Field(  # type: ignore[valid-type]
        None, description="lateral spacing along y, e.g. 100um (default dx)",
        json_schema_extra={"unit": "m", "display_unit": "µm", "quantity": "length"})


class ArrayKey(LoadOptions):
    """Where the data array is in a container file.

    Attributes
    ----------
    key : str or None
        The HDF5 dataset path (or MAT-file variable) of the data, at most :data:`KEY_MAX`
        characters of ``[A-Za-z0-9_/.-]``; None: the format's default (``sensor_data``,
        ``sensor_data/clean``, ...).

    Examples
    --------
    >>> from fpscan.service.formats.load_options import ArrayKey
    >>> ArrayKey(key="sensor_data/noisy").key
    'sensor_data/noisy'
    """

    key: Annotated[str, Field(max_length=KEY_MAX, pattern=r"^[A-Za-z0-9_/.\-]+$")] | None = Field(
        None, description="HDF5 dataset path (or MAT-file variable) of the data in a k-Wave file")


def axes_order(value: Any) -> str | None:
    """An ``axes`` option as given -> its canonical form (``"y,x,t"``), or None for None.

    Parameters
    ----------
    value : str or None
        The array's axes in order, comma-separated, case and spaces ignored: 2-D ``t,x`` or
        ``x,t`` (k-Wave's ``sensor,time`` is ``x,t``), 3-D any order of ``t``, ``y``, ``x``
        (``time`` is ``t``; ``y,x,t`` is k-Wave's sensor order reshaped).

    Returns
    -------
    str or None
        The axes as ``t``, ``y``, ``x`` joined by commas, in the array's order.

    Raises
    ------
    ValueError
        Not text, an unknown name, a repeated axis, no ``t``, a count other than 2 or 3, 2-D
        axes other than ``t`` and ``x``, ``sensor`` in 3-D.

    Examples
    --------
    >>> from fpscan.service.formats.load_options import axes_order
    >>> axes_order("Y, X, T"), axes_order("sensor,time"), axes_order(None)
    ('y,x,t', 'x,t', None)
    """
    if value is None:
        return None
    usage = ('axes must name the array\'s axes in order, e.g. "y,x,t" or "t,y,x" (3-D), "x,t" or "t,x" '
             '(2-D; k-Wave\'s "sensor,time" is "x,t")')
    if not isinstance(value, str):
        raise ValueError(f"{usage}, got {value!r}")
    names = [part.strip().lower() for part in value.split(",")]
    if any(n not in AXIS_NAMES for n in names) or len(names) not in (2, 3):
        raise ValueError(f"{usage}, got {value!r}")
    axes = [AXIS_NAMES[n] for n in names]
    if len(set(axes)) != len(axes) or "t" not in axes or (len(axes) == 2 and set(axes) != {"t", "x"}) \
            or (len(axes) == 3 and "sensor" in names):
        raise ValueError(f"{usage}, got {value!r}")
    return ",".join(axes)


class ArrayAxes(LoadOptions):
    """The order of an array's axes, for a file that does not say (a ``.npy`` array).

    Attributes
    ----------
    axes : str or None
        The axes in the array's order (:func:`axes_order`: ``"y,x,t"``, ``"t,y,x"``,
        ``"x,t"``, ``"t,x"``, ``"sensor,time"``, ...), kept in canonical form (``"x,t"``);
        None: time first when the array's shape shows it, else refused (the format's rule,
        ``fpscan.service.formats.npy``).

    Examples
    --------
    >>> from fpscan.service.formats.load_options import ArrayAxes
    >>> ArrayAxes(axes="sensor, time").axes
    'x,t'
    """

    axes: Annotated[Annotated[str, Field(max_length=40, pattern=r"^[txy](,[txy]){1,2}$")] | None,
                    BeforeValidator(axes_order)] = Field(
        None, description='the array\'s axis order, e.g. y,x,t (k-Wave\'s sensor order) or t,y,x; 2-D x,t '
                          '(k-Wave\'s sensor,time) or t,x; default: time first where the shape shows it')


class WavelengthChoice(LoadOptions):
    """One excitation wavelength of a multi-wavelength file.

    Attributes
    ----------
    wavelength : int or None
        Its index, 0..:data:`WAVELENGTH_MAX` (None: the first); out of the file's range: a
        ValueError naming the file's wavelengths.

    Examples
    --------
    >>> from fpscan.service.formats.load_options import WavelengthChoice
    >>> WavelengthChoice(wavelength=1).wavelength
    1
    """

    wavelength: Annotated[int, Field(ge=0, le=WAVELENGTH_MAX)] | None = Field(
        None, description="index of the excitation wavelength to read (default: the first)")


class KwaveOptions(GridSpacing, ArrayKey):
    """The load options of a k-Wave file (``kwave-hdf5``, ``kwave-mat``): the array's sampling and
    where it is.

    Attributes
    ----------
    dt, dx, dy, key
        As :class:`GridSpacing`'s and :class:`ArrayKey`'s.

    Examples
    --------
    >>> from fpscan.service.formats.load_options import KwaveOptions
    >>> list(KwaveOptions.model_fields)
    ['key', 'dt', 'dx', 'dy']
    """


class NpyOptions(ArrayAxes, GridSpacing):
    """The load options of a ``.npy`` array: its sampling and the order of its axes.

    Attributes
    ----------
    dt, dx, dy, axes
        As :class:`GridSpacing`'s and :class:`ArrayAxes`'.

    Examples
    --------
    >>> from fpscan.service.formats.load_options import NpyOptions
    >>> list(NpyOptions.model_fields)
    ['dt', 'dx', 'dy', 'axes']
    """


def load_option_fields() -> dict[str, Any]:
    """Every load option of the registered formats: name -> its pydantic ``FieldInfo`` (the first
    format that declares it), in registration order.

    Returns
    -------
    dict
        ``{name: FieldInfo}``.

    Examples
    --------
    >>> from fpscan.service.formats.load_options import load_option_fields
    >>> {"dt", "dx", "dy", "axes", "key", "wavelength"} <= set(load_option_fields())
    True
    """
    from fpscan.service.formats.registry import FORMATS

    out: dict[str, Any] = {}
    for fmt in FORMATS.values():
        if fmt.options is not None:
            for name, info in fmt.options.model_fields.items():
                out.setdefault(name, info)
    return out


def load_option_schemas() -> list[dict[str, Any]]:
    """Every load option of the registered formats as the surfaces read them: per option ``name``,
    ``description``, ``schema`` (its value's JSON schema with ``unit`` and ``quantity``, as
    ``fpscan.service.recon.methods.option_schemas`` gives a method's) and ``formats`` (the names of the
    formats that take it), in registration order.

    Returns
    -------
    list of dict
        One per option name.

    Examples
    --------
    >>> from fpscan.service.formats.load_options import load_option_schemas
    >>> dt = next(o for o in load_option_schemas() if o["name"] == "dt")
    >>> dt["schema"]["unit"], "npy" in dt["formats"]
    ('s', True)
    """
    from fpscan.service.formats.registry import FORMATS
    from fpscan.service.recon.methods import option_schemas

    out: dict[str, dict[str, Any]] = {}
    for fmt in FORMATS.values():
        if fmt.options is None:
            continue
        for o in option_schemas(fmt.options):
            entry = out.setdefault(o["name"], {"name": o["name"], "description": o["description"],
                                               "schema": o["schema"], "formats": []})
            entry["formats"].append(fmt.name)
    return list(out.values())


def check_load_options(format: str, options: dict[str, Any]) -> dict[str, Any]:
    """``options`` (None = not given) checked against the load options ``format`` declares.

    Parameters
    ----------
    format : str
        A registered format's name.
    options : dict
        Load options as given (SI numbers; None: not given).

    Returns
    -------
    dict
        The given options, validated (converted to the fields' types).

    Raises
    ------
    ValueError
        An unknown format; an option the format does not take (naming the ones it takes); a value
        its field refuses (the field's rule).

    Examples
    --------
    >>> from fpscan.service.formats.load_options import check_load_options
    >>> check_load_options("npy", {"dt": 2e-8, "key": None})
    {'dt': 2e-08}
    >>> check_load_options("npy", {"key": "sensor_data"})
    Traceback (most recent call last):
    ...
    ValueError: format npy takes no option key (its options: dt, dx, dy, axes)
    """
    from fpscan.service.formats.registry import FORMATS

    fmt = FORMATS.get(format)
    if fmt is None:
        raise ValueError(f"format must be one of {', '.join(FORMATS)}, got {format!r}")
    given = {k: v for k, v in options.items() if v is not None}
    takes = tuple(fmt.options.model_fields) if fmt.options is not None else ()
    foreign = sorted(k for k in given if k not in takes)
    if foreign:
        said = f"its options: {', '.join(takes)}" if takes else "it takes none"
        raise ValueError(f"format {fmt.name} takes no option {', '.join(foreign)} ({said})")
    if fmt.options is None:
        return {}
    try:
        checked = fmt.options.model_validate(given)
    except ValidationError as exc:
        err = exc.errors()[0]
        name = ".".join(str(p) for p in err["loc"]) or "options"
        msg = str(err["msg"]).removeprefix("Value error, ")
        raise ValueError(msg if msg.startswith(name) else f"{name}: {msg}") from None
    return {k: v for k, v in checked.model_dump().items() if k in given}
