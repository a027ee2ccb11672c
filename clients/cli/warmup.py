"""`fpscan warmup`: compile the reconstruction's kernels into numba's cache, so that the
first reconstruction of every later interpreter (``fpscan recon``, the server's workers)
loads compiled code instead of compiling it (see ``fpscan.service.recon.warmup``: where the cache
lives, ``NUMBA_CACHE_DIR`` on a read-only install)."""
from __future__ import annotations

import argparse

__all__ = ["COMMAND", "HELP", "add_arguments", "run"]

COMMAND = "warmup"
HELP = "compile the reconstruction's kernels into numba's cache (run once after installing)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare this sub-command's options on ``parser`` (an ``argparse`` sub-parser).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser, changed in place.
    """
    parser.add_argument("--dtype", choices=["float32", "float64", "both"], default="both",
                        help="precision(s) to compile for (default both)")
    parser.add_argument("--quick", action="store_true",
                        help="only the methods that are quick to compile (every one but those a server's workers "
                             "compile in the background, after their first job can start: tv); the others compile "
                             "on their first run (scripts/demo.sh's set-up)")


def run(args: argparse.Namespace) -> int:
    """Run the tiny reconstructions; print the methods warmed, the time taken and the cache directories.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line (:func:`add_arguments`).

    Returns
    -------
    int
        0.

    Raises
    ------
    ValueError
        From :func:`fpscan.service.recon.warmup.warm_up` (not for the choices argparse allows).
    """
    from fpscan.service.recon.warmup import DTYPES, warm_up

    got = warm_up(DTYPES if args.dtype == "both" else (args.dtype,), background=False if args.quick else None)
    print(f"compiled the kernels of {', '.join(got['methods']) or 'no method'} in {got['seconds']:.1f} s; "
          f"numba cache: {', '.join(got['cache_dirs']) or '(none)'}")
    return 0
