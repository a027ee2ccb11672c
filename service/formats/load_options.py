"""The load options a file format declares (``Format.options``): typed pydantic models, as the
methods' options are (``fpscan.service.recon.methods.options``), from which the surfaces are generated —
the upload form of ``POST /api/datasets`` (its fields), ``GET /api/formats`` (each format's
options with their value schema: the web page shows the fields the chosen format takes), the
flags of ``fpscan recon`` / ``unmix`` (``fpscan.clients.cli.recon_options.add_load_flags``) — and every
door refuses an option the chosen format does not take (:func:`check_load_options`).

The mix-ins: :class:`GridSpacing` (``dt``, ``dx``, ``dy``: a k-Wave style array's sampling),
:class:`ArrayKey` (``key``: the array's path in an HDF5 or MAT-file) and
:class:`WavelengthChoice` (``wavelength``: one excitation wavelength of a multi-wavelength
file). A format module declares ``options=`` with one of them or a model combining several.
Field metadata as the methods' (``unit``, ``quantity``: text with a unit accepted). The speed of
sound is every input's (``fpscan.service.recon.methods.options.SpeedOptions``), not a load option.
"""
from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, model_validator

__all__ = ["KEY_MAX", "WAVELENGTH_MAX", "Positive", "LoadOptions", "GridSpacing", "ArrayKey", "WavelengthChoice", "KwaveOptions", "load_option_fields", "load_option_schemas", "check_load_options"]

#: the longest ``key`` accepted (an HDF5 path or a MAT-file variable name)
KEY_MAX = 200
#: the highest wavelength index accepted (a multi-wavelength file's)
WAVELENGTH_MAX = 1023



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
        json_schema_extra={"unit": "s", "quantity": "time"})
    dx: Positive("dx") = Field(  # type: ignore[valid-type]
        None, description="lateral spacing along x, e.g. 100um",
        json_schema_extra={"unit": "m", "quantity": "length"})
    dy: Positive("dy") = Field(  # type: ignore[valid-type]
        None, description="lateral spacing along y, e.g. 100um (default dx)",
        json_schema_extra={"unit": "m", "quantity": "length"})


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
    >>> {"dt", "dx", "dy", "key", "wavelength"} <= set(load_option_fields())
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
    ValueError: format npy takes no option key (its options: dt, dx, dy)
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
