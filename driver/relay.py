"""Relay process of the host driver: drains a local serial tty into a pipe.

A tty hands its reader at most ~4 KiB per wake-up, so at full A-line rates it must be
read every few hundred microseconds; a Python thread competing for the interpreter lock
with the thread that decodes A-lines and writes the scan file cannot promise that. The
host therefore starts ``python -m fpscan.driver.relay FD`` with the open tty descriptor: it does
nothing but copy bytes from the tty to its stdout, a pipe the host enlarges to 1 MiB and
reads in large blocks. Its first byte out is a frame delimiter (0x00, which the deframer
skips) that says it is reading: the host waits for it before it sends a command, so the
relay's start-up is never taken for a lost command. The relay exits when its stdout is closed, on a tty error (the
message goes to stderr), or within 0.1 s of its parent's death; it ignores SIGINT and
SIGTERM (a Ctrl-C or a ``kill`` of the process group is the host's to handle). Should it end anyway, the host reads the tty itself.
"""
from __future__ import annotations

import os
import select
import sys

__all__ = ["READY", "relay"]

#: the relay's first byte: it is reading the tty (a frame delimiter, harmless to a deframer)
READY = b"\x00"


def relay(fd: int, out: int = 1, parent: int | None = None) -> int:
    """Copy ``fd`` to ``out`` until ``out`` closes, ``fd`` fails or ``parent`` dies.

    Writes :data:`READY` first, then copies what ``fd`` yields (up to 64 KiB a read),
    checking every 0.1 s of silence whether the parent is still alive.

    Parameters
    ----------
    fd : int
        The open descriptor to read (the host's serial tty).
    out : int, optional
        The descriptor to write to (default 1, stdout: the pipe the host reads).
    parent : int or None, optional
        Process id of the parent to outlive; None: this process's parent now.

    Returns
    -------
    int
        The exit status: 0 when ``out`` closes, ``fd`` reaches end of file or the parent has
        died; 1 when ``fd`` fails (select or read error, the message on stderr).
    """
    parent = os.getppid() if parent is None else parent
    try:
        os.write(out, READY)
    except OSError:
        return 0
    while True:
        try:
            ready = select.select([fd], [], [], 0.1)[0]
        except (OSError, ValueError) as exc:
            print(f"relay: {exc}", file=sys.stderr)
            return 1
        if not ready:
            if os.getppid() != parent:
                return 0
            continue
        try:
            data = os.read(fd, 1 << 16)
        except BlockingIOError:
            continue
        except OSError as exc:
            print(f"relay: read failed: {exc}", file=sys.stderr)
            return 1
        if not data:
            return 0
        view = memoryview(data)
        try:
            while view:
                view = view[os.write(out, view):]
        except (BrokenPipeError, OSError):
            return 0


if __name__ == "__main__":
    import signal

    # Ctrl-C in a terminal (and a SIGTERM to the process group, as a service manager sends
    # it) reaches the relay too: the host handles it (and needs the relay to leave the
    # scanner idle); the relay ends with its parent
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    sys.exit(relay(int(sys.argv[1]), parent=int(sys.argv[2]) if len(sys.argv) > 2 else None))
