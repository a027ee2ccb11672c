"""Service settings: environment variables (prefix ``FPSCAN_``) and an optional file.

Source: pydantic-settings (``BaseSettings``). Precedence, highest first: keyword
arguments, environment (``FPSCAN_DATA_DIR``, ``FPSCAN_TOKEN``, ...), the settings file
(JSON or TOML named by ``FPSCAN_SETTINGS_FILE`` or passed to :meth:`Settings.load`),
defaults.

Units: bytes for memory and upload limits, seconds for intervals.
"""
from __future__ import annotations

import ipaddress
import json
import math
import os
import re
import tomllib
import zlib
from pathlib import Path
from typing import Any, Literal

from pydantic import AliasChoices, Field, SecretStr, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

__all__ = ["LOOPBACK_HOSTS", "LOG_LEVELS", "MIN_TOKEN_BITS", "TOKEN_RECIPE", "is_loopback", "token_entropy_bits",
           "Settings"]

LOOPBACK_HOSTS = {"127.0.0.1", "localhost", "::1"}
#: the log levels ``log_level`` takes (uvicorn's: ``uvicorn.config.LOG_LEVELS``; trace is uvicorn's own, below debug)
LOG_LEVELS = ("critical", "error", "warning", "info", "debug", "trace")
#: the least estimated entropy of a bearer token ``fpscan serve`` starts with (bits), unless told
#: otherwise (``allow_weak_token``): 128 bits, the security strength NIST SP 800-57 Part 1 (Rev. 5),
#: Table 2, asks of keys used beyond 2030
MIN_TOKEN_BITS = 128
#: the command that makes a token of 256 random bits (64 hexadecimal digits; ``secrets.token_hex``, as
#: Jupyter Server's tokens): hexadecimal, so that it never starts with "-", which a command line
#: (``--token``) would take for an option, and needs no quoting in a URL or a shell
TOKEN_RECIPE = "python3 -c 'import secrets; print(secrets.token_hex(32))'"

#: character classes of a token and their sizes (:func:`token_entropy_bits`): a class counts
#: whole once one of its characters is in the token
_CHARACTER_CLASSES = (("abcdefghijklmnopqrstuvwxyz", 26), ("ABCDEFGHIJKLMNOPQRSTUVWXYZ", 26),
                      ("0123456789", 10), ("-_", 2))
_HEX = frozenset("0123456789abcdef")


def token_entropy_bits(token: str) -> float:
    """An upper estimate of a token's entropy, in bits: what a token drawn at random from the
    character classes it uses would have, capped by its compressed length.

    The alphabet is the sum of the classes the token uses (lower case 26, upper case 26,
    digits 10, ``-`` and ``_`` 2, the rest of printable ASCII 30, any other character 2**16),
    at most 16 for a token of hexadecimal digits alone; the estimate is
    ``len(token) * log2(alphabet)`` (a random choice of that many characters), capped by the
    bits of the token compressed with DEFLATE (RFC 1951; ``zlib``, raw, level 9): a token that
    repeats itself (``"change-me-change-me-..."``, ``"aaaa..."``) compresses and is estimated
    low. It is an upper bound for a token a person chose (it cannot see words, dates or
    keyboard rows): the tokens to use are made at random (:data:`TOKEN_RECIPE`: 32 random
    bytes, some 256 bits).

    Parameters
    ----------
    token : str
        The bearer token.

    Returns
    -------
    float
        The estimate, bits (0 for ``""``).

    Examples
    --------
    >>> round(token_entropy_bits("change-me"))
    43
    >>> token_entropy_bits("3f9c2a7e51b8d04c6e1f0a93b7d25c48")  # 32 hexadecimal digits
    128.0
    """
    if not token:
        return 0.0
    alphabet = sum(size for chars, size in _CHARACTER_CLASSES if any(ch in chars for ch in token))
    known = "".join(chars for chars, _ in _CHARACTER_CLASSES)
    if any(ch not in known and " " <= ch <= "~" for ch in token):
        alphabet += 30  # the rest of printable ASCII (95 - 26 - 26 - 10 - 2 - the space)
    if any(not " " <= ch <= "~" for ch in token):
        alphabet += 2**16
    if set(token.lower()) <= _HEX:
        alphabet = min(alphabet, 16)
    estimate = len(token) * math.log2(alphabet)
    packer = zlib.compressobj(9, zlib.DEFLATED, -15)  # raw DEFLATE: no header, no checksum
    compressed = len(packer.compress(token.encode("utf-8")) + packer.flush())
    return min(estimate, 8.0 * compressed)


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback addresses (127.0.0.0/8, ::1).

    Parameters
    ----------
    host : str
        A host name or an IP address (IPv6 without brackets).

    Returns
    -------
    bool
        True for ``"localhost"`` or a loopback address; False for any other name or address.
    """
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class Settings(BaseSettings):
    """Everything the service needs to run.

    ``devices`` maps a scanner id (``[A-Za-z0-9_-]``) to a serial device path or pyserial
    URL (``/dev/ttyACM0``, ``socket://host:port``...). In the environment give it as JSON
    (``FPSCAN_DEVICES='{"fp1": "/dev/ttyACM0"}'``).

    Raises ``pydantic.ValidationError`` (a ``ValueError``) for bad values.
    """

    model_config = SettingsConfigDict(env_prefix="FPSCAN_", extra="forbid")

    data_dir: Path = Field(Path("fpscan-data"), description="folder for the database, plans, scans, results (a "
                           "relative path is taken from the folder the server starts in, and kept absolute: the "
                           "jobs' records name their files by it)")
    db_path: Path | None = Field(None, description="SQLite job database (default: <data_dir>/jobs.sqlite); one "
                                 "server per database: the server locks <db_path>.lock beside it")
    devices: dict[str, str] = Field(default_factory=dict, description="scanner id -> serial path or pyserial URL")
    token: SecretStr | None = Field(None, description="bearer token; None = none given (fpscan serve then makes "
                                    "one, unless no_token)")
    allow_weak_token: bool = Field(False, description="let fpscan serve start with a token of under 128 bits of "
                                   "estimated entropy (fpscan.service.settings.token_entropy_bits); default: refused")
    no_token: bool = Field(False, description="serve without a token (loopback only): every user and program of "
                           "this machine may then use the server; default: fpscan serve makes a token when none "
                           "is given")
    executor: Literal["local", "dask"] = Field("local", description="where reconstructions run: 'local' "
                                               "(a process pool of this server) or 'dask' (a dask.distributed "
                                               "cluster at dask_scheduler)")
    dask_scheduler: str | None = Field(None, description="dask.distributed scheduler address (implies executor dask)")
    workers: int = Field(1, ge=1, le=64, description="local process pool size")
    worker_nice: int = Field(0, ge=0, le=19, description="CPU priority increment (os.nice) of the local "
                             "reconstruction workers: 0 = the server's own priority (a job then costs what the "
                             "library costs; the server stays responsive because its CPU work runs off the "
                             "event loop); raise it (e.g. 10) to favour other programs on a shared machine")
    warm_up: bool = Field(True, description="compile the reconstruction kernels (a tiny NER and NEDNER), "
                          "import the writer and draw a picture in each local worker at start-up, in the "
                          "background (health answers at once; the first job waits for its worker's warm-up), "
                          "and start the plan and live-preview workers, warmed; false: no warm-up, and those two "
                          "workers start at their first use")
    memory_limit: int = Field(8 * 2**30, gt=0, description="bytes available to reconstructions at once")
    upload_limit: int = Field(2 * 2**30, gt=0, description="largest accepted upload, bytes")
    body_timeout_s: float = Field(30.0, gt=0, le=3600, description="a request whose body sends nothing for "
                                  "this long is refused with 408")
    body_min_rate: int = Field(100 * 1024, ge=0, description="slowest a request body may arrive, bytes/s averaged "
                               "over body_rate_window_s (after its first window): a body slower than this is "
                               "refused with 408 (the unread rest of one answered already closes the connection); "
                               "0 = no floor")
    body_rate_window_s: float = Field(10.0, gt=0, le=3600, description="the window body_min_rate is averaged over, s")
    json_limit: int = Field(64 * 2**20, gt=0, description="largest plan request body (POST /api/plans, "
                            "/api/plans/preview), bytes: parsed in the plan worker; the plan JSON of the largest "
                            "lattice is 15-32 MiB")
    request_json_limit: int = Field(64 * 1024, gt=0, le=64 * 2**20, description="largest JSON body of every other "
                                    "request (reconstructions, scans, retention, ...), bytes: parsed and validated "
                                    "on the event loop, so capped at what its schema can need")
    header_timeout_s: float = Field(5.0, gt=0, le=600, description="a connection that has not sent a complete "
                                    "request head (request line and headers) this long after it was accepted, or "
                                    "after the first byte of its next request, is closed, s")
    max_head_bytes: int = Field(16 * 1024, ge=1024, le=2**20, description="longest request line and headers, "
                                "bytes: a longer head is refused with 431 before the app sees it")
    keep_alive_s: float = Field(5.0, gt=0, le=3600, description="an idle kept-alive connection is closed after "
                                "this long, s")
    send_timeout_s: float = Field(30.0, gt=0, le=3600, description="a response's bytes may wait this long for "
                                  "a reader that takes fewer than send_min_rate bytes/s of them (its socket full): "
                                  "then the connection is closed and the bytes dropped, s")
    send_min_rate: int = Field(1024, ge=0, description="slowest a reader may take a response's waiting bytes, "
                               "bytes/s averaged over send_timeout_s; 0 = any progress")
    send_buffer_bytes: int | None = Field(64 * 1024, ge=4096, le=64 * 2**20, description="the kernel's send "
                                          "buffer of each connection (SO_SNDBUF; the kernel doubles it): bounds the "
                                          "memory a reader that does not read holds in the kernel (autotuned, it "
                                          "grows to 4 MiB each, and thousands put every socket of the machine "
                                          "under memory pressure); None = the system's autotuning")
    events_keepalive_s: float = Field(15.0, gt=0, le=3600, description="an event stream (GET "
                                      "/api/jobs/{id}/events) sends a keep-alive comment after this long without "
                                      "an event, s")
    shutdown_grace_s: float = Field(5.0, gt=0, le=3600, description="on shutdown, connections still open "
                                    "(event streams included) are closed after this long, s")
    connections_per_address: int = Field(64, ge=1, le=100_000, description="most open connections of one client "
                                         "address that have not shown the token; more must show it in their first "
                                         "request head (without a token: 503; a wrong one is refused as on any "
                                         "connection)")
    max_connections: int | None = Field(None, ge=1, le=1_000_000, description="open connections without the "
                                        "token in all beyond which a client address gets only its allowance of 4 "
                                        "(more must show the token in their first request head; without a token: 503; "
                                        "a wrong one is refused as on any connection); None = half the process's "
                                        "open-file limit")
    uploads_per_client: int | None = Field(None, ge=1, le=1024, description="uploads (and plan requests) one client "
                                           "address may have in progress or waiting; more get 429 while the "
                                           "server's slots are not all taken by others; None = import_workers")
    queued_per_client: int | None = Field(100, ge=1, le=1_000_000, description="reconstructions one client "
                                          "address may have queued (not yet running); another is refused with 429 "
                                          "saying the cap, the queue's length and its estimated wait; None = no cap")
    work_limit_s: float = Field(8 * 3600.0, gt=0, le=30 * 86400, description="most work one reconstruction may "
                                "ask for, in seconds on 2 cores by its method's estimate "
                                "(fpscan.service.jobs.admission.estimate_work); more is refused with 422")
    import_timeout_s: float = Field(60.0, gt=0, le=3600, description="longest time an upload's import may "
                                    "take before it is refused (damaged files can block the HDF5 library)")
    import_workers: int = Field(2, ge=1, le=64, description="uploads imported at once (each in a child process "
                                "whose address space is capped at memory_limit, at least 1 GiB); up to 4x as many "
                                "more wait, further ones get 429")
    export_workers: int = Field(2, ge=1, le=64, description="exports built at once (a result's exports stream "
                                "its volume in slabs of a few MiB, in the server's process; a scan's IPASC export "
                                "reads the whole scan); up to 4x as many more wait (for a turn or for another "
                                "request's build of the same file), further ones get 429")
    host: str = Field("127.0.0.1", description="address the server listens on (loopback by default)")
    allowed_hosts: list[str] = Field(default_factory=list, description="names (or addresses) besides the "
                                     "loopback ones that clients may reach this server by: a request whose Host "
                                     "header names another is refused with 403 (DNS rebinding); '*' = any (only "
                                     "behind a token). Environment: JSON, FPSCAN_ALLOWED_HOSTS='[\"scanner-pc\"]'")
    port: int = Field(8000, ge=0, le=65535, description="TCP port the server listens on; 0 = any free port")
    web_root: Path | None = Field(None, description="folder of the web page's static files; None = no page")
    preview_interval_s: float = Field(3.0, gt=0, le=3600, description="live preview refresh period")
    heartbeat_s: float = Field(2.0, gt=0, le=600, description="lease heartbeat period of running jobs")
    max_attempts: int = Field(3, ge=1, le=100, description="tries of a reconstruction before it fails")
    time_limit_s: float = Field(3600.0, gt=0, le=7 * 86400, description="wall-time limit of one reconstruction by "
                                "a time-limited (iterative) method, s: the default of its time_limit option and the "
                                "most a request may ask; reached, the solver stops and says so (stop_reason 'time "
                                "limit'). Environment: FPSCAN_TIME_LIMIT_S (FPSCAN_TV_TIME_LIMIT_S, its former name, "
                                "is still read)",
                                validation_alias=AliasChoices("time_limit_s", "fpscan_time_limit_s", "tv_time_limit_s",
                                                              "fpscan_tv_time_limit_s"))
    resume_scans: bool = Field(False, description="resume scans interrupted by a restart at start-up "
                                                  "(default: they wait, paused, for POST /resume)")
    log_level: str = Field("info", description="log level of the server and its app (critical, error, warning, info, "
                           "debug, trace; case-insensitive)")
    token_file: Path | None = Field(None, description="file holding the bearer token (Docker secrets: "
                                                      "/run/secrets/<name>); used when token is not set")
    retention_keep_results: int | None = Field(None, ge=0, description="keep the newest N finished "
                                               "reconstruction results (None = all); PUT /api/retention overrides")
    retention_keep_bytes: int | None = Field(None, ge=0, le=10**18, description="keep at most this many bytes of result "
                                             "files, oldest finished deleted first (None = no limit)")
    retention_include_scans: bool = Field(False, description="let retention delete finished scan files too")
    retention_datasets_keep_bytes: int | None = Field(None, ge=0, description="keep at most this many bytes of "
                                                      "uploaded datasets no active job reads, oldest deleted first "
                                                      "(None = no limit)")
    retention_datasets_max_age_s: float | None = Field(None, ge=0, description="delete uploaded datasets no active "
                                                       "job reads once older than this, s (None = never)")
    disk_reserve_bytes: int = Field(256 * 2**20, ge=0, description="free disk an upload or its import, and an "
                                    "export's build, must leave: one that would leave less (counting those in "
                                    "flight) is refused with 507; below it /api/health lists the disk as full")
    db_reserve_bytes: int = Field(8 * 2**20, ge=0, le=2**30, description="bytes kept in a reserve file beside the "
                                  "job database and given up when its disk fills, so that jobs' final states, cancels "
                                  "and deletions can still be written (0 = none)")
    disk_walk_period_s: float = Field(600.0, gt=0, le=7 * 86400, description="seconds between two walks of the "
                                      "data folder that check the disk-use counters /api/health answers from")

    @field_validator("devices")
    @classmethod
    def _device_ids(cls, value: dict[str, str]) -> dict[str, str]:
        for key in value:
            if not key or len(key) > 64 or not all(ch.isalnum() or ch in "_-" for ch in key):
                raise ValueError(f"scanner id {key!r} must be 1-64 characters of [A-Za-z0-9_-]")
        return value

    @field_validator("data_dir", "db_path")
    @classmethod
    def _absolute(cls, value: Path | None) -> Path | None:
        # the jobs' records hold their datasets' and results' paths: a relative data folder would
        # make them relative to the folder the server started in, which a restart elsewhere changes
        return None if value is None else Path(value).expanduser().absolute()

    @field_validator("log_level")
    @classmethod
    def _log_level(cls, value: str) -> str:
        level = value.strip().lower()
        if level not in LOG_LEVELS:
            raise ValueError(f"log level must be one of {', '.join(LOG_LEVELS)}, got {value!r}")
        return level

    @field_validator("allowed_hosts")
    @classmethod
    def _host_names(cls, value: list[str]) -> list[str]:
        out = []
        for name in value:
            name = name.strip().lower().rstrip(".")
            if name.startswith("[") and name.endswith("]"):
                name = name[1:-1]
            if not name or len(name) > 253 or not all(ch.isalnum() or ch in "-.:_*" for ch in name) \
                    or ("*" in name and name != "*"):
                raise ValueError(f"allowed host {name!r} must be a host name or address (no port, no scheme), "
                                 "or '*' for any")
            out.append(name)
        return out

    @model_validator(mode="after")
    def _one_token_rule(self) -> Settings:
        if self.no_token and (self.token is not None or self.token_file is not None):
            raise ValueError("no_token and a token (token or token_file) both given: choose one")
        return self

    @model_validator(mode="after")
    def _dask_address(self) -> Settings:
        if self.dask_scheduler and self.executor == "local":
            self.executor = "dask"
        if self.executor == "dask" and not self.dask_scheduler:
            raise ValueError("executor 'dask' needs dask_scheduler (a scheduler address)")
        return self

    @property
    def database(self) -> Path:
        """The SQLite file: ``db_path`` or ``<data_dir>/jobs.sqlite``."""
        return self.db_path if self.db_path is not None else self.data_dir / "jobs.sqlite"

    def redact(self, text: str) -> str:
        """``text`` with the data directory's path replaced by ``<data>``, so error
        messages that reach clients never show the server's file system layout. Only whole
        path prefixes are replaced (``--data-dir data`` leaves the word "dataset" alone)."""
        # the folder as resolved, as kept (absolute) and relative to the working folder, the spelling
        # a relative --data-dir gave it
        rel = os.path.relpath(self.data_dir)
        roots = {str(Path(self.data_dir).resolve()), str(self.data_dir)} | ({rel} if not rel.startswith("..") else set())
        for root in sorted(roots, key=len, reverse=True):
            if root and root != ".":
                # only a whole path prefix: not inside a word or another path ("dataset",
                # "/x/data" for data_dir "data"), and followed by "/" or the path's end
                # (a relative one only when a path follows: "data" alone is a word)
                end = r"(?=/|$|[^\w.~-])" if root.startswith("/") else r"(?=/)"
                text = re.sub(r"(?<![\w./~-])" + re.escape(root.rstrip("/")) + end, "<data>", text)
        return text

    def token_value(self) -> str | None:
        """The bearer token: ``token``, else the first line of ``token_file`` (surrounding
        whitespace stripped). Raises ValueError when the file cannot be read or is empty."""
        if self.token is not None:
            return self.token.get_secret_value()
        if self.token_file is None:
            return None
        try:  # read on use: a rotated secret takes effect without a restart
            text = Path(self.token_file).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ValueError(f"cannot read token_file {self.token_file}: {exc}") from None
        token = text.strip().splitlines()[0].strip() if text.strip() else ""
        if not token:
            raise ValueError(f"token_file {self.token_file} is empty")
        return token

    @classmethod
    def load(cls, path: str | os.PathLike | None = None, **overrides: Any) -> Settings:
        """Settings from a JSON/TOML file (``path`` or ``$FPSCAN_SETTINGS_FILE``), the
        environment, then ``overrides`` (highest). Raises ``ValueError`` for an unreadable
        file or bad values."""
        path = path or os.environ.get("FPSCAN_SETTINGS_FILE")
        base: dict[str, Any] = {}
        if path:
            p = Path(path)
            try:
                text = p.read_text()
            except OSError as exc:
                raise ValueError(f"cannot read settings file {p}: {exc.strerror}") from None
            try:
                base = tomllib.loads(text) if p.suffix == ".toml" else json.loads(text)
            except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
                raise ValueError(f"settings file {p} is not valid {p.suffix or 'JSON'}: {exc}") from None
            if not isinstance(base, dict):
                raise ValueError(f"settings file {p} must hold a table/object")
        # Environment beats the file: build from env, then layer file values underneath.
        env_only = cls(**{k: v for k, v in overrides.items()})
        explicit = env_only.model_fields_set
        merged = {k: v for k, v in base.items() if k not in explicit}
        merged.update({k: getattr(env_only, k) for k in explicit})
        return cls(**merged) if merged else env_only
