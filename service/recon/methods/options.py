"""The reconstruction options shared by several methods: typed fields with their range,
unit and default, each refused by the kernel's own rule.

A method's options model (:class:`MethodOptions` and the mix-ins below) is what every door
checks a request with: :func:`fpscan.service.pipeline.reconstruct`, ``fpscan recon`` / ``unmix``
(their flags are generated from these fields) and ``POST /api/reconstructions`` (its body a
union keyed on ``method`` of the methods' models). Each bounded field runs the kernel's
rule (:mod:`fpscan.service.recon.checks`) before its type and range, so every door refuses a value
with the kernel's words (``eps must be in [1e-14, 1e-1], got 5e-15``); the ranges are
those of :mod:`fpscan.service.recon.limits`, stated in the JSON schema (``minimum``/``maximum``).

Field metadata (``json_schema_extra``) read by the generated surfaces: ``unit`` (SI unit
of the value, shown by the CLI and the docs table), ``quantity`` (``length`` or ``time``:
every door accepts text with a unit, ``"20um"``), ``display_unit`` (the unit the web page's
field is shown in and reads a bare number in, e.g. ``µm`` for ``dz``; default ``unit``),
``flag`` (a CLI flag other than ``--name-with-dashes``), ``derived`` (what a default of
``None`` is, e.g. ``n_t``).

Every option type admits ``None``: "the method's default" (JSON null), which a method's model
replaces by its field's default. This module imports no numpy: the rules load their kernel checks on first use.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, model_validator

from fpscan.constants import C_AUTOFOCUS_LIMITS, C_AUTOFOCUS_RANGE, C_DEFAULT, C_LIMITS, C_PLAUSIBLE
from fpscan.service.recon.limits import (
    DEFAULT_DEVICE,
    DEFAULT_DTYPE,
    DEFAULT_EPS,
    DEVICES,
    DTYPES,
    DZ_RANGE,
    EPS_RANGE,
    N_Z_RANGE,
    UPSAMPLE_RANGE,
)

__all__ = ["DEPRECATED_NAMES", "renamed_options", "SpeedOptions", "plausible_speeds", "speed_schema", "MethodOptions", "NufftOptions", "UpsampleOption", "PositivityOption", "DepthOptions", "DEPTH_ROWS_DEFAULT", "DEPTH_SPACING_DEFAULT", "Eps",
           "Upsample", "NZ", "Dz", "Dtype", "Flag", "kernel_rule", "check_flag", "check_dtype_name", "Device",
           "DeviceOption", "check_device_name"]


def kernel_rule(name: str) -> Callable[[Any], Any]:
    """The rule ``fpscan.service.recon.checks.<name>`` as a before-validator: ``None`` (the
    default) passes, anything else is checked (``OptionError``, a ValueError naming the
    option and its range) and converted (a float, an int).

    Parameters
    ----------
    name : str
        A rule of :mod:`fpscan.service.recon.checks` (``"check_eps"``, ``"check_upsample"``,
        ``"check_n_z"``, ``"check_dz"``, ``"check_lam"``, ``"check_max_iter"``,
        ``"check_time_limit"``).

    Returns
    -------
    callable
        ``apply(value)``: ``None`` unchanged, else the rule's checked value (SI units); its
        ``__name__`` is ``name``. ``fpscan.service.recon.checks`` is imported on the first call.

    Raises
    ------
    fpscan.service.recon.checks.OptionError
        From ``apply``: the value is outside the rule (the message names the option and its
        range).

    Examples
    --------
    >>> from fpscan.service.recon.methods.options import kernel_rule
    >>> eps = kernel_rule("check_eps")
    >>> eps(None) is None, eps("1e-3"), kernel_rule("check_upsample")(2.0)
    (True, 0.001, 2)
    >>> eps(5e-15)
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: eps must be in [1e-14, 1e-1], got 5e-15
    """
    def apply(value: Any) -> Any:
        if value is None:
            return None
        import fpscan.service.recon.checks as checks

        return getattr(checks, name)(value)

    apply.__name__ = name
    return apply


def check_flag(name: str) -> Callable[[Any], Any]:
    """The rule of a true/false option: a bool (NumPy's too) or the integers 0 and 1;
    anything else (``"yes"``, 2, 0.5) is an ``OptionError`` naming the option.

    Parameters
    ----------
    name : str
        The option's name, used in the error message.

    Returns
    -------
    callable
        ``apply(value)`` -> ``bool`` (``None`` unchanged).

    Raises
    ------
    fpscan.service.recon.checks.OptionError
        From ``apply``: anything but ``None``, a bool or the integers 0 and 1.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.methods.options import check_flag
    >>> rule = check_flag("positivity")
    >>> rule(1), rule(np.bool_(False)), rule(None)
    (True, False, None)
    >>> rule("yes")
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: positivity must be true or false, got 'yes'
    """
    def apply(value: Any) -> Any:
        if value is None or isinstance(value, bool):
            return value
        if type(value).__module__ == "numpy" and type(value).__name__ in ("bool", "bool_"):  # numpy.bool_
            return bool(value)
        if isinstance(value, int) and value in (0, 1):
            return bool(value)
        from fpscan.service.recon.checks import OptionError

        raise OptionError(f"{name} must be true or false, got {value!r}")

    return apply


def check_dtype_name(value: Any) -> Any:
    """The rule of ``dtype``: one of :data:`fpscan.service.recon.limits.DTYPES`, given as its name
    or as a NumPy dtype / scalar type (``np.float64``), returned as the name.

    Parameters
    ----------
    value : str, numpy dtype, type or None
        The precision asked for; ``None`` (the default) passes.

    Returns
    -------
    str or None
        ``"float32"`` or ``"float64"`` (``None`` unchanged).

    Raises
    ------
    fpscan.service.recon.checks.OptionError
        Any other dtype, or something that names none.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.methods.options import check_dtype_name
    >>> check_dtype_name(np.float64), check_dtype_name(np.dtype("float32")), check_dtype_name("float32")
    ('float64', 'float32', 'float32')
    >>> check_dtype_name("int8")
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: dtype must be one of float32, float64, got 'int8'
    """
    if value is None or (isinstance(value, str) and value in DTYPES):
        return value
    from fpscan.service.recon.checks import OptionError

    name = None
    if not isinstance(value, (str, bytes)):  # text is checked as text: NumPy's dtype parser is never
        try:  # handed a request's string ("(1,2" raised SyntaxError in it; "f4,f4,..." took seconds)
            import numpy as np

            name = np.dtype(value).name
        except (TypeError, ValueError):
            name = None
    if name not in DTYPES:
        shown = repr(value) if len(repr(value)) <= 64 else repr(value)[:60] + "...'"
        raise OptionError(f"dtype must be one of {', '.join(DTYPES)}, got {shown}")
    return name


#: NUFFT tolerance (relative accuracy of the non-uniform FFTs), in ``EPS_RANGE``
Eps = Annotated[Annotated[float, Field(ge=EPS_RANGE[0], le=EPS_RANGE[1])] | None,
                BeforeValidator(kernel_rule("check_eps"))]
#: lateral upsampling factor, in ``UPSAMPLE_RANGE``
Upsample = Annotated[Annotated[int, Field(ge=UPSAMPLE_RANGE[0], le=UPSAMPLE_RANGE[1])] | None,
                     BeforeValidator(kernel_rule("check_upsample"))]
#: output depth samples (None: the default, ``fpscan.service.recon.depth``), in ``N_Z_RANGE``
NZ = Annotated[Annotated[int, Field(ge=N_Z_RANGE[0], le=N_Z_RANGE[1])] | None,
               BeforeValidator(kernel_rule("check_n_z"))]
#: output depth spacing in m (None: the default, ``fpscan.service.recon.depth``), in ``DZ_RANGE``
Dz = Annotated[Annotated[float, Field(ge=DZ_RANGE[0], le=DZ_RANGE[1])] | None,
               BeforeValidator(kernel_rule("check_dz"))]
#: working and output precision
Dtype = Annotated[Literal["float32", "float64"] | None, BeforeValidator(check_dtype_name)]


def Flag(name: str) -> Any:  # a type, named as one
    """A true/false option named ``name`` (:func:`check_flag`).

    Parameters
    ----------
    name : str
        The option's name, used in the error message.

    Returns
    -------
    typing.Annotated
        ``bool | None`` with :func:`check_flag` as its before-validator: the type of a
        field of an options model.

    Examples
    --------
    >>> from pydantic import TypeAdapter, ValidationError
    >>> from fpscan.service.recon.methods.options import Flag
    >>> debias = TypeAdapter(Flag("debias"))
    >>> debias.validate_python(0), debias.validate_python(True)
    (False, True)
    >>> try:
    ...     debias.validate_python(2)
    ... except ValidationError as exc:
    ...     print(exc.errors()[0]["msg"])
    Value error, debias must be true or false, got 2
    """
    return Annotated[bool | None, BeforeValidator(check_flag(name))]


def plausible_speeds(sep: str = "-") -> str:
    """The speeds of sound accepted without ``force`` (``fpscan.constants.C_PLAUSIBLE``, tissue
    and water) as text for a message, a help line or a form label.

    Parameters
    ----------
    sep : str, optional
        Between the two ends (``"-"``; ``"–"`` for a page, ``" to "`` for a sentence).

    Returns
    -------
    str
        ``"1000-2000"`` (m/s, without the unit).

    Examples
    --------
    >>> from fpscan.service.recon.methods.options import plausible_speeds
    >>> plausible_speeds(), plausible_speeds(" to ")
    ('1000-2000', '1000 to 2000')
    """
    return f"{C_PLAUSIBLE[0]:g}{sep}{C_PLAUSIBLE[1]:g}"


Speed = Annotated[float, Field(gt=0)]
AutofocusSpeed = Annotated[float, Field(ge=C_AUTOFOCUS_LIMITS[0], le=C_AUTOFOCUS_LIMITS[1])]

#: option names of an earlier release, still accepted for one release: old name -> the one name
#: (a ``DeprecationWarning`` names the new one; the speed of sound is k-Wave's ``medium.sound_speed``,
#: the iteration cap scikit-learn's and SciPy's ``max_iter``)
DEPRECATED_NAMES: dict[str, str] = {"c": "sound_speed", "c_range": "sound_speed_range", "iterations": "max_iter"}


def renamed_options(data: dict, fields: Any, *, stacklevel: int = 6) -> dict:
    """``data`` with each old option name of :data:`DEPRECATED_NAMES` whose new name is one of
    ``fields`` replaced by the new name, warning once per name (``DeprecationWarning`` naming
    the new one). Both names at once is an ``OptionError``.

    Parameters
    ----------
    data : dict
        Option name -> value, as given.
    fields : collection of str
        The options model's field names.
    stacklevel : int, optional
        Of the warning (the caller's line where it is the library's).

    Returns
    -------
    dict
        A new dict (``data`` itself when nothing was renamed).

    Raises
    ------
    fpscan.service.recon.checks.OptionError
        An old name and its new one both given.

    Examples
    --------
    >>> import warnings
    >>> from fpscan.service.recon.methods.options import renamed_options
    >>> with warnings.catch_warnings(record=True) as seen:
    ...     warnings.simplefilter("always")
    ...     renamed_options({"c": 1480.0, "eps": 1e-6}, {"sound_speed", "eps"})
    {'sound_speed': 1480.0, 'eps': 1e-06}
    >>> str(seen[0].message)
    'option c is deprecated: use sound_speed (c is refused from the next release)'
    """
    old = [k for k in data if k in DEPRECATED_NAMES and DEPRECATED_NAMES[k] in fields]
    if not old:
        return data
    import warnings

    for name in old:
        new = DEPRECATED_NAMES[name]
        if new in data:
            from fpscan.service.recon.checks import OptionError

            raise OptionError(f"give {new} or its deprecated name {name}, not both")
        warnings.warn(f"option {name} is deprecated: use {new} ({name} is refused from the next release)",
                      DeprecationWarning, stacklevel=stacklevel)
    return {DEPRECATED_NAMES[k] if k in old else k: v for k, v in data.items()}


class SpeedOptions(BaseModel):
    """The speed of sound, every method's options (:class:`MethodOptions` inherits them): its unit,
    bounds and default, the autofocus interval and ``force``. ``GET /api/reconstructions/methods``
    lists its value schema (:func:`speed_schema`, from which the web page's fields and labels are
    built); the flags of ``fpscan recon`` / ``unmix`` (``--sound-speed``, ``--sound-speed-range``,
    ``--force``) and every message about a speed read it; the numbers are ``fpscan.constants``'
    (``C_PLAUSIBLE`` without ``force``, ``C_LIMITS`` with it, ``C_AUTOFOCUS_RANGE`` the search's
    default); the rule is ``fpscan.driver.units.check_speeds``. The name is k-Wave's
    (``medium.sound_speed``); ``c`` and ``c_range``, an earlier release's, are accepted with a
    ``DeprecationWarning`` (:data:`DEPRECATED_NAMES`).

    Attributes
    ----------
    sound_speed : float, "auto" or None
        Speed of sound in m/s; ``"auto"``: the speed of sharpest focus searched within
        ``sound_speed_range``; None: the input's (else ``fpscan.constants.C_DEFAULT``). Text with a
        unit is accepted (``"1.5 km/s"``).
    sound_speed_range : tuple of float or None
        The autofocus search interval (c_min, c_max) in m/s, each within ``C_AUTOFOCUS_LIMITS``;
        None: ``C_AUTOFOCUS_RANGE``. Only with ``sound_speed="auto"``.
    force : bool
        Accept a speed (or an end of the interval) outside ``C_PLAUSIBLE`` (another medium).

    Examples
    --------
    >>> from pydantic import ValidationError
    >>> from fpscan.service.recon.methods.options import SpeedOptions
    >>> SpeedOptions.model_validate({"sound_speed": "1.48 km/s"}).sound_speed
    1480.0
    >>> SpeedOptions.model_fields["sound_speed"].json_schema_extra["unit"]
    'm/s'
    >>> try:
    ...     SpeedOptions(sound_speed_range=(1450, 1600))
    ... except ValidationError as exc:
    ...     print(exc.errors()[0]["msg"])
    Value error, sound_speed_range is the autofocus search interval: it needs sound_speed='auto', got None
    """

    sound_speed: Speed | Literal["auto"] | None = Field(
        None, description=f"speed of sound, m/s ({plausible_speeds()} unless force, "
                          f"{C_LIMITS[0]:g}-{C_LIMITS[1]:g} with it), or 'auto': the speed of sharpest focus (Tenenbaum "
                          f"sharpness, searched within sound_speed_range); default: the input's, else {C_DEFAULT:g}",
        json_schema_extra={"unit": "m/s", "quantity": "speed", "flag": "--sound-speed"})
    sound_speed_range: tuple[AutofocusSpeed, AutofocusSpeed] | None = Field(
        None, description="autofocus search interval (c_min, c_max), m/s (default "
                          f"{C_AUTOFOCUS_RANGE[0]:g}-{C_AUTOFOCUS_RANGE[1]:g}); with sound_speed 'auto' only",
        json_schema_extra={"unit": "m/s", "quantity": "speed", "flag": "--sound-speed-range"})
    force: bool = Field(False, description=f"accept a sound_speed (or sound_speed_range) outside {plausible_speeds()} "
                                           "m/s (a medium other than tissue or water); without it such a value is "
                                           "refused as a likely unit mistake (fpscan.driver.units.check_speeds)")

    @model_validator(mode="before")
    @classmethod
    def _names_and_units(cls, data: Any) -> Any:
        """An earlier release's names (:data:`DEPRECATED_NAMES`, warned), ``None`` (JSON null:
        "the default") dropped, and numbers typed with a unit (``"30um"``, ``"600s"``,
        ``"1.5 km/s"``) for every field whose schema names a ``quantity``: to SI by the one
        parser (``fpscan.driver.units.parse_quantity``); numbers are SI already."""
        if not isinstance(data, dict):
            return data
        data = renamed_options({k: v for k, v in data.items() if v is not None}, cls.model_fields)
        for name, value in list(data.items()):
            field = cls.model_fields.get(name)
            extra = field.json_schema_extra if field is not None and isinstance(field.json_schema_extra, dict) else {}
            kind = extra.get("quantity")
            if kind is None:
                continue
            from fpscan.driver.units import parse_quantity

            if isinstance(value, str) and not (name == "sound_speed" and value == "auto"):
                try:
                    data[name] = parse_quantity(value, str(kind), name=name)
                except ValueError as exc:
                    if name != "sound_speed":
                        raise
                    raise ValueError(f"sound_speed must be a speed (m/s, or with a unit: 1.5 km/s) or 'auto', "
                                     f"got {value!r}") from exc
            elif isinstance(value, (list, tuple)):
                data[name] = [parse_quantity(v, str(kind), name=name) if isinstance(v, str) else v for v in value]
        return data

    @model_validator(mode="after")
    def _speed_rule(self) -> Any:
        """The speed-of-sound rule (``fpscan.driver.units.check_speeds``: a likely unit mistake
        unless ``force``; forced, within ``fpscan.constants.C_LIMITS``); an interval needs
        ``"auto"`` and is checked by ``fpscan.service.recon.checks.check_sound_speed_range``."""
        from fpscan.driver.units import check_speeds

        check_speeds(sound_speed=self.sound_speed, sound_speed_range=self.sound_speed_range, force=self.force)
        if self.sound_speed_range is not None:  # never silently unused
            if self.sound_speed != "auto":
                from fpscan.service.recon.checks import OptionError

                raise OptionError("sound_speed_range is the autofocus search interval: it needs "
                                  f"sound_speed='auto', got {self.sound_speed!r}")
            from fpscan.service.recon.checks import check_sound_speed_range

            check_sound_speed_range(self.sound_speed_range)
        return self


def speed_schema() -> dict:
    """The value schema of ``sound_speed`` as ``GET /api/reconstructions/methods`` lists it (the web
    page's speed fields and labels): a number in m/s within ``C_PLAUSIBLE``, or ``"auto"``.

    Returns
    -------
    dict
        ``{"anyOf": [number schema, {"enum": ["auto"]}], "unit": "m/s", "quantity": "speed",
        "limits": [lo, hi]}`` (``limits``: ``C_LIMITS``, what ``force`` allows).

    Examples
    --------
    >>> from fpscan.service.recon.methods.options import speed_schema
    >>> s = speed_schema()
    >>> s["anyOf"][0]["minimum"], s["anyOf"][0]["maximum"], s["unit"]
    (1000.0, 2000.0, 'm/s')
    """
    return {"anyOf": [{"type": "number", "minimum": C_PLAUSIBLE[0], "maximum": C_PLAUSIBLE[1]},
                      {"type": "string", "enum": ["auto"]}], "unit": "m/s", "quantity": "speed",
            "limits": [C_LIMITS[0], C_LIMITS[1]]}


class MethodOptions(SpeedOptions):
    """The options every method takes: the speed of sound (:class:`SpeedOptions`: ``sound_speed``,
    ``sound_speed_range``, ``force``) and the precision. A method's options model subclasses it
    (with the mix-ins below); an instance is what the library's
    :func:`fpscan.service.pipeline.reconstruct`, a job's record and the method's ``run`` carry.
    Unknown names, NaN and infinities are refused.

    A frozen pydantic model; a value ``None`` (JSON null) is dropped before validation, so
    it means the field's default.

    Attributes
    ----------
    sound_speed, sound_speed_range, force
        :class:`SpeedOptions`'.
    dtype : {"float32", "float64"}
        Working and output precision (default ``fpscan.service.recon.limits.DEFAULT_DTYPE``,
        ``"float32"``); a NumPy dtype or scalar type is accepted and stored as its name.

    Examples
    --------
    >>> import numpy as np
    >>> from pydantic import ValidationError
    >>> from fpscan.service.recon.methods.options import MethodOptions
    >>> MethodOptions().dtype, MethodOptions(dtype=np.float64).dtype
    ('float32', 'float64')
    >>> MethodOptions.model_validate({"dtype": None}).dtype  # null: the default
    'float32'
    >>> for bad in ({"dtype": "int8"}, {"eps": 1e-6}):  # eps is no option of this model
    ...     try:
    ...         MethodOptions.model_validate(bad)
    ...     except ValidationError as exc:
    ...         print(exc.errors()[0]["msg"])
    Value error, dtype must be one of float32, float64, got 'int8'
    Extra inputs are not permitted
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)

    dtype: Dtype = Field(DEFAULT_DTYPE, description="working and output precision")


class NufftOptions(BaseModel):
    """Mix-in: the NUFFT tolerance of the methods that use non-uniform FFTs.

    Attributes
    ----------
    eps : float
        NUFFT tolerance (relative accuracy, dimensionless) in ``EPS_RANGE`` = [1e-14, 1e-1],
        default ``DEFAULT_EPS`` = 1e-6 (rule: ``fpscan.service.recon.checks.check_eps``).

    Examples
    --------
    >>> from pydantic import ValidationError
    >>> from fpscan.service.recon.methods.options import NufftOptions
    >>> NufftOptions().eps, NufftOptions(eps="1e-8").eps
    (1e-06, 1e-08)
    >>> try:
    ...     NufftOptions(eps=5e-15)
    ... except ValidationError as exc:
    ...     print(exc.errors()[0]["msg"])
    Value error, eps must be in [1e-14, 1e-1], got 5e-15
    """

    eps: Eps = Field(DEFAULT_EPS, description="NUFFT tolerance (relative accuracy of the non-uniform FFTs)",
                     json_schema_extra={"unit": "1"})


class UpsampleOption(BaseModel):
    """Mix-in: lateral upsampling of the output grid.

    Attributes
    ----------
    upsample : int
        Lateral upsampling factor of the output grid in ``UPSAMPLE_RANGE`` = 1..8
        (dimensionless), default 1 (rule: ``fpscan.service.recon.checks.check_upsample``).

    Examples
    --------
    >>> from pydantic import ValidationError
    >>> from fpscan.service.recon.methods.options import UpsampleOption
    >>> UpsampleOption().upsample, UpsampleOption(upsample=8).upsample
    (1, 8)
    >>> try:
    ...     UpsampleOption(upsample=9)
    ... except ValidationError as exc:
    ...     print(exc.errors()[0]["msg"])
    Value error, upsample must be an integer in 1..8, got 9
    """

    upsample: Upsample = Field(1, description="lateral upsampling factor of the output grid",
                               json_schema_extra={"unit": "1"})


class PositivityOption(BaseModel):
    """Mix-in: clip negative p0 to 0 (default off).

    Attributes
    ----------
    positivity : bool
        Clip negative p0 to 0 (default False; rule: :func:`check_flag`).

    Examples
    --------
    >>> from pydantic import ValidationError
    >>> from fpscan.service.recon.methods.options import PositivityOption
    >>> PositivityOption().positivity, PositivityOption(positivity=1).positivity
    (False, True)
    >>> try:
    ...     PositivityOption(positivity="yes")
    ... except ValidationError as exc:
    ...     print(exc.errors()[0]["msg"])
    Value error, positivity must be true or false, got 'yes'
    """

    positivity: Flag("positivity") = Field(False, description="clip negative p0 to 0")  # type: ignore[valid-type]


def check_device_name(value: Any) -> Any:
    """The rule of ``device``: one of ``"auto"``, ``"cpu"``, ``"cuda"``
    (`fpscan.service.recon.device.DEVICES`).

    Parameters
    ----------
    value : str or None

    Returns
    -------
    str or None
        ``value`` (None: the default).

    Raises
    ------
    fpscan.service.recon.checks.OptionError
        Anything else.

    Examples
    --------
    >>> from fpscan.service.recon.methods.options import check_device_name
    >>> check_device_name("cuda")
    'cuda'
    >>> check_device_name("tpu")
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: device must be one of auto, cpu, cuda, got 'tpu'
    """
    if value is None or (isinstance(value, str) and value in DEVICES):
        return value
    from fpscan.service.recon.checks import OptionError

    shown = repr(value) if len(repr(value)) <= 64 else repr(value)[:60] + "...'"
    raise OptionError(f"device must be one of {', '.join(DEVICES)}, got {shown}")


#: where a reconstruction runs (`fpscan.service.recon.device`)
Device = Annotated[Literal["auto", "cpu", "cuda"] | None, BeforeValidator(check_device_name)]


class DeviceOption(BaseModel):
    """Mix-in: where the method runs, ``"auto"`` (default: the GPU where CuPy sees one and the
    job fits it, else the CPU), ``"cpu"`` or ``"cuda"`` (`fpscan.service.recon.device`).

    Attributes
    ----------
    device : {"auto", "cpu", "cuda"}
        Default ``"auto"``; the result's ``params["device"]`` says which ran.

    Examples
    --------
    >>> from fpscan.service.recon.methods.options import DeviceOption
    >>> DeviceOption().device, DeviceOption(device="cpu").device
    ('auto', 'cpu')
    """

    device: Device = Field(DEFAULT_DEVICE, description="where it runs: auto (the GPU where one fits), cpu or cuda")


#: the default depth grid in words (``fpscan.service.recon.depth``, every method's rule): the rows, the spacing
DEPTH_ROWS_DEFAULT = "down to c·t_last, as deep as the record reaches"
DEPTH_SPACING_DEFAULT = "the lateral pitch, c·dt where that is finer"


class DepthOptions(BaseModel):
    """Mix-in: the output depth grid (``n_z`` samples at ``dz``).

    Attributes
    ----------
    n_z : int or None
        Output depth samples in ``N_Z_RANGE`` = 2..65536; None (default): as deep as the record
        reaches, c·t_last (``fpscan.service.recon.depth``, every method's rule).
    dz : float or None
        Output depth spacing in m, in ``DZ_RANGE`` = [1e-9, 0.1] m; None (default): the lateral
        pitch, or c·dt where the pitch is finer. One of the two given alone keeps the other's
        default: ``n_z`` alone is that many rows of the pitch.

    Examples
    --------
    >>> from pydantic import ValidationError
    >>> from fpscan.service.recon.methods.options import DepthOptions
    >>> DepthOptions().n_z is None, DepthOptions(n_z=64, dz="2e-5").dz  # m
    (True, 2e-05)
    >>> for bad in ({"n_z": 1}, {"dz": 1.0}):
    ...     try:
    ...         DepthOptions(**bad)
    ...     except ValidationError as exc:
    ...         print(exc.errors()[0]["msg"])
    Value error, n_z must be an integer in 2..65536, got 1
    Value error, dz must be in [1e-09, 0.1] m, got 1.0
    """

    n_z: NZ = Field(None, description="output depth samples (given alone: rows of the default dz)",
                    json_schema_extra={"unit": "1", "derived": DEPTH_ROWS_DEFAULT})
    dz: Dz = Field(None, description="output depth spacing; with the input's c·t_last it sets the working depth "
                   "rows, counted in the memory admission",
                   json_schema_extra={"unit": "m", "display_unit": "µm", "quantity": "length",
                                      "derived": DEPTH_SPACING_DEFAULT})
