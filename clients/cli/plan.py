"""`fpscan plan <kind> [kind options] [--out plan.json] [--server URL] [--preview mask.png]`.

One subcommand per mask kind, with one flag per parameter, all generated from the
kind's parameter model in ``fpscan.service.plans.kinds`` (defaults, units and help included):
adding a kind there adds it here. Prints the point count (obtained of requested), the
outer/inner weight ratio and the expected scan time. Locally the plan JSON ("Plan JSON"
of docs/architecture.md) goes to ``--out``; with ``--server`` the plan is created on
the server (``POST /api/plans``, same request the web page sends) and ``--out`` gets the
server's plan JSON.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from fpscan.clients.cli.common import UsageError, add_server_options, client_errors, needs_extra
from fpscan.constants import C_PLAUSIBLE

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (`fpscan --help` starts faster)
if TYPE_CHECKING:
    from typing import Any

__all__ = ["COMMAND", "HELP", "flag", "parse_value", "add_arguments", "mask_params", "request_body", "run"]

COMMAND = "plan"
HELP = "make a scan plan (sensor mask + weights + order + acquisition settings) as plan JSON"


def flag(name: str) -> str:
    """The command-line flag of a parameter: ``n_points`` -> ``--n-points``.

    Parameters
    ----------
    name : str
        The parameter's name.

    Returns
    -------
    str
        The flag.
    """
    return "--" + name.replace("_", "-")


_UNIT_KINDS = {"m": "length", "s": "time", "Hz": "frequency", "m/s": "speed"}


def parse_value(text: str, unit: str | None) -> float:
    """One number from the command line in the parameter's SI ``unit``: a bare number is
    SI, text may carry a unit (``60um``, ``3.6mm``, ``8ns``, ``500Hz``;
    ``fpscan.driver.units.parse_quantity``). A bad value is a usage error (exit 2) naming it.

    Parameters
    ----------
    text : str
        The value as typed.
    unit : str or None
        The parameter's SI unit (``"m"``, ``"s"``, ``"Hz"``, ``"m/s"``); another unit or None:
        a plain number.

    Returns
    -------
    float
        The value in SI units.

    Raises
    ------
    argparse.ArgumentTypeError
        Text that is not a number with a unit of that kind.
    ValueError
        Text that is not a number, for a parameter without a unit.
    """
    kind = _UNIT_KINDS.get(unit or "")
    if kind is None:
        return float(text)
    from fpscan.driver.units import parse_quantity

    try:
        return parse_quantity(text, kind, name=kind)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _json_value(text: str) -> object:
    """A JSON value given inline or as a file name holding it."""
    import json

    if text.lstrip()[:1] in ("[", "{"):
        source = text
    else:
        try:
            raw = Path(text).read_bytes()
        except OSError as exc:
            raise argparse.ArgumentTypeError(f"cannot read {text}: {exc}") from None
        try:
            source = raw.decode("utf-8")
        except UnicodeDecodeError:
            from fpscan.clients.cli.common import (
                wrong_file,  # names a scan file, a result, a NumPy array ...
            )

            raise argparse.ArgumentTypeError(wrong_file(text, "a JSON list of pairs")
                                             or f"{text}: this is not UTF-8 text, not a JSON list of pairs") from None
    try:
        return json.loads(source)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"{text} is not valid JSON: {exc}") from None


def _add_field(group: argparse._ArgumentGroup, f: dict) -> None:
    """One argparse option from a parameter descriptor (``fpscan.service.plans.kinds.kind_fields``)."""
    unit = f["unit"]
    number = int if f["integer"] else (lambda s, u=unit: parse_value(s, u))
    desc = f["description"] or f["title"]
    if f["required"]:
        desc += " (required)"
    elif f["default"] is not None:
        desc += f" (default {f['default']})"
    kw: dict[str, Any] = {"dest": "p_" + f["name"], "default": None, "help": desc}
    if f["widget"] == "pairs":
        kw.update(type=_json_value, metavar="JSON|FILE", help=desc + ": a JSON list of pairs, inline or in a file")
    elif f["widget"] == "numbers":  # space- or comma-separated: --poi -2mm 2mm, --poi=-2mm,2mm
        kw.update(type=lambda s, one=number: [one(x) for x in s.split(",") if x.strip()] or [one(s)],
                  nargs="+", metavar="N" if f["integer"] else "VALUE")
    else:
        kw.update(type=number, metavar="N" if f["integer"] else "VALUE")
    group.add_argument(flag(f["name"]), **kw)


def _common_options() -> argparse.ArgumentParser:
    from fpscan.service.plans.plan import ORDER_NAMES, Acquisition

    acq = Acquisition()
    common = argparse.ArgumentParser(add_help=False)
    g = common.add_argument_group("lattice")
    g.add_argument("--n-x", type=int, default=226, help="lattice points along x (default 226)")
    g.add_argument("--n-y", type=int, default=None,
                   help="lattice points along y (default: n_x; 1 for equiangular)")
    g.add_argument("--pitch", type=lambda s: parse_value(s, "m"), default=60e-6,
                   help="lattice pitch in m (default 6e-05)")
    g = common.add_argument_group("plan")
    g.add_argument("--order", default="auto", choices=ORDER_NAMES,
                   help="scan order (default auto: rings for equisteradian, given for points, serpentine otherwise)")
    g.add_argument("--n-t", type=int, default=acq.n_t, help=f"samples per A-line (default {acq.n_t})")
    g.add_argument("--dt", type=lambda s: parse_value(s, "s"), default=acq.dt,
                   help=f"sample interval in s (default {acq.dt:g})")
    g.add_argument("--averages", type=int, default=acq.averages,
                   help=f"pulses averaged per point (default {acq.averages})")
    g.add_argument("--wavelength", type=lambda s: parse_value(s, "m"), action="append", metavar="M",
                   help=f"excitation wavelength in m; repeat for several (default {acq.wavelengths[0]:g})")
    g.add_argument("--wavelength-order", choices=["per_point", "per_pass"], default=None,
                   help="with several wavelengths: tune the laser at every point (per_point, the "
                        "default: wavelengths register) or once per full pass (per_pass: fewer "
                        "tunings, motion between passes); docs/protocol.md §4.1")
    g.add_argument("--prf", type=lambda s: parse_value(s, "Hz"), default=acq.prf,
                   help=f"laser pulse repetition frequency in Hz (default {acq.prf:g})")
    g.add_argument("--sound-speed", type=lambda s: parse_value(s, "m/s"), default=acq.sound_speed,
                   help=f"speed of sound, e.g. 1500m/s (default {acq.sound_speed:g})")
    g.add_argument("--force", action="store_true",
                   help=f"accept a sound speed outside {C_PLAUSIBLE[0]:g}-{C_PLAUSIBLE[1]:g} m/s (a medium other than tissue/water)")
    g = common.add_argument_group("output")
    g.add_argument("--out", help="where to write the plan JSON (required without --server)")
    g.add_argument("--preview", metavar="PNG", help="also write a preview PNG of the mask")
    add_server_options(g)
    return common


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare ``fpscan plan``'s options on ``parser``: one sub-parser per mask kind
    (aliases included) with one flag per parameter of its model, plus the common options.
    Where the planner (``fpscan.service.plans``: numpy, scipy; the ``fpscan[driver]`` extra) is not
    installed, e.g. a client-only install, the command is declared but says so when run.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser, changed in place.
    """
    try:
        from fpscan.service.plans.kinds import KINDS, kind_fields

        common = _common_options()
    except ImportError as exc:
        parser.add_argument("rest", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
        parser.set_defaults(_planner_missing=str(exc))
        return
    sub = parser.add_subparsers(dest="mask", metavar="KIND", title="mask kinds")
    sub.required = True
    for k in KINDS.values():
        p = sub.add_parser(k.name, aliases=list(k.aliases), parents=[common], help=k.label,
                           description=f"{k.label}: {k.description}")
        p.set_defaults(mask=k.name)
        g = p.add_argument_group(f"{k.name} parameters (SI units)")
        for f in kind_fields(k.name):
            _add_field(g, f)


def mask_params(args: argparse.Namespace) -> dict:
    """The kind's parameters from the parsed flags (unset optional ones left out).
    Raises ValueError naming a missing required flag.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line (``args.mask`` the kind, ``args.p_<name>`` its parameters).

    Returns
    -------
    dict
        Parameter name -> value, in SI units.

    Raises
    ------
    UsageError
        A required parameter's flag is missing (a ``ValueError``).
    """
    from fpscan.service.plans.kinds import kind_fields

    params: dict = {}
    for f in kind_fields(args.mask):
        v = getattr(args, "p_" + f["name"], None)
        if v is None:
            if f["required"]:
                raise UsageError(f"{args.mask} needs {flag(f['name'])}")
            continue
        if f["widget"] == "pairs" and isinstance(v, dict):
            params.update(v)  # a JSON object names its parameters, e.g. {"indices": [...]}
            continue
        if f["widget"] == "numbers":  # each token a list (comma-separated values): one list
            v = [x for token in v for x in token]
        if f["widget"] == "numbers" and len(v) == 1 and f["scalar"]:
            v = v[0]  # n_per_side 13 -> 13; n_per_side 13 9 -> [13, 9]
        params[f["name"]] = v
    return params


def request_body(args: argparse.Namespace) -> dict:
    """The plan request (``POST /api/plans`` body) the flags describe.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line.

    Returns
    -------
    dict
        ``kind``, ``lattice``, ``params``, ``order``, ``force`` and ``acquisition`` (SI units;
        ``n_y`` defaults to 1 for the equiangular kind, else to ``n_x``; the wavelengths
        to 750 nm).

    Raises
    ------
    UsageError
        A required parameter's flag is missing (:func:`mask_params`).
    """
    n_y = args.n_y if args.n_y is not None else (1 if args.mask == "equiangular" else args.n_x)
    return {
        "kind": args.mask,
        "lattice": {"n_x": args.n_x, "n_y": n_y, "pitch": args.pitch},
        "params": mask_params(args),
        "order": args.order,
        "force": args.force,
        "acquisition": {"n_t": args.n_t, "dt": args.dt, "averages": args.averages,
                        "wavelengths": args.wavelength or [7.5e-7], "prf": args.prf,
                        "sound_speed": args.sound_speed,
                        **({"wavelength_order": args.wavelength_order} if args.wavelength_order else {})},
    }


@client_errors
def run(args: argparse.Namespace) -> int:
    """Make the plan locally (``--out``) or on the server (``--server``); exit status.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line (:func:`add_arguments`).

    Returns
    -------
    int
        The exit status: 0 on success; 2 without the planner installed (the ``fpscan[driver]``
        extra). Errors of the client become exit 1, or 2 when the server refused the request as given
        (``fpscan.clients.cli.common.client_errors``).
    """
    if getattr(args, "_planner_missing", None):
        return needs_extra(args, "driver", args._planner_missing)
    if not args.out and not args.server:
        raise UsageError("give --out FILE (a local plan) or --server URL (a plan on the server)")
    from fpscan.clients.cli.common import check_out_writable

    for flag, path in (("--out", args.out), ("--preview", args.preview)):  # refused before anything is written
        if path:
            check_out_writable(path, flag)
    body = request_body(args)
    if args.server:
        return _remote(args, body)
    from fpscan.service.plans import make_plan, preview_png

    plan = make_plan(kind=body["kind"], lattice=body["lattice"], params=body["params"],
                     order=body["order"], acquisition=body["acquisition"], force=args.force)
    plan.to_json(args.out)
    if args.preview:
        preview_png(plan, args.preview)
    lat = plan.lattice
    print(f"plan {plan.id}: {plan.mask.kind} on {lat.n_x}x{lat.n_y} at {lat.pitch:g} m")
    print(f"points: {plan.mask.obtained_points} (requested {plan.mask.requested_points})")
    from fpscan.service.plans.mask import shortfall

    why = shortfall(plan.mask.kind, plan.mask.requested_points, plan.mask.obtained_points, lat.pitch)
    if why:
        print(f"note: {why}")
    print(f"weight ratio (outer/inner): {plan.mask.weight_ratio:.4g}")
    t = plan.expected_scan_time_s
    print(f"order: {plan.order}; expected scan time: "
          + (_seconds(t) if t is not None else "set by the scanner (no PRF in the plan)"))
    print(f"wrote {args.out}" + (f" and {args.preview}" if args.preview else ""))
    return 0


def _seconds(t: float) -> str:
    """A scan time for the terminal: 3 significant digits below 100 s (a 16-point plan at 500 Hz
    is 0.032 s, not 0.0 s), whole seconds above."""
    return f"{t:.3g} s" if t < 100 else f"{t:.0f} s"


def _remote(args: argparse.Namespace, body: dict) -> int:
    import json

    from fpscan.clients.cli.common import make_client
    from fpscan.clients.http import field_of

    with make_client(args) as api:
        plan = api.create_plan(body)
        pid = field_of(plan, "id")
        if args.out:
            Path(args.out).write_text(json.dumps(api.get_plan_json(pid)) + "\n", encoding="utf-8")
        if args.preview:
            api.download_plan_preview(pid, args.preview)
    print(f"plan {pid} on {args.server}: {field_of(plan, 'kind')}, {field_of(plan, 'n_points')} points "
          f"(requested {field_of(plan, 'requested_points')})")
    if field_of(plan, "shortfall"):
        print(f"note: {field_of(plan, 'shortfall')}")
    print(f"weight ratio (outer/inner): {field_of(plan, 'weight_ratio'):.4g}")
    t = field_of(plan, "expected_scan_time_s")
    print("expected scan time: " + (_seconds(t) if t is not None else "set by the scanner (no PRF in the plan)"))
    if args.out:
        print(f"wrote {args.out}" + (f" and {args.preview}" if args.preview else ""))
    return 0
