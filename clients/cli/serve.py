"""`fpscan serve`: run the HTTP service (FastAPI on uvicorn)."""
from __future__ import annotations

import argparse

from fpscan.clients.cli.common import UsageError

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (`fpscan --help` starts faster)
if TYPE_CHECKING:
    from typing import Any

    from fpscan.service.settings import Settings

__all__ = ["COMMAND", "HELP", "add_arguments", "parse_devices", "page_url", "run", "use_malloc"]

#: set in the environment of the server process that :func:`use_malloc` started
_REEXEC_MARK = "FPSCAN_SERVE_MALLOC"

COMMAND = "serve"
HELP = "run the fpscan HTTP service (job queue, scans, reconstructions, web page)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare this sub-command's options on ``parser`` (an ``argparse`` sub-parser).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser, changed in place.
    """
    parser.add_argument("--host", default=None, help="bind address (default 127.0.0.1; beyond loopback needs --token)")
    parser.add_argument("--allowed-host", action="append", default=[], metavar="NAME", dest="allowed_hosts",
                        help="a host name (or address) clients may reach the server by besides localhost, "
                             "127.0.0.1 and [::1] (repeatable; '*' = any, only with a token): requests naming "
                             "another Host are refused (DNS rebinding)")
    parser.add_argument("--port", type=int, default=None, help="port (default 8000; 0 = any free port)")
    parser.add_argument("--data-dir", default=None, help="folder for the database, scans and results")
    parser.add_argument("--device", action="append", default=[], metavar="ID=PATH",
                        help="a scanner: id and serial device path or pyserial URL (repeatable)")
    parser.add_argument("--token", default=None, help="bearer token (default: $FPSCAN_TOKEN, else the file "
                        "$FPSCAN_TOKEN_FILE names, e.g. a Docker secret; none given: one is made and printed "
                        "with the page's address)")
    parser.add_argument("--allow-weak-token", action="store_true", default=None,
                        help="start with a token of under 128 bits of estimated entropy (refused otherwise)")
    parser.add_argument("--no-token", action="store_true", default=None,
                        help="serve without a token, on loopback only: every user and program of this machine "
                             "may then use the server")
    parser.add_argument("--executor", choices=["local", "dask"], default=None, help="where reconstructions run")
    parser.add_argument("--dask-scheduler", default=None, help="dask.distributed scheduler address")
    parser.add_argument("--workers", type=int, default=None, help="local process pool size")
    parser.add_argument("--memory-limit", type=float, default=None, help="reconstruction memory limit, GiB")
    parser.add_argument("--settings", default=None, help="settings file (JSON or TOML)")
    parser.add_argument("--no-web", action="store_true", help="do not serve the web page")
    parser.add_argument("--log-level", default=None,
                        help="uvicorn/app log level: critical, error, warning, info (default), debug or trace")
    from fpscan.clients.cli.common import default_dtype

    parser.epilog = (f"Precision: reconstructions are {default_dtype()} unless a request's params.dtype asks for "
                     "float64, the same default as fpscan recon locally and the web page.")


def parse_devices(items: list[str]) -> dict[str, str]:
    """``["fp1=/dev/ttyACM0", ...]`` → ``{"fp1": "/dev/ttyACM0"}``; raises ValueError.

    Parameters
    ----------
    items : list of str
        ``ID=PATH`` items from ``--device``.

    Returns
    -------
    dict[str, str]
        Scanner id -> device path.

    Raises
    ------
    UsageError
        An item without ``=``, an id or a path (a ``ValueError``).
    """
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key or not value:
            raise UsageError(f"--device must be ID=PATH, got {item!r}")
        out[key] = value
    return out


def use_malloc() -> None:
    """Restart this process (the same command line, the same pid: ``os.execv``) with Python's
    allocator on the C library's ``malloc`` (``PYTHONMALLOC=malloc``) unless ``PYTHONMALLOC`` is
    set already; in the restarted process, take the setting out of the environment again so that
    the job workers it spawns keep Python's default allocator (their work is numpy's).

    Why (docs/performance.md): after a burst of thousands of connections Python's
    small-object allocator (pymalloc) keeps most of the burst's 1-MiB arenas, since a few
    long-lived objects made during the burst pin each one: 5000 slow readers left the server at
    1.6-1.8x its resident memory before them, with the same live objects. With ``malloc`` the
    freed memory goes back to the C allocator, which ``malloc_trim`` returns to the system
    (``fpscan.service.api.connections``): within 10 % of the baseline after 20 000 readers.

    Only on POSIX (``os.execv`` replaces the process in place there); a ``PYTHONMALLOC`` the
    user set is kept.

    Raises
    ------
    OSError
        From ``os.execv`` where the interpreter cannot be started again (not expected: it is
        the running one).
    """
    import os
    import sys

    if os.environ.pop(_REEXEC_MARK, None) is not None:  # the restarted server: children get the default
        os.environ.pop("PYTHONMALLOC", None)
        return
    if os.name != "posix" or "PYTHONMALLOC" in os.environ or not getattr(sys, "orig_argv", None):
        return
    os.environ["PYTHONMALLOC"] = "malloc"
    os.environ[_REEXEC_MARK] = "1"
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(sys.executable, [sys.executable, *sys.orig_argv[1:]])


def _settings(args: argparse.Namespace) -> Settings:
    """The server's settings: the settings file and environment (``Settings.load``), the
    command line's options over them; a bind beyond loopback, or any host name, without a token
    is refused (:class:`UsageError`)."""
    import importlib.resources

    from pydantic import ValidationError

    from fpscan.service.settings import Settings, is_loopback

    overrides = {}
    for name in ("host", "port", "data_dir", "token", "executor", "dask_scheduler", "workers", "log_level",
                 "allow_weak_token", "no_token"):
        value = getattr(args, name)
        if value is not None:
            overrides[name] = value
    if args.allowed_hosts:
        overrides["allowed_hosts"] = list(args.allowed_hosts)
    if args.device:
        overrides["devices"] = parse_devices(args.device)
    if args.memory_limit is not None:
        import math

        if not (math.isfinite(args.memory_limit) and args.memory_limit > 0):
            raise UsageError(f"--memory-limit must be a finite number of GiB > 0, got {args.memory_limit}")
        overrides["memory_limit"] = int(args.memory_limit * 2**30)
    if not args.no_web:
        try:
            overrides["web_root"] = str(importlib.resources.files("fpscan.clients.web"))
        except ModuleNotFoundError:
            pass
    try:
        settings = Settings.load(args.settings, **overrides)
    except ValidationError as exc:
        raise UsageError("; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())) from None
    if not is_loopback(settings.host) and settings.token_value() is None:  # reads token_file
        raise UsageError(f"binding to {settings.host} (beyond loopback) needs a --token "
                         "(or $FPSCAN_TOKEN_FILE)")
    if "*" in settings.allowed_hosts and settings.token_value() is None:
        raise UsageError("--allowed-host '*' (any host name) needs a --token (or $FPSCAN_TOKEN_FILE)")
    return settings


def run(args: argparse.Namespace) -> int:
    """Run this sub-command with the parsed ``args``; return the exit status.

    The server process runs on the C library's allocator (:func:`use_malloc`: it restarts
    itself in place once, before anything else).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line (:func:`add_arguments`).

    Returns
    -------
    int
        The exit status: 0 after the server stopped; 1 when the port or the data folder is already in
        use.
    """
    use_malloc()
    import json
    import logging
    import sys

    settings, made_token = _token_rules(_settings(args))

    # one server per data folder and per job database (wherever FPSCAN_DB_PATH puts it), on a
    # free port: each refused in one line before anything reads the job store (its start-up
    # recovery would pause a live server's running scan and re-queue its reconstructions)
    from fpscan.service.data_lock import (
        DataFolderInUse,
        PortInUse,
        check_port,
        lock_data_folder,
        lock_job_store,
    )

    try:
        check_port(settings.host, settings.port)
        folder_lock = lock_data_folder(settings.data_dir)  # held until this process ends
        try:
            store_lock = lock_job_store(settings.database)  # likewise
        except BaseException:
            folder_lock.release()
            raise
    except (DataFolderInUse, PortInUse) as exc:
        print(f"fpscan serve: error: {exc}", file=sys.stderr, flush=True)
        return 1

    level = settings.log_level.upper()
    logging.basicConfig(level=getattr(logging, level, logging.INFO), stream=sys.stderr,
                        format='{"time": "%(asctime)s", "level": "%(levelname)s", "logger": "%(name)s", '
                               '"message": %(message_json)s}')
    _install_json_messages()

    executor = None
    if settings.executor == "local":  # the pool's workers spawn and warm up while the app loads
        from typing import cast

        from fpscan.service.jobs.executors import LocalExecutor, make_executor

        executor = cast(LocalExecutor, make_executor(settings))  # executor "local": a LocalExecutor
        executor.start_workers()
    try:
        import uvicorn  # after the workers' spawn: they warm up while the server loads (0.2 s sooner)

        from fpscan.service.api.app import create_app
        from fpscan.service.api.connections import server_config

        app = create_app(settings, executor=executor)
        # timeouts, connection limits and capped logs: fpscan.service.api.connections
        server = uvicorn.Server(server_config(app, settings))
        print(json.dumps({"event": "serving", "host": settings.host, "port": settings.port,
                          "data_dir": str(settings.data_dir)}), file=sys.stderr, flush=True)
        if made_token is not None:
            print(f"fpscan serve: no token given, this one made for this run: open {page_url(settings, made_token)} "
                  f"; clients: export FPSCAN_TOKEN={made_token}", file=sys.stderr, flush=True)
        server.run()
    finally:
        if executor is not None and not getattr(executor, "closed", False):  # the app's shutdown closes it
            executor.close()  # too; here when the app never started (closing twice raised)
        store_lock.release()
        folder_lock.release()
    return 0


def page_url(settings: Any, token: str | None = None) -> str:
    """The web page's address for ``settings`` (its host and port), with ``token`` in the
    fragment (``#token=...``: the page keeps it for its tab and takes it out of the address; a
    fragment is never sent to a server, so no request log holds it). :func:`run` prints this
    address once at start, with a token it made, on standard error: the server's own log,
    which therefore holds the token (keep it private, or give a token).

    Parameters
    ----------
    settings : Settings
        The service's settings (``host``, ``port``; a wildcard bind is shown as 127.0.0.1).
    token : str or None, optional
        The token to sign in with; default None: none.

    Returns
    -------
    str
        ``http://HOST:PORT/`` or ``http://HOST:PORT/#token=TOKEN``.
    """
    from urllib.parse import quote

    host = settings.host if settings.host not in ("0.0.0.0", "::", "") else "127.0.0.1"
    host = f"[{host}]" if ":" in host else host
    return f"http://{host}:{settings.port}/" + (f"#token={quote(token, safe='')}" if token else "")


def _token_rules(settings: Any) -> tuple[Any, str | None]:
    """The token rules of ``fpscan serve``: a token given must have at least
    ``MIN_TOKEN_BITS`` of estimated entropy (``token_entropy_bits``) unless
    ``allow_weak_token``; none given (and not ``no_token``), one is made
    (``secrets.token_hex(32)``: 256 random bits, ``TOKEN_RECIPE``'s), as Jupyter Server does. Returns the
    settings (with the made token) and the made token (None when none was made).

    Raises
    ------
    UsageError
        A weak token not allowed (a ``ValueError``).
    """
    import secrets

    from pydantic import SecretStr

    from fpscan.service.settings import MIN_TOKEN_BITS, TOKEN_RECIPE, token_entropy_bits

    if settings.no_token:  # loopback only: run() refused a wider bind without a token already
        return settings, None
    token = settings.token_value()  # reads token_file: an unreadable one is refused here
    if token is None:
        made = secrets.token_hex(32)  # TOKEN_RECIPE's: never starts with "-" (a command line's option)
        return settings.model_copy(update={"token": SecretStr(made)}), made
    bits = token_entropy_bits(token)
    if bits < MIN_TOKEN_BITS and not settings.allow_weak_token:
        raise UsageError(f"the token is weak (about {bits:.0f} bits of estimated entropy, under {MIN_TOKEN_BITS}): "
                         f"make one with {TOKEN_RECIPE}, or leave it out and one is made; "
                         "--allow-weak-token (FPSCAN_ALLOW_WEAK_TOKEN=true) starts with it anyway")
    return settings, None


def _install_json_messages() -> None:
    """Structured logs: every record carries its message as a JSON string."""
    import json
    import logging

    old = logging.getLogRecordFactory()

    def factory(*a: Any, **kw: Any) -> logging.LogRecord:
        record = old(*a, **kw)
        try:
            record.message_json = json.dumps(record.getMessage())
        except Exception:
            record.message_json = json.dumps(str(record.msg))
        return record

    logging.setLogRecordFactory(factory)
