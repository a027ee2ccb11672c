"""Real fpscan processes for the client/CLI tests, through the product's own starter
(``fpscan.clients.processes``): the service (``fpscan serve`` on 127.0.0.1, its own SQLite file)
and the simulated scanner (``fpscan sim`` on a pty)."""
from __future__ import annotations

import contextlib
from pathlib import Path

from fpscan.clients.processes import clean_env, free_port, service, simulator
from tests.waits import HANG_S

__all__ = ["QUIET", "clean_env", "fpscan_server", "fpscan_sim", "free_port", "has_command"]

#: the test servers' settings: no warm-up (``Settings.warm_up``). A warming server compiled or loaded
#: every method's kernels in both precisions in the background, 9.7 s of CPU against 1.9 s, on the
#: 2-core machine the other test worker shares; a job loads what it needs itself, and the plan and
#: live-preview workers start at their first use. The README's recipes and the demo keep the defaults.
#: The tests' tokens are short names (``"cli-test-token"``) that ``fpscan serve`` refuses as weak by
#: itself: allowed here (``Settings.allow_weak_token``); the refusal is tested in
#: tests/service/test_browser_security.py.
QUIET = {"FPSCAN_WARM_UP": "false", "FPSCAN_ALLOW_WEAK_TOKEN": "true"}


def has_command(name: str) -> bool:
    from fpscan.clients.cli import subcommand_modules

    return any(m.COMMAND == name for m in subcommand_modules())


@contextlib.contextmanager
def fpscan_server(data_dir: Path, *, token: str | None = None, devices: dict | None = None,
                  timeout: float = HANG_S, env: dict | None = None):
    """Yield ``(url, process)`` of a running ``fpscan serve``. ``env`` adds ``FPSCAN_*`` settings to
    :data:`QUIET`."""
    with service(data_dir, token=token, devices=devices, timeout=timeout, env={**QUIET, **(env or {})}) as srv:
        yield srv.url, srv


@contextlib.contextmanager
def fpscan_sim(*args: str, timeout: float = HANG_S, log_dir: Path | None = None):
    """Yield ``(device_path, process)`` of a running ``fpscan sim``."""
    import tempfile

    with tempfile.TemporaryDirectory(prefix="fpscan-sim-") as tmp:
        log = Path(log_dir or tmp) / "simulator.log"
        with simulator(*args, log_path=log, timeout=timeout) as (device, proc):
            yield device, proc
