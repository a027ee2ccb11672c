"""Work arrays kept between calls, so that a reconstruction's steady state touches no fresh pages.

A fresh array's pages are mapped when first written: the operating system zeroes each page on
a page fault, and for a large array (numpy asks for transparent huge pages) may first compact
memory to find a huge page. On the 2-core machine (load 10-12) first writing 239 MB of fresh
memory took 0.13-2.0 s, the same pages written again 0.02 s; so a step that writes a fresh
volume spends most of its time in the kernel's page faults, serially where the writing step is
serial. FFTW and FINUFFT keep their work arrays in their plans for the same reason.

:func:`take` lends an array on a buffer of the pool. A buffer is busy while any array made from
it is alive (numpy's views keep their base alive; its reference count says so, CPython), so an
array the caller keeps (the image a reconstruction returns lives in its work memory) is never
lent twice; once the last of them is dropped, the buffer is free and the next :func:`take` of
at most its size (and not much smaller) gets it, its pages already mapped. A request no free
buffer fits drops the free ones that no recent request took (the pool holds the arrays of the
calls that recur: a reconstruction repeated, the operator pair of an iterative solve). The pool keeps buffers up to
a quarter of the machine's memory (:func:`limit`); beyond it a :func:`take` gets an array of
its own. Its free buffers are released with :func:`release` (`fpscan.service.recon.checks.check_memory`
does before it refuses a reconstruction for want of memory; a job worker does once it has been
idle a while). Arrays below :data:`MIN_BYTES` are not pooled (the C heap reuses those).
"""
from __future__ import annotations

import os
import sys
import threading

import numpy as np
import numpy.typing as npt

__all__ = ["MIN_BYTES", "LARGEST", "AGE", "take", "release", "held", "limit"]

#: arrays smaller than this (bytes) are allocated as usual: the C heap keeps and reuses them
MIN_BYTES = 4 << 20
#: a free buffer is lent for a request of at least 1 / LARGEST of its size (a larger one would
#: keep pages resident that the request does not use)
LARGEST = 1.5

#: a miss drops the free buffers lent in none of the last AGE takes
AGE = 64

_LOCK = threading.Lock()
_BUFFERS: list[np.ndarray] = []
_LENT: dict[int, int] = {}  # id of a buffer -> the take that last lent it
_TAKES = 0


def _refs_when_free() -> int:
    """The reference count `_is_free` reads of a pooled buffer that nothing else holds."""
    probe = [np.empty(1, np.uint8)]
    return sys.getrefcount(probe[0])


_FREE_REFS = _refs_when_free()


def _is_free(i: int) -> bool:
    return sys.getrefcount(_BUFFERS[i]) <= _FREE_REFS


def limit() -> int:
    """Bytes the pool keeps at most: a quarter of the machine's physical memory.

    Returns
    -------
    int
        Bytes.

    Examples
    --------
    >>> from fpscan.physics.workspace import limit
    >>> limit() > 0
    True
    """
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") // 4
    except (ValueError, OSError, AttributeError):  # no sysconf: 1 GiB
        return 1 << 30


def held() -> int:
    """Bytes of the buffers the pool holds now (busy and free).

    Returns
    -------
    int
        Bytes.

    Examples
    --------
    >>> from fpscan.physics.workspace import held
    >>> held() >= 0
    True
    """
    with _LOCK:
        return sum(b.nbytes for b in _BUFFERS)


def release() -> int:
    """Drop the pool's free buffers (their memory goes back to the system); busy ones stay.

    Returns
    -------
    int
        Bytes released.

    Examples
    --------
    >>> from fpscan.physics.workspace import release, take
    >>> a = take((1 << 20,), "float64")  # 8 MiB: pooled
    >>> del a
    >>> release() >= 8 << 20
    True
    """
    with _LOCK:
        free = [i for i in range(len(_BUFFERS)) if _is_free(i)]
        freed = sum(_BUFFERS[i].nbytes for i in free)
        for i in reversed(free):
            _drop(i)
    return freed


def take(shape: int | tuple[int, ...], dtype: npt.DTypeLike) -> np.ndarray:
    """A C-contiguous array of ``shape`` and ``dtype``, its contents undefined, on a free buffer
    of the pool where one is large enough and at most `LARGEST` times the request (the smallest
    such: its pages already mapped); else the pool drops its free buffers lent in none of the
    last `AGE` takes and the array gets a new buffer, which the pool keeps if it stays within
    :func:`limit` (dropping the other free buffers first if that makes room).

    Parameters
    ----------
    shape : int or tuple of int
        The array's shape.
    dtype : dtype
        Its dtype.

    Returns
    -------
    ndarray
        ``shape``, ``dtype``; busy (never lent again) until it and every view of it are gone.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.workspace import take
    >>> a = take((1024, 1024), np.complex64)  # 8 MiB
    >>> address = a.ctypes.data
    >>> b = take((1024, 1024), np.complex64)  # a is alive: another buffer
    >>> b.ctypes.data != address
    True
    >>> del a
    >>> take((768, 1024), np.complex64).ctypes.data == address  # a's buffer, warm
    True
    """
    shape = (shape,) if isinstance(shape, int | np.integer) else tuple(shape)
    shape = tuple(int(s) for s in shape)
    dtype = np.dtype(dtype)
    need = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if need < MIN_BYTES:
        return np.empty(shape, dtype)
    with _LOCK:
        global _TAKES
        _TAKES += 1
        best = -1
        for i in range(len(_BUFFERS)):
            size = _BUFFERS[i].nbytes
            if need <= size <= LARGEST * need and (best < 0 or size < _BUFFERS[best].nbytes) and _is_free(i):
                best = i
        if best >= 0:
            buf = _BUFFERS[best]
            _LENT[id(buf)] = _TAKES
        else:
            # a miss: free buffers lent in none of the last `AGE` takes belong to calls that do
            # not recur (another size of problem); dropped, so that the pool holds the arrays of
            # the calls that do (a reconstruction repeated, the pair of an iterative solve)
            room = limit()
            for i in reversed(range(len(_BUFFERS))):
                if _is_free(i) and _LENT.get(id(_BUFFERS[i]), 0) <= _TAKES - AGE:
                    _drop(i)
            buf = np.empty(need, np.uint8)
            total = sum(b.nbytes for b in _BUFFERS)
            if total + need > room:  # beyond the limit: the free buffers make room first
                for i in reversed(range(len(_BUFFERS))):
                    if _is_free(i):
                        total -= _BUFFERS[i].nbytes
                        _drop(i)
            if total + need <= room:
                _BUFFERS.append(buf)
                _LENT[id(buf)] = _TAKES
        return buf[:need].view(dtype).reshape(shape)


def _drop(i: int) -> None:
    _LENT.pop(id(_BUFFERS[i]), None)
    del _BUFFERS[i]
