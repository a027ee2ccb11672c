"""Fill numba's cache of the reconstruction's compiled kernels (``fpscan warmup``).

Every numba kernel of the reconstruction (``fpscan.physics.nufft_kernels``, ``fpscan.service.recon.kwave``)
is ``@numba.njit(cache=True)``: the first call in any interpreter compiles it for the
argument types it gets and writes the machine code to numba's cache; later interpreters
load it instead of compiling (seconds saved on the first reconstruction). Where the cache
lives: ``NUMBA_CACHE_DIR`` when set; otherwise ``__pycache__`` beside the kernel's module
when that directory is writable; otherwise numba's user-wide cache directory (e.g.
``~/.cache/numba``). A read-only install (a system site-packages, a container image) should
run ``fpscan warmup`` as the user who reconstructs, or set ``NUMBA_CACHE_DIR`` to a writable
directory for both the warm-up and the reconstructions. The cache of a kernel is kept until
its source file changes (numba checks the file's time stamp and size).

:func:`warm_up` runs each method's own warm-up (``fpscan.service.recon.methods``: ``Method.warm_up``)
once on tiny data in each precision, so that every kernel is compiled for every argument type a
reconstruction passes it.
"""
from __future__ import annotations

import time
from collections.abc import Iterable
from typing import Any

__all__ = ["DTYPES", "warm_up", "cache_dirs"]

DTYPES = ("float32", "float64")


def _methods(names: Iterable[str] | None, background: bool | None) -> list[Any]:
    """The registered methods called ``names`` (None: all) that have a warm-up, those whose
    ``warm_in_background`` is ``background`` (None: either), in list order."""
    from fpscan.service.recon.methods import METHODS, get

    chosen = list(METHODS.values()) if names is None else [get(str(n)) for n in names]
    return [m for m in chosen if m.warm_up is not None
            and (background is None or m.warm_in_background == background)]


def warm_up(dtypes: Iterable[str] = DTYPES, methods: Iterable[str] | None = None,
            background: bool | None = None) -> dict:
    """Compile (or load from the cache) every numba kernel of the reconstruction.

    Runs each method's own warm-up (``Method.warm_up``: the method on tiny data) in each of
    ``dtypes``, once per warm-up (methods sharing kernels share it).

    Parameters
    ----------
    dtypes : iterable of str, optional
        ``"float32"`` and/or ``"float64"``; default both.
    methods : iterable of str, optional
        Method names (``fpscan.service.recon.methods.METHODS``); default every registered one.
    background : bool or None, optional
        Only the methods whose ``warm_in_background`` is this (a job worker warms the quick
        ones before its first job and the slow ones beside it: ``fpscan.service.jobs.work.warm_up``);
        None: both.

    Returns
    -------
    dict
        ``seconds`` (float, wall time, s), ``methods`` (list of str: the methods warmed) and
        ``cache_dirs`` (sorted list of str: the directories numba's cache of their kernels is
        in).

    Raises
    ------
    ValueError
        An unknown dtype or method (``fpscan.service.recon.checks.OptionError``).

    Examples
    --------
    >>> from fpscan.service.recon.warmup import warm_up
    >>> sorted(warm_up(["float32"]))  # doctest: +SKIP
    ['cache_dirs', 'methods', 'seconds']
    >>> warm_up(["float16"])  # refused before anything runs
    Traceback (most recent call last):
    ...
    ValueError: dtype must be one of ('float32', 'float64'), got 'float16'
    """
    names = [str(d) for d in dtypes]
    for d in names:
        if d not in DTYPES:
            raise ValueError(f"dtype must be one of {DTYPES}, got {d!r}")
    chosen = _methods(methods, background)
    t0 = time.perf_counter()
    done: list[Any] = []
    for m in chosen:
        if m.warm_up not in done:
            m.warm_up(names)
            done.append(m.warm_up)
    return {"seconds": time.perf_counter() - t0, "methods": [m.name for m in chosen],
            "cache_dirs": cache_dirs(m.name for m in chosen)}


def cache_dirs(methods: Iterable[str] | None = None) -> list[str]:
    """The directories numba's cache of the reconstruction's kernels is in.

    Parameters
    ----------
    methods : iterable of str, optional
        Method names whose kernels (``Method.kernel_modules``) are looked at (their modules
        are imported); default every registered method.

    Returns
    -------
    list of str
        Sorted; ``NUMBA_CACHE_DIR`` when set, else ``__pycache__`` beside the kernels'
        modules where writable, else numba's user-wide cache.

    Raises
    ------
    ValueError
        An unknown method (``fpscan.service.recon.checks.OptionError``).

    Examples
    --------
    >>> from fpscan.service.recon.warmup import cache_dirs
    >>> dirs = cache_dirs()
    >>> dirs == sorted(dirs) and all(isinstance(d, str) for d in dirs)
    True
    """
    import importlib

    import numba

    from fpscan.service.recon.methods import METHODS, get

    chosen = list(METHODS.values()) if methods is None else [get(str(n)) for n in methods]
    names: list[str] = []
    for m in chosen:
        names += [k for k in m.kernel_modules if k not in names]
    dirs = set()
    for name in names:
        for value in vars(importlib.import_module(name)).values():
            cache = getattr(value, "_cache", None)
            if isinstance(value, numba.core.registry.CPUDispatcher) and cache is not None:
                path = getattr(cache, "cache_path", None) or getattr(cache, "_cache_path", None)
                if path:
                    dirs.add(str(path))
    return sorted(dirs)
