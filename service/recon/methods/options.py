"""The reconstruction options shared by several methods: typed fields with their range,
unit and default, each refused by the kernel's own rule.

A method's options model (:class:`MethodOptions` and the mix-ins below) is what every door
checks a request with: :func:`service.pipeline.reconstruct`, ``fpscan recon`` / ``unmix``
(their flags are generated from these fields) and ``POST /api/reconstructions`` (its
``ReconParams`` is the union of the methods' fields). Each bounded field runs the kernel's
rule (:mod:`service.recon.checks`) before its type and range, so every door refuses a value
with the kernel's words (``eps must be in [1e-14, 1e-1], got 5e-15``); the ranges are
those of :mod:`service.recon.limits`, stated in the JSON schema (``minimum``/``maximum``).

Field metadata (``json_schema_extra``) read by the generated surfaces: ``unit`` (SI unit
of the value, shown by the CLI, the web page and the docs table), ``quantity`` (``length``
or ``time``: the CLI and the API accept text with a unit, ``"20um"``), ``flag`` (a CLI flag
other than ``--name-with-dashes``), ``derived`` (what a default of ``None`` is, e.g. ``n_t``).

Every option type admits ``None``: "the method's default" (JSON null), which a method's model
replaces by its field's default. This module imports no numpy: the rules load their kernel checks on first use.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, model_validator

from service.recon.limits import (
    DEFAULT_DTYPE,
    DEFAULT_EPS,
    DTYPES,
    DZ_RANGE,
    EPS_RANGE,
    N_Z_RANGE,
    UPSAMPLE_RANGE,
)

__all__ = ["MethodOptions", "NufftOptions", "UpsampleOption", "PositivityOption", "DepthOptions", "Eps",
           "Upsample", "NZ", "Dz", "Dtype", "Flag", "kernel_rule", "check_flag", "check_dtype_name"]


def kernel_rule(name: str) -> Callable[[Any], Any]:
    """The rule ``service.recon.checks.<name>`` as a before-validator: ``None`` (the
    default) passes, anything else is checked (``OptionError``, a ValueError naming the
    option and its range) and converted (a float, an int)."""
    def apply(value: Any) -> Any:
        if value is None:
            return None
        from service.recon import checks

        return getattr(checks, name)(value)

    apply.__name__ = name
    return apply


def check_flag(name: str) -> Callable[[Any], Any]:
    """The rule of a true/false option: a bool (NumPy's too) or the integers 0 and 1;
    anything else (``"yes"``, 2, 0.5) is an ``OptionError`` naming the option."""
    def apply(value: Any) -> Any:
        if value is None or isinstance(value, bool):
            return value
        if type(value).__module__ == "numpy" and type(value).__name__ in ("bool", "bool_"):  # numpy.bool_
            return bool(value)
        if isinstance(value, int) and value in (0, 1):
            return bool(value)
        from service.recon.checks import OptionError

        raise OptionError(f"{name} must be true or false, got {value!r}")

    return apply


def check_dtype_name(value: Any) -> Any:
    """The rule of ``dtype``: one of :data:`service.recon.limits.DTYPES`, given as its name
    or as a NumPy dtype / scalar type (``np.float64``), returned as the name."""
    if value is None or (isinstance(value, str) and value in DTYPES):
        return value
    from service.recon.checks import OptionError

    try:
        import numpy as np

        name = np.dtype(value).name
    except TypeError:
        name = None
    if name not in DTYPES:
        raise OptionError(f"dtype must be one of {', '.join(DTYPES)}, got {value!r}")
    return name


#: NUFFT tolerance (relative accuracy of the non-uniform FFTs), in ``EPS_RANGE``
Eps = Annotated[Annotated[float, Field(ge=EPS_RANGE[0], le=EPS_RANGE[1])] | None,
                BeforeValidator(kernel_rule("check_eps"))]
#: lateral upsampling factor, in ``UPSAMPLE_RANGE``
Upsample = Annotated[Annotated[int, Field(ge=UPSAMPLE_RANGE[0], le=UPSAMPLE_RANGE[1])] | None,
                     BeforeValidator(kernel_rule("check_upsample"))]
#: output depth samples (None: n_t), in ``N_Z_RANGE``
NZ = Annotated[Annotated[int, Field(ge=N_Z_RANGE[0], le=N_Z_RANGE[1])] | None,
               BeforeValidator(kernel_rule("check_n_z"))]
#: output depth spacing in m (None: c·dt), in ``DZ_RANGE``
Dz = Annotated[Annotated[float, Field(ge=DZ_RANGE[0], le=DZ_RANGE[1])] | None,
               BeforeValidator(kernel_rule("check_dz"))]
#: working and output precision
Dtype = Annotated[Literal["float32", "float64"] | None, BeforeValidator(check_dtype_name)]


def Flag(name: str) -> Any:  # noqa: N802  (a type, named as one)
    """A true/false option named ``name`` (:func:`check_flag`)."""
    return Annotated[bool | None, BeforeValidator(check_flag(name))]


class MethodOptions(BaseModel):
    """The options every method takes (but ``c``, the speed of sound, which
    :func:`service.pipeline.reconstruct` owns: a number, the dataset's, or ``"auto"``).
    Unknown names, NaN and infinities are refused."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)

    @model_validator(mode="before")
    @classmethod
    def _null_is_the_default(cls, data: Any) -> Any:
        """``None`` (JSON null) means "the method's default": such entries are dropped."""
        if isinstance(data, dict):
            return {k: v for k, v in data.items() if v is not None}
        return data

    dtype: Dtype = Field(DEFAULT_DTYPE, description="working and output precision")


class NufftOptions(BaseModel):
    """Mix-in: the NUFFT tolerance of the methods that use non-uniform FFTs."""

    eps: Eps = Field(DEFAULT_EPS, description="NUFFT tolerance (relative accuracy of the non-uniform FFTs)",
                     json_schema_extra={"unit": "1"})


class UpsampleOption(BaseModel):
    """Mix-in: lateral upsampling of the output grid."""

    upsample: Upsample = Field(1, description="lateral upsampling factor of the output grid",
                               json_schema_extra={"unit": "1"})


class PositivityOption(BaseModel):
    """Mix-in: clip negative p0 to 0 (default off)."""

    positivity: Flag("positivity") = Field(False, description="clip negative p0 to 0")  # type: ignore[valid-type]


class DepthOptions(BaseModel):
    """Mix-in: the output depth grid (``n_z`` samples at ``dz``)."""

    n_z: NZ = Field(None, description="output depth samples", json_schema_extra={"unit": "1", "derived": "n_t"})
    dz: Dz = Field(None, description="output depth spacing; with the input's c·t_last it sets the working depth "
                   "rows, counted in the memory admission",
                   json_schema_extra={"unit": "m", "quantity": "length", "derived": "c·dt"})
