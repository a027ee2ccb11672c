"""The `fpscan` command line: one entry point, one module per subcommand.

Every module in this package that defines ``COMMAND`` (the subcommand's name),
``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int`` is a
subcommand. Modules must import heavy dependencies inside ``run`` so that
``fpscan --help`` stays fast and works on the base install (httpx + pydantic): a command
run where its extra is missing says so in one line (exit 2).

Exit codes: 0 success, 1 failure (one-line reason on stderr), 2 usage error.
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
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
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run ``fpscan`` with ``argv`` (default: ``sys.argv[1:]``); return the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    from clients.cli._common import missing_extra, needs_extra
    from driver.units import ImplausibleValue

    try:
        code = args._run(args)
    except ImplausibleValue as exc:  # a unit mistake is a usage error, like a bad flag
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
    except (ValueError, OSError, RuntimeError) as exc:
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
