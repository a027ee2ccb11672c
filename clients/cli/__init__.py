"""The `fpscan` command line: one entry point, one module per subcommand.

Every module in this package that defines ``COMMAND`` (the subcommand's name),
``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int`` is a
subcommand. Modules must import heavy dependencies inside ``run`` so that
``fpscan --help`` stays fast and works on the base install (httpx + pydantic): a command
run where its extra is missing says so in one line (exit 2).

Exit codes (a one-line reason on stderr): 0 success; 2 refused input -- a bad flag (argparse),
any ``ValueError`` (the library's refusal of a value, a file or a combination: a unit mistake,
an option outside its rule or one the method does not take, a missing input file) or a request
the server refused as invalid (HTTP 400/422); 1 a failure of the work itself -- I/O or a device
(``OSError``, ``RuntimeError``), the server unreachable or refusing for its state (409, 401,
503), a job that failed, an incomplete scan.
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import re
import sys


def _subcommand_modules():
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        if hasattr(module, "COMMAND") and hasattr(module, "run"):
            yield module


def build_parser() -> argparse.ArgumentParser:
    """The ``fpscan`` argument parser with one sub-command per module of this package."""
    from driver.acquire import software_version

    parser = argparse.ArgumentParser(
        prog="fpscan",
        description="Planar Fabry-Perot photoacoustic scanning: plan, acquire, reconstruct, serve.",
    )
    parser.add_argument("--version", action="version", version=f"fpscan {software_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for module in _subcommand_modules():
        p = sub.add_parser(module.COMMAND, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    allow_negative_quantities(parser)
    return parser


#: A negative number with an optional unit (``-2mm``, ``-1e-12``, ``-.5 um``), or a comma-separated
#: list starting with one (``-2mm,2mm``): a value, not an option
_Q = r"(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?\s*[A-Za-zµμ/ ]*"
NEGATIVE_QUANTITY = re.compile(rf"^-{_Q}(,\s*[+-]?{_Q})*,?$")  # also a comma-separated list: -2mm,2mm


def allow_negative_quantities(parser: argparse.ArgumentParser) -> None:
    """Let ``parser`` and its sub-parsers take negative values with units as values
    (``--poi -2mm 2mm``, ``--lambda -1e-12``: refused by the option's own rule, not as an
    unknown option). argparse reads a token starting with ``-`` as a value only when it
    matches its negative-number pattern (plain ``-2``, ``-.5``); no fpscan option looks like
    a number, so the pattern is widened to numbers with exponents and units."""
    parser._negative_number_matcher = NEGATIVE_QUANTITY  # type: ignore[attr-defined]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in set(action.choices.values()):
                allow_negative_quantities(sub)


def main(argv: list[str] | None = None) -> int:
    """Run ``fpscan`` with ``argv`` (default: ``sys.argv[1:]``); return the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    from clients.cli._common import missing_extra, needs_extra
    from driver.units import RefusedInput

    try:
        code = args._run(args)
    except RefusedInput as exc:  # a unit mistake or a refused option is a usage error, like a bad flag
        print(f"fpscan {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except ImportError as exc:  # a command run on an install without its extra
        extra = missing_extra(exc)
        if extra is None:
            raise
        return needs_extra(args, extra, str(exc))
    except KeyboardInterrupt:
        print("fpscan: interrupted", file=sys.stderr)
        return 130
    except ValueError as exc:  # refused input (a value, a file's content, a combination): a usage error
        print(f"fpscan {args.command}: error: {reason(exc)}", file=sys.stderr)
        return 2
    except (OSError, RuntimeError) as exc:  # the work failed (I/O, a device)
        print(f"fpscan {args.command}: error: {reason(exc)}", file=sys.stderr)
        return 1
    return int(code or 0)


def reason(exc: BaseException) -> str:
    """The message of an error for one line on stderr: a pydantic ``ValidationError``
    (a ``ValueError`` with ``errors()``) as ``field: reason; ...`` without pydantic's
    boilerplate, anything else as ``str(exc)``."""
    errors = getattr(exc, "errors", None)
    if callable(errors):
        try:
            items = errors(include_url=False)
        except TypeError:
            items = None
        if isinstance(items, list) and items and all(isinstance(e, dict) for e in items):
            parts = []
            for e in items:
                msg = str(e.get("msg", "")).removeprefix("Value error, ")
                loc = ".".join(str(p) for p in e.get("loc", ()))
                parts.append(f"{loc}: {msg}" if loc else msg)
            return "; ".join(parts)
    return str(exc)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
