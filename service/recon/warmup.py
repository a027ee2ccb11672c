"""Fill numba's cache of the reconstruction's compiled kernels (``fpscan warmup``).

Every numba kernel of the reconstruction (``driver.physics.nufft_kernels``, ``service.recon.kwave``)
is ``@numba.njit(cache=True)``: the first call in any interpreter compiles it for the
argument types it gets and writes the machine code to numba's cache; later interpreters
load it instead of compiling (seconds saved on the first reconstruction). Where the cache
lives: ``NUMBA_CACHE_DIR`` when set; otherwise ``__pycache__`` beside the kernel's module
when that directory is writable; otherwise numba's user-wide cache directory (e.g.
``~/.cache/numba``). A read-only install (a system site-packages, a container image) should
run ``fpscan warmup`` as the user who reconstructs, or set ``NUMBA_CACHE_DIR`` to a writable
directory for both the warm-up and the reconstructions. The cache of a kernel is kept until
its source file changes (numba checks the file's time stamp and size).

:func:`warm_up` runs each method once on tiny data in each precision, so that every kernel
is compiled for every argument type a reconstruction passes it.
"""
from __future__ import annotations

import time

import numpy as np

from driver.constants import C_DEFAULT

__all__ = ["DTYPES", "GROUPS", "warm_up", "cache_dirs"]

DTYPES = ("float32", "float64")


#: the kernel groups :func:`warm_up` compiles, in the order it does: NER and NEDNER (the
#: planar inversions: numba, scipy.fft), the k-Wave-compatible modes, the model-based operator
#: and forward model (``tv``: also pylops and pyproximal, the slowest imports)
GROUPS = ("planar", "kwave", "model")


def warm_up(dtypes=DTYPES, groups=GROUPS) -> dict:
    """Compile (or load from the cache) every numba kernel of the reconstruction.

    Runs NER (grid), NEDNER (scattered A-lines), the k-Wave-compatible modes and the forward
    model (the model-based method's operator) on tiny data, in each of ``dtypes``.

    Parameters
    ----------
    dtypes : iterable of str, optional
        ``"float32"`` and/or ``"float64"``; default both.
    groups : iterable of str, optional
        Names in :data:`GROUPS`; default all: ``"planar"`` (NER, NEDNER), ``"kwave"`` (the
        k-Wave-compatible modes), ``"model"`` (the model-based operator and the forward
        model). A job server warms ``"planar"`` and ``"kwave"`` before its worker takes a
        job and ``"model"`` beside it (``service.jobs.work.WARM_FIRST``, ``WARM_LATER``).

    Returns
    -------
    dict
        ``seconds`` (float, wall time, s) and ``cache_dirs`` (sorted list of str: the
        directories numba's cache of these kernels is in).

    Raises
    ------
    ValueError
        An unknown dtype or group.

    Examples
    --------
    >>> from service.recon.warmup import warm_up
    >>> sorted(warm_up(["float32"]))  # doctest: +SKIP
    ['cache_dirs', 'seconds']
    >>> warm_up(["float16"])  # refused before anything runs
    Traceback (most recent call last):
    ...
    ValueError: dtype must be one of ('float32', 'float64'), got 'float16'
    """
    names = [str(d) for d in dtypes]
    for d in names:
        if d not in DTYPES:
            raise ValueError(f"dtype must be one of {DTYPES}, got {d!r}")
    wanted = [str(g) for g in groups]
    for g in wanted:
        if g not in GROUPS:
            raise ValueError(f"group must be one of {GROUPS}, got {g!r}")
    t0 = time.perf_counter()
    for g in GROUPS:  # in the order of GROUPS
        if g in wanted:
            _WARM[g](names)
    return {"seconds": time.perf_counter() - t0, "cache_dirs": cache_dirs(wanted)}


_DX, _DT = 1e-4, 2e-8


def _tiny(d: str, n: int = 6) -> np.ndarray:
    data = np.zeros((32, n, n), dtype=d)
    data[5, 3, 3] = 1.0
    return data


#: lateral samples of the planar warm-up: above `driver.physics.fft_engine.SMALL_ELEMENTS`
#: (a smaller transform runs in numpy and would compile nothing)
_PLANAR_N = 64


def _warm_planar(names: list[str]) -> None:
    from service.recon.planar import reconstruct_grid, reconstruct_points

    n = _PLANAR_N
    rng = np.random.default_rng(0)
    for d in names:
        data = _tiny(d, n)
        reconstruct_grid(data, _DX, _DT, dtype=d)
        reconstruct_grid(np.tile(data[:, 0, :], (1, n)), _DX, _DT, dtype=d)  # a line of n * n sensors
        pos = rng.uniform(0.0, (n - 1) * _DX, (30, 2))
        grid = (np.arange(n) * _DX, np.arange(n) * _DX)
        reconstruct_points(rng.standard_normal((30, 32)).astype(d), pos, _DT, weights=np.full(30, _DX * _DX),
                           grid=grid, dtype=d)


def _warm_kwave(names: list[str]) -> None:
    from service.recon.kwave import kspace_line_recon, kspace_plane_recon

    for d in names:
        data = _tiny(d)
        for interp in ("*nearest", "*linear"):
            kspace_plane_recon(data, _DX, _DX, _DT, C_DEFAULT, interp=interp, dtype=d)
            kspace_line_recon(data[:, 0, :], _DX, _DT, C_DEFAULT, interp=interp, dtype=d)


def _warm_model(names: list[str]) -> None:
    from driver.physics.forward import forward_grid
    from service.recon import tv
    from service.recon.operator import PlanarOperator

    for d in names:  # the model-based operator runs its transforms in the working precision
        op = PlanarOperator((4, 6, 6), _DX, C_DEFAULT * _DT, _DT, 32, dtype=d)
        op.adjoint(op.forward(np.ones((4, 6, 6))))
        v = np.ones((4, 6, 6), dtype=d)  # the TV part's compiled sweeps (2-D images run as 3-D views)
        tv._tv_prox(v, 0.1, True, None, None)
        tv._tv_norm(v)
        tv._apply_weight(tv._ner_weight(v.shape, _DX, C_DEFAULT * _DT), v)  # the preconditioner's kernel
        flat = v.ravel()  # the solver's in-place vector kernels
        tv._axpy(flat, flat, 0.5)
        tv._extrapolate(flat, flat, 0.5)
        tv._difference_norm(flat, flat)
        tv._moves(flat, flat, flat, 1.0, flat, 0.5)
        dual = np.zeros((3, 4, 6, 6), dtype=d)  # the dual's wait between iterations
        tv._restore_dual(tv._store_dual(dual), dual.dtype)
    forward_grid(np.ones((4, 6, 6)), _DX, C_DEFAULT * _DT, _DT, 32)


_WARM = {"planar": _warm_planar, "kwave": _warm_kwave, "model": _warm_model}


#: the modules holding each group's numba kernels
_KERNEL_MODULES = {
    "planar": ("driver.physics.nufft_kernels",),
    "kwave": ("service.recon.kwave",),
    "model": ("driver.physics.nufft_kernels", "service.recon.tv"),
}


def cache_dirs(groups=GROUPS) -> list[str]:
    """The directories numba's cache of the reconstruction's kernels is in.

    Parameters
    ----------
    groups : iterable of str, optional
        Names in :data:`GROUPS` whose kernels are looked at (their modules are imported);
        default all.

    Returns
    -------
    list of str
        Sorted; ``NUMBA_CACHE_DIR`` when set, else ``__pycache__`` beside the kernels'
        modules where writable, else numba's user-wide cache.

    Raises
    ------
    ValueError
        An unknown group.

    Examples
    --------
    >>> from service.recon.warmup import cache_dirs
    >>> dirs = cache_dirs()
    >>> dirs == sorted(dirs) and all(isinstance(d, str) for d in dirs)
    True
    """
    import importlib

    import numba

    names: list[str] = []
    for g in groups:
        if g not in _KERNEL_MODULES:
            raise ValueError(f"group must be one of {GROUPS}, got {g!r}")
        names += [m for m in _KERNEL_MODULES[g] if m not in names]
    dirs = set()
    for name in names:
        for value in vars(importlib.import_module(name)).values():
            cache = getattr(value, "_cache", None)
            if isinstance(value, numba.core.registry.CPUDispatcher) and cache is not None:
                path = getattr(cache, "cache_path", None) or getattr(cache, "_cache_path", None)
                if path:
                    dirs.add(str(path))
    return sorted(dirs)
