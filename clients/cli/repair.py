"""`fpscan repair`: close a scan file that its writer left open (``kill -9``, a crash, a power
cut), so that any HDF5 reader opens it (``h5py.File(path, "r")``, HDFView, MATLAB), with exactly
the A-lines its record marks complete (``fpscan.driver.scanfile.repair``). Resuming the scan
(``fpscan scan`` with the same ``--out``) repairs it too; ``repair`` is for a file that is to be
read as it is. A file being written is refused; one closed cleanly is checked and left as it is.
"""
from __future__ import annotations

import argparse

__all__ = ["COMMAND", "HELP", "add_arguments", "run"]

COMMAND = "repair"
HELP = "close a scan file left open by a killed scan (kill -9, power cut) so that any reader opens it"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare ``fpscan repair``'s arguments on ``parser``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser, changed in place.
    """
    parser.add_argument("files", nargs="+", metavar="FILE", help="scan file(s) (HDF5)")


def run(args: argparse.Namespace) -> int:
    """Repair each file; print one line per file (what it holds, what was done).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line (:func:`add_arguments`).

    Returns
    -------
    int
        0 when every file is (now) closed cleanly.

    Raises
    ------
    ValueError
        A file that is not a scan file, is corrupt or truncated, or is being written (exit 2).
    FileNotFoundError
        A missing file (exit 1).
    """
    from fpscan.driver.scanfile import repair

    for path in args.files:
        r = repair(path)
        state = "was left open by its writer, now closed" if r.was_open else "was closed cleanly"
        spectral = f" ({r.alines_done} A-lines)" if r.alines_done != r.points_done else ""
        stray = (f"; {r.alines_cleared} A-line(s) written but not marked complete zeroed"
                 if r.alines_cleared else "")
        print(f"{path}: {state}; {r.points_done}/{r.n_points} points complete{spectral}{stray}")
    return 0
