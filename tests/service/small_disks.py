"""A small real disk for the full-disk tests: a tmpfs mounted for one test, and a filler that
takes its free bytes the way another program that filled it once would.

Needs ``mount -t tmpfs`` (root, or a container that allows it): `tmpfs` skips the test with
the reason where it cannot mount."""
from __future__ import annotations

import errno
import os
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest


@contextmanager
def tmpfs(folder: Path, size: str) -> Iterator[Path]:
    """``folder`` (made here) with a tmpfs of ``size`` (mount's ``size=``, e.g. "64m") mounted
    on it until the block ends; skips the test where mounting is not permitted."""
    folder.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip() or r.returncode}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], capture_output=True)


def fill(folder: Path, leave: int = 0) -> None:
    """Take every free byte of the disk but ``leave`` (bytes; default 0), as another program
    that filled it once would, without taking what the server frees afterwards, into
    ``folder / "filler.bin"``. A loop of writes
    until one fails took more: the server may meet the full disk first (the scan's next
    A-line) and give up its job store's reserve, and the loop then took the freed reserve too,
    so that a cancel afterwards found no room (seen in loaded runs). Here: all but a slack of
    4 MiB in one allocation (the server's writes meanwhile fit the slack), then the slack; a
    step retried after a write of the server's came in between (ENOSPC) never asks for more
    than it measured first, so a reserve freed meanwhile stays free. A write loop only where
    the system cannot allocate."""
    fd = os.open(folder / "filler.bin", os.O_WRONLY | os.O_CREAT, 0o600)

    def free() -> int:
        st = os.statvfs(folder)
        return st.f_bavail * st.f_frsize

    try:
        for slack in (leave + (4 << 20), leave):
            want = free() - slack
            for _ in range(1000):  # bounded: each retry follows a write of the server's
                if want <= 0:
                    break
                try:
                    os.posix_fallocate(fd, 0, os.fstat(fd).st_size + want)
                    break
                except OSError as exc:
                    if exc.errno != errno.ENOSPC:
                        raise
                    want = min(want, free() - slack)
    except OSError:  # no fallocate on this file system: write until the disk is full
        try:
            while True:
                os.write(fd, b"\0" * (1 << 20))
        except OSError:
            pass
    finally:
        os.close(fd)
