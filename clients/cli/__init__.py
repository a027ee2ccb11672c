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

__all__ = ["build_parser", "subcommand_modules", "NEGATIVE_QUANTITY", "allow_negative_quantities", "join_units",
           "refuse_unknown_options", "main", "reason", "in_flags",
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


def _sub_parser(parser: argparse.ArgumentParser, argv: Sequence[str]) -> argparse.ArgumentParser | None:
    """The innermost built parser ``argv`` names (``fpscan plan full``: the parser of ``full``);
    None when it names no sub-command."""
    found = None
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            word = next((w for w in argv if w in action.choices), None)
            sub = action.choices.get(word) if word is not None else None
            if isinstance(sub, argparse.ArgumentParser):
                found = _sub_parser(sub, argv[argv.index(word) + 1:]) or sub
            break
    return found


#: a number as one word (``100``, ``-2``, ``1.5e-3``) and a unit as the next one (``um``, ``µs``, ``km/s``)
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")
_UNIT_WORD = re.compile(r"^[A-Za-zµμ][A-Za-zµμ/]*$")


def _quantity_with(action: argparse.Action, number: str, unit: str) -> bool:
    """Whether ``number`` followed by the word ``unit`` is one value of ``action``: a flag whose
    type reads a number with a unit as a float (or a list of them: ``--poi``)."""
    if action.type is None or not _NUMBER.match(number) or not _UNIT_WORD.match(unit):
        return False
    try:
        value = action.type(number + unit)  # type: ignore[operator]  # argparse's type: a callable
    except Exception:  # argparse's own rule: any error of the type is a refused value
        return False
    values = value if isinstance(value, list) else [value]
    return bool(values) and all(isinstance(v, float) for v in values)


def join_units(parser: argparse.ArgumentParser, argv: Sequence[str]) -> list[str]:
    """``argv`` with each value of a quantity flag typed as two words, a number and its unit
    (``--pitch 100 um``, ``--poi -2 mm 2 mm``, ``--dt=8 ns``), joined into one (``100um``): the
    shell splits ``100 um`` in two, and argparse would refuse the unit as an argument of its
    own. A flag's type is a quantity when it reads the joined word as a number (m, s, Hz, m/s:
    :func:`fpscan.clients.cli.common.quantity`); other words are left as they are.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser (its flags and their types).
    argv : sequence of str
        The command line's words.

    Returns
    -------
    list of str
        The words, a quantity flag's number and unit joined.
    """
    out: list[str] = []
    words = list(argv)
    i = 0
    while i < len(words):
        word = words[i]
        out.append(word)
        i += 1
        if word == "--":
            out.extend(words[i:])
            break
        name, eq, value = word.partition("=")
        action = parser._option_string_actions.get(name) if word.startswith("--") else None
        if action is None or action.nargs == 0:
            continue
        if eq:
            if i < len(words) and _quantity_with(action, value, words[i]):
                out[-1] = word + words[i]
                i += 1
            continue
        nargs = action.nargs
        count = nargs if isinstance(nargs, int) else (1 if nargs in (None, "?") else len(words))
        while count > 0 and i < len(words) and (not words[i].startswith("-") or NEGATIVE_QUANTITY.match(words[i])):
            value = words[i]
            i += 1
            count -= 1
            if i < len(words) and _quantity_with(action, value, words[i]):
                value += words[i]
                i += 1
            out.append(value)
    return out


def refuse_unknown_options(parser: argparse.ArgumentParser, argv: Sequence[str]) -> None:
    """Refuse, naming the closest, a ``--flag`` that ``parser`` does not have but nearly does
    (``--lamda`` for ``--lam``): argparse would only list it among "unrecognized arguments"
    under the top-level usage. A flag with no close match, or a prefix argparse completes,
    is left to argparse.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser.
    argv : sequence of str
        The command line's words.

    Raises
    ------
    SystemExit
        Status 2, after the sub-command's usage and ``fpscan COMMAND: error: unrecognized option
        --lamda: did you mean --lam?`` on stderr.
    """
    import difflib

    canonical: dict[str, str] = {}  # every long flag -> the flag its action is named by (--lambda -> --lam)
    for action in parser._actions:
        longs = [s for s in action.option_strings if s.startswith("--")]
        if longs and action.help != argparse.SUPPRESS:
            canonical.update(dict.fromkeys(longs, longs[0]))
    for word in argv:
        if word == "--":
            return
        name = word.partition("=")[0]
        if not name.startswith("--") or len(name) < 3 or name in canonical:
            continue
        if any(flag.startswith(name) for flag in canonical):  # an abbreviation: argparse's to judge
            continue
        close = difflib.get_close_matches(name, list(canonical), n=1)
        if close:
            parser.error(f"unrecognized option {name}: did you mean {canonical[close[0]]}?")


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
        work failed (``OSError``, ``RuntimeError``) or, with ``--server``, the server's answer had a
        shape the command could not read (a ``KeyError``, ``TypeError``, ``AttributeError`` or
        ``IndexError``: one line naming the server, not a traceback); 130 when interrupted; :data:`CLOSED_PIPE`
        when stdout's reader went away. argparse's own errors and ``--help``/``--version``
        exit through ``SystemExit``.
    """
    if argv is None:
        argv = sys.argv[1:]
    command = _command_named(argv)
    if command is None and "--version" in argv and not {"-h", "--help"} & set(argv):
        _top_parser().parse_args(argv)  # prints the version and exits; no subcommand is imported
    parser = build_parser(() if command is None else (command,))
    sub = _sub_parser(parser, argv) if command is not None else None
    if sub is not None:
        argv = join_units(sub, argv)
        refuse_unknown_options(sub, argv)
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
    except (KeyError, TypeError, AttributeError, IndexError) as exc:
        from fpscan.clients.http.errors import format_detail

        server = getattr(args, "server", None)
        if not server:
            raise  # this program's own fault: its traceback is the report
        # an answer of another shape than this client's (an older or newer server, or not fpscan)
        print(f"fpscan {args.command}: error: the server at {server} answered in a shape this client does not "
              f"read ({type(exc).__name__}: {format_detail(reason(exc))[:300]}); is it an fpscan server of this version "
              f"(`fpscan --version`, GET {server.rstrip('/')}/api/health)?", file=sys.stderr)
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
