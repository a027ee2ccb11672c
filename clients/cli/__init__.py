"""The `fpscan` command line: one entry point, one module per subcommand.

Every module in this package that defines ``COMMAND`` (the subcommand's name),
``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int`` is a
subcommand. Modules must import heavy dependencies inside ``run`` (and anything slow that
their options need inside ``add_arguments``) so that ``fpscan --version`` and ``fpscan
--help`` answer at once and work on the base install (httpx + pydantic): `main` calls
``add_arguments`` only for the subcommand named on the command line, so ``fpscan --help``
imports nothing but the subcommand modules themselves. A command run where its extra is
missing says so in one line (exit 2).

Exit codes (a one-line reason on stderr): 0 success; 2 refused input -- a bad flag (argparse),
any ``ValueError`` (the library's refusal of a value, a file or a combination: a unit mistake,
an option outside its rule or one the method does not take, a missing input file) or a request
the server refused as given (HTTP 400, 404 an unknown id, 422); 1 a failure of the work itself -- I/O or a device
(``OSError``, ``RuntimeError``), the server unreachable or refusing for its state (409, 401,
503), a job that failed, an incomplete scan.
"""
from __future__ import annotations

import argparse
import importlib
import os
import re
import sys

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (`fpscan --help` starts faster)
if TYPE_CHECKING:
    from collections.abc import Collection, Iterator, Sequence
    from types import ModuleType
    from typing import Any

__all__ = ["build_parser", "subcommand_modules", "NEGATIVE_QUANTITY", "allow_negative_quantities", "main", "reason", "in_flags",
           "CLOSED_PIPE", "closed_pipe"]


def subcommand_modules() -> Iterator[ModuleType]:
    """The sub-commands of ``fpscan``: every module of this package that defines ``COMMAND``
    and ``run`` (package docstring), imported, in the order of their module names.

    Found from the package's own ``.py`` files, not ``pkgutil.iter_modules`` (which imports
    ``inspect``: a quarter of the start-up of ``fpscan --version``); modules whose names start
    with ``_`` are skipped.

    Returns
    -------
    iterator of types.ModuleType
        The sub-commands' modules (``module.COMMAND`` the name, ``module.HELP`` the one-line
        help, ``module.add_arguments`` and ``module.run``).

    Raises
    ------
    ImportError
        A module of the package cannot be imported.
    """
    # the package's own .py files (not pkgutil.iter_modules: see above)
    names = sorted({n[:-3] for d in __path__ for n in os.listdir(d) if n.endswith(".py")})
    for name in names:
        if name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{name}")
        if hasattr(module, "COMMAND") and hasattr(module, "run"):
            yield module


class _VersionAction(argparse.Action):
    """``--version``: looks the installed version up only when asked (``importlib.metadata``
    is slower to import than the rest of the command line)."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS, default: Any = argparse.SUPPRESS,
                 help: str | None = None) -> None:
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: str | Sequence[Any] | None, option_string: str | None = None) -> None:
        from fpscan.driver.acquire import software_version

        print(f"fpscan {software_version()}")
        parser.exit()


class _HelpFormatter(argparse.HelpFormatter):
    """argparse's help formatter at the terminal's width, read by `shutil.get_terminal_size`'s
    rule (``$COLUMNS``, else the terminal on stdout, else 80 columns) without importing
    shutil, whose archive modules were a tenth of ``fpscan --help``."""

    def __init__(self, prog: str, indent_increment: int = 2, max_help_position: int = 24,
                 width: int | None = None) -> None:
        if width is None:
            try:
                width = int(os.environ["COLUMNS"])
            except (KeyError, ValueError):
                width = 0
            if width <= 0:
                stdout = sys.__stdout__
                try:
                    width = os.get_terminal_size(stdout.fileno()).columns if stdout is not None else 0
                except (AttributeError, ValueError, OSError):  # not a terminal, or no file descriptor
                    width = 0
            width = (width or 80) - 2
        super().__init__(prog, indent_increment, max_help_position, width)


def _top_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fpscan",
        formatter_class=_HelpFormatter,
        description="Planar Fabry-Perot photoacoustic scanning: plan, acquire, reconstruct, serve.",
    )
    parser.add_argument("--version", action=_VersionAction, help="show the program's version number and exit")
    return parser


def build_parser(commands: Collection[str] | None = None) -> argparse.ArgumentParser:
    """The ``fpscan`` argument parser with one sub-command per module of this package.

    ``commands``: the names of the sub-commands whose parsers are built, with their options
    (their ``add_arguments`` may import what the options need); default all of them. The
    others are listed with their one-line help only (``fpscan --help``; naming one of them
    is not parsed: ``main`` builds the sub-command the command line names).

    Parameters
    ----------
    commands : collection of str, optional
        The sub-commands to build (None: all of them).

    Returns
    -------
    argparse.ArgumentParser
        The top-level parser; each built sub-command's ``_run`` default is its module's ``run``.
    """
    parser = _top_parser()
    building = False

    def sub_parser(**kwargs: Any) -> argparse.ArgumentParser | None:
        # argparse's parser of one sub-command; only a named one is built (each costs about
        # 2 ms, mostly gettext look-ups: 13 of them were most of ``fpscan --help``)
        return argparse.ArgumentParser(formatter_class=_HelpFormatter, **kwargs) if building else None

    # argparse calls parser_class(**kwargs) (any callable; typeshed wants a class)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=sub_parser)  # type: ignore[call-overload]
    sub.required = True
    for module in subcommand_modules():
        building = commands is None or module.COMMAND in commands
        p = sub.add_parser(module.COMMAND, help=module.HELP, description=module.HELP)
        if building:
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
    a number, so the pattern is widened to numbers with exponents and units.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        Changed in place, with every sub-parser built (:data:`NEGATIVE_QUANTITY`).
    """
    parser._negative_number_matcher = NEGATIVE_QUANTITY
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in set(action.choices.values()):
                if sub is not None:  # a sub-command listed but not built (`build_parser`)
                    allow_negative_quantities(sub)


def _command_named(argv: list[str]) -> str | None:
    """The sub-command ``argv`` names: its first word that is not an option (the top-level
    options, ``-h`` and ``--version``, take no value)."""
    for word in argv:
        if word == "--":
            continue
        if not word.startswith("-"):
            return word
    return None


def main(argv: list[str] | None = None) -> int:
    """Run ``fpscan`` with ``argv`` (default: ``sys.argv[1:]``); return the exit status.

    Parameters
    ----------
    argv : list of str, optional
        The arguments after the program name (default ``sys.argv[1:]``).

    Returns
    -------
    int
        The exit status: the sub-command's (0 when it returns None); 2 for refused input
        (``ValueError``, :class:`fpscan.driver.units.RefusedInput`) or a missing extra; 1 when the
        work failed (``OSError``, ``RuntimeError``); 130 when interrupted; :data:`CLOSED_PIPE`
        when stdout's reader went away. argparse's own errors and ``--help``/``--version``
        exit through ``SystemExit``.
    """
    if argv is None:
        argv = sys.argv[1:]
    command = _command_named(argv)
    if command is None and "--version" in argv and not {"-h", "--help"} & set(argv):
        _top_parser().parse_args(argv)  # prints the version and exits; no subcommand is imported
    parser = build_parser(() if command is None else (command,))
    args = parser.parse_args(argv)
    from fpscan.clients.cli.common import missing_extra, needs_extra
    from fpscan.driver.units import RefusedInput

    try:
        code = args._run(args)
        sys.stdout.flush()  # here, not at exit: a reader gone away is seen where it is handled
    except BrokenPipeError:  # `fpscan jobs list | head`: the reader has what it wanted
        return closed_pipe()
    except RefusedInput as exc:  # a unit mistake or a refused option is a usage error, like a bad flag
        options = type(exc).__name__ == "OptionError"  # fpscan.service.recon.checks: it names options
        print(f"fpscan {args.command}: error: {in_flags(str(exc), options=options)}", file=sys.stderr)
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
        print(f"fpscan {args.command}: error: {in_flags(reason(exc))}", file=sys.stderr)
        return 2
    except (OSError, RuntimeError) as exc:  # the work failed (I/O, a device)
        print(f"fpscan {args.command}: error: {reason(exc)}", file=sys.stderr)
        return 1
    return int(code or 0)


def in_flags(message: str, *, options: bool = False) -> str:
    """A reason worded for every caller (``fpscan.driver.units``: "force a value outside the range";
    a loader's "give key") in the command line's own terms: the flag that does it
    (``--force``, ``--key``); with ``options`` (a refused reconstruction option,
    ``fpscan.service.recon.checks.OptionError``) every option it names as its flag (``lam`` →
    ``--lambda``, ``c`` → ``--sound-speed``: ``fpscan.clients.cli.recon_options.option_flags``).

    Parameters
    ----------
    message : str
        An error message.
    options : bool, optional
        Whether the message names reconstruction options by their library names.

    Returns
    -------
    str
        The message in the flags' words.
    """
    import re

    message = message.replace("force a value outside the range", "give --force for a value outside the range")
    message = re.sub(r'give the load option axes, e\.g\. axes="([a-z,]+)" or axes="([a-z,]+)" \([^)]*\)',
                     r"give --axes \1 or --axes \2", message)  # fpscan.service.formats.npy.time_axes'
    message = re.sub(r"\bgive (key|dt|dx|dy)\b", r"give --\1", message)
    message = re.sub(r"given \((key|dt|dx|dy)\)", r"given (--\1)", message)
    message = re.sub(r"^(key|dt|dx|dy) is neither given", r"--\1 is neither given", message)
    message = re.sub(r"\b(needs|and) (dt|dx|dy) \(", r"\1 --\2 (", message)
    if options:
        try:
            from fpscan.clients.cli.recon_options import option_flags
            from fpscan.service.names import renamed_words
        except ImportError:  # pragma: no cover -- a client-only install: the names as they are
            return message
        message = renamed_words(message, option_flags())
    return message


#: the exit status after stdout's reader went away: a process killed by SIGPIPE, as shells report it
CLOSED_PIPE = 128 + 13


def closed_pipe() -> int:
    """Stdout's reader went away (``fpscan jobs list | head``): say nothing (no ``[Errno 32]``
    line, no traceback at exit) and return :data:`CLOSED_PIPE`, the status of ``ls | head``'s
    ``ls``. Stdout is pointed at the null device so the interpreter's final flush cannot
    fail again.

    Returns
    -------
    int
        :data:`CLOSED_PIPE` (141).
    """
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):
        pass
    return CLOSED_PIPE


def reason(exc: BaseException) -> str:
    """The message of an error for one line on stderr: a pydantic ``ValidationError``
    (a ``ValueError`` with ``errors()``) as ``field: reason; ...`` without pydantic's
    boilerplate, anything else as ``str(exc)``.

    Parameters
    ----------
    exc : BaseException
        The error.

    Returns
    -------
    str
        Its one-line message.
    """
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
