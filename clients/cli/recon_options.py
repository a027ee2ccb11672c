"""The reconstruction options of ``fpscan recon`` and ``fpscan unmix``, as flags generated
from the method registry (``fpscan.service.recon.methods``: each method's typed options model).

One flag per option of any method: ``--name-with-dashes`` of the option's one name (``--lam``,
``--max-iter``; or the field's ``flag``), its type from the field's JSON schema (a number, an
integer, a choice, true/false as ``--x`` / ``--no-x``, a length or time with a unit where the
field names a ``quantity``), its help from the field's description, range, unit and default. The
speed of sound is ``--sound-speed`` and its autofocus interval ``--sound-speed-range``. An earlier
release's flags (:data:`OLD_FLAGS`: ``--c``, ``--c-range``, ``--lambda``, ``--iterations``) still
work for one release and print a warning naming the new one. The registry loads without numpy,
so a client-only install has the same flags (the server checks the values, 422 → exit 2).
"""
from __future__ import annotations

import argparse

from fpscan.clients.cli.common import quantity, speed
from fpscan.constants import C_AUTOFOCUS_RANGE, C_DEFAULT, C_PLAUSIBLE

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (`fpscan --help` starts faster)
if TYPE_CHECKING:
    from typing import Any

__all__ = ["OLD_FLAGS", "add_speed_flags", "add_load_flags", "add_option_flags", "option_names", "option_params",
           "option_flags"]

#: an earlier release's flags, still accepted for one release (a warning names the new one): option -> old flags
OLD_FLAGS: dict[str, tuple[str, ...]] = {"sound_speed": ("--c",), "sound_speed_range": ("--c-range",),
                                         "lam": ("--lambda",), "max_iter": ("--iterations",)}


class _Renamed(argparse.Action):
    """Store the value; given by an old flag (:data:`OLD_FLAGS`), warn on stderr naming the new one."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        if option_string is not None and option_string != self.option_strings[0]:
            import sys

            print(f"fpscan: warning: {option_string} is deprecated: use {self.option_strings[0]} ({option_string} is "
                  "refused from the next release)", file=sys.stderr)
        setattr(namespace, self.dest, values)


def _registry() -> Any:
    try:
        from fpscan.service.recon import methods
    except ImportError:  # no service package at all: the server checks the options
        return None
    return methods


def _speed_fields() -> dict[str, str]:
    """The registry's speed option (``fpscan.service.recon.methods.options.SpeedOptions``): each
    field's flag and description; without the service package (a client-only install) the
    same words from ``fpscan.constants``."""
    try:
        from fpscan.service.recon.methods.options import SpeedOptions
    except ImportError:
        return {"sound_speed": f"speed of sound, m/s; default: the input's, else {C_DEFAULT:g}",
                "sound_speed_range": f"autofocus search interval (c_min, c_max), m/s (default "
                                     f"{C_AUTOFOCUS_RANGE[0]:g}-{C_AUTOFOCUS_RANGE[1]:g})",
                "force": f"accept a sound_speed outside {C_PLAUSIBLE[0]:g}-{C_PLAUSIBLE[1]:g} m/s (another medium)"}
    return {name: f.description or "" for name, f in SpeedOptions.model_fields.items()}


def add_speed_flags(group: Any, *, what: str = "") -> None:
    """``--sound-speed``, ``--sound-speed-range`` and ``--force`` on ``group`` (``--c`` and
    ``--c-range``, an earlier release's, warn); dests ``sound_speed``, ``sound_speed_range``,
    ``force`` (the options' names); their help from the registry's one speed option (unit,
    bounds, default: :func:`_speed_fields`).

    Parameters
    ----------
    group : argparse.ArgumentParser or argument group
        Where the flags go.
    what : str, optional
        Text appended to ``--sound-speed``'s help (what the speed is used for here).
    """
    said = _speed_fields()
    group.add_argument("--sound-speed", *OLD_FLAGS["sound_speed"], dest="sound_speed", type=speed, default=None,
                       metavar="C", action=_Renamed,
                       help=f"{said['sound_speed']}{what}; e.g. 1500 or 1.5km/s".replace("%", "%%"))
    group.add_argument("--sound-speed-range", *OLD_FLAGS["sound_speed_range"], dest="sound_speed_range",
                       type=quantity("speed", "sound-speed-range"), nargs=2, default=None, metavar=("MIN", "MAX"),
                       action=_Renamed,
                       help=f"{said['sound_speed_range']}; e.g. 1450 1600 or 1.45km/s 1.6km/s".replace("%", "%%"))
    group.add_argument("--force", action="store_true", help=said["force"].replace("%", "%%"))


#: the load options' flags on a client-only install (no format registry to read them from)
_LOAD_FALLBACK: list[dict[str, Any]] = [
    {"name": "dt", "description": "sample interval, e.g. 20ns (bare numbers are SI)", "formats": [],
     "schema": {"type": "number", "unit": "s", "quantity": "time"}},
    {"name": "dx", "description": "lateral spacing along x, e.g. 100um", "formats": [],
     "schema": {"type": "number", "unit": "m", "quantity": "length"}},
    {"name": "dy", "description": "lateral spacing along y, e.g. 100um (default dx)", "formats": [],
     "schema": {"type": "number", "unit": "m", "quantity": "length"}},
    {"name": "key", "description": "HDF5 dataset path (or MAT-file variable) of the data in a k-Wave file",
     "formats": [], "schema": {"type": "string"}},
    {"name": "axes", "description": "the array's axis order, e.g. y,x,t (k-Wave's sensor order) or t,y,x; 2-D x,t "
                                    "(k-Wave's sensor,time) or t,x; default: time first where the shape shows it",
     "formats": [], "schema": {"type": "string"}},
]


def add_load_flags(group: Any, *, skip: tuple[str, ...] = ("wavelength",)) -> None:
    """One flag per load option of the registered file formats (``fpscan.service.formats.load_options``:
    ``--dt``, ``--dx``, ``--dy``, ``--key``, ``--axes``), with the formats that take each in its help; a value
    the chosen format does not take is refused when the file is loaded.

    Parameters
    ----------
    group : argparse.ArgumentParser or argument group
        Where the flags go.
    skip : tuple of str, optional
        Options the command declares itself (``--wavelength``: an index or ``all``).
    """
    try:
        from fpscan.service.formats.load_options import load_option_schemas
    except ImportError:  # client-only install: the server checks the options
        options = _LOAD_FALLBACK
    else:
        options = load_option_schemas()
    for o in options:
        if o["name"] in skip:
            continue
        schema, flag = o["schema"], "--" + o["name"].replace("_", "-")
        who = f" ({', '.join(o['formats'])})" if o["formats"] else ""
        kind = {} if schema.get("type") == "string" else _value_type(o["name"], schema, flag)
        group.add_argument(flag, dest=o["name"], default=None, help=f"{o['description']}{who}".replace("%", "%%"),
                           **kind)


def _value_type(name: str, schema: dict, flag: str) -> dict:
    """The argparse keywords (``type``/``choices``/``action``) for a value of ``schema``."""
    if schema.get("type") == "boolean":
        return {"action": argparse.BooleanOptionalAction}
    if "enum" in schema:
        return {"choices": list(schema["enum"])}
    if schema.get("quantity"):
        return {"type": quantity(schema["quantity"], flag.lstrip("-"))}
    return {"type": int if schema.get("type") == "integer" else float}


def add_option_flags(group: argparse._ArgumentGroup) -> None:
    """One flag per option of the registered methods on ``group`` (module docstring).

    A flag already on ``group`` is not added again; without the service package (a
    client-only install) none is added.

    Parameters
    ----------
    group : argparse.ArgumentParser or argument group
        Where the flags go; each flag's dest is the option's name, its default None (not given).
    """
    methods = _registry()
    if methods is None:
        return
    for m in methods.METHODS.values():
        for o in methods.option_schemas(m):
            name, schema = o["name"], o["schema"]
            flag = schema.get("flag") or "--" + name.replace("_", "-")
            if any(flag in a.option_strings for a in group._group_actions):
                continue
            takers = [x.name for x in methods.METHODS.values() if name in x.options_model.model_fields]
            who = "" if len(takers) == len(methods.METHODS) else f"{', '.join(takers)}: "
            rng = "" if "enum" in schema or schema.get("type") == "boolean" else methods.range_text(schema)
            unit = schema.get("unit", "")
            unit = "" if unit in ("", "1") else f" {unit}"
            said = f"{who}{o['description']}" + (f"; {rng}{unit}" if rng else (f";{unit}" if unit else "")) + \
                f" (default {methods.default_text(name)}{', locally and on the server' if name == 'dtype' else ''})"
            metavar = name.upper() if schema.get("type") in ("number", "integer") else None
            kind = _value_type(name, schema, flag)
            old = OLD_FLAGS.get(name, ()) if "action" not in kind else ()
            if old:
                kind["action"] = _Renamed
            group.add_argument(flag, *old, dest=name, default=None, help=said.replace("%", "%%"),
                               **({"metavar": metavar} if metavar else {}), **kind)


def option_flags() -> dict[str, str]:
    """Each reconstruction and load option's name (``lam``) → the flag that gives it
    (``--lam``; ``sound_speed`` → ``--sound-speed``): how the command line words an error that
    names options (``fpscan.clients.cli.in_flags``).

    Returns
    -------
    dict
        Empty without the service package (a client-only install).
    """
    methods = _registry()
    if methods is None:
        return {}
    out = {name: "--" + name.replace("_", "-") for name in ("sound_speed", "sound_speed_range", "force")}  # add_speed_flags'
    for m in methods.METHODS.values():
        for o in methods.option_schemas(m):
            out.setdefault(o["name"], o["schema"].get("flag") or "--" + o["name"].replace("_", "-"))
    for name in ("key", "axes", "dt", "dx", "dy"):
        out[name] = "--" + name
    return out


def option_names() -> list[str]:
    """The options' names (dests of :func:`add_option_flags`).

    Returns
    -------
    list of str
        Every registered method's option names; empty without the service package.
    """
    methods = _registry()
    return [] if methods is None else list(methods.option_fields())


def option_params(args: argparse.Namespace) -> dict:
    """The options given on the command line: the ``params`` of
    ``fpscan.service.pipeline.reconstruct`` and of ``POST /api/reconstructions``.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line (flags of :func:`add_option_flags` and :func:`add_speed_flags`).

    Returns
    -------
    dict
        Each option given (``None``: not given, left out), with the speed of sound
        ``sound_speed`` (m/s), ``sound_speed_range`` (a list ``[c_min, c_max]``, m/s) and
        ``force`` (True) when set: the same names in the library and over HTTP.
    """
    params: dict[str, Any] = {}
    for name in ("sound_speed", *option_names()):
        value = getattr(args, name, None)
        if value is not None:
            params[name] = bool(value) if isinstance(value, bool) else value
    if getattr(args, "sound_speed_range", None) is not None:
        params["sound_speed_range"] = list(args.sound_speed_range)
    if getattr(args, "force", False):  # the speed-of-sound rule, as the library and the API apply it
        params["force"] = True
    return params
