"""Where a reconstruction runs: the ``device`` option (``"auto"``, ``"cpu"``, ``"cuda"``).

``"cuda"`` runs the GPU path (`fpscan.service.recon.gpu`: CuPy, cuFFT, the array-namespace temporal
step of `fpscan.physics.temporal_xp`) on the first CUDA device CuPy sees; ``"cpu"`` the CPU
kernels; ``"auto"`` (the default) the GPU when CuPy is installed and sees one, the method's GPU
path covers the request, the job fits the GPU's free memory and no other fpscan job holds the
GPU, else the CPU. CuPy is imported here only when a request is not ``"cpu"`` (and never by
``import fpscan``): a CPU install needs neither CuPy nor a driver.

One GPU job at a time per GPU: a job takes the GPU's lock (an ``flock`` on a file in the
temporary directory, so that every process of the machine — the server's workers, a CLI run —
shares it) for its run. ``"auto"`` never waits for it (the CPU takes the job); ``"cuda"`` waits,
polling ``wait`` (a cancel's checkpoint) every 0.2 s.

A GPU that fails mid-run (out of memory, a driver or cuFFT error: :func:`is_gpu_error`) raises
:class:`GpuError` with the reason where ``"cuda"`` was asked, and falls back to the CPU where
``"auto"`` chose the GPU; the result's params say which device ran (``device``) and why it is
not the GPU chosen (``device_fallback``).
"""
from __future__ import annotations

import contextlib
import fcntl
import os
import tempfile
import time
from collections.abc import Callable, Iterator
from types import ModuleType
from typing import Any, TypeVar

from fpscan.driver.units import RefusedInput
from fpscan.service.recon.limits import DEFAULT_DEVICE, DEVICES

__all__ = ["DEVICES", "DEFAULT_DEVICE", "Unsuited", "GpuError", "check_device", "cupy_module", "gpu_module", "cuda_devices",
           "probe_devices", "choose",
           "is_gpu_error", "gpu_lock", "run", "release"]

#: share of the GPU's free memory a job may plan to use (cuFFT's work areas and the memory
#: pool's rounding take the rest)
GPU_MEMORY_SHARE = 0.85

T = TypeVar("T")
_CUPY: list[ModuleType | None] = []  # [] not looked for yet; [None] none usable
_HELD = [0]  # how deep this process holds the GPU's lock (a warm start inside a tv run takes it again)


class Unsuited(RefusedInput):
    """``device="cuda"`` cannot run this request here: no GPU, a request the GPU path does not
    cover, or more memory than the GPU has free (the message says which). A ValueError and a
    refused input (CLI exit 2, HTTP 422). Raised inside a GPU run that ``"auto"`` chose, it
    sends the request to the CPU (:func:`run`)."""


class GpuError(RuntimeError):
    """The GPU failed while running a job asked for ``device="cuda"`` (the message names the
    CUDA error: out of memory, a driver or cuFFT failure)."""


def check_device(device: Any) -> str:
    """The ``device`` option's rule: one of :data:`DEVICES`.

    Parameters
    ----------
    device : str or None
        None: the default (:data:`DEFAULT_DEVICE`).

    Returns
    -------
    str

    Raises
    ------
    ValueError
        Anything else, naming the choices.

    Examples
    --------
    >>> from fpscan.service.recon.device import check_device
    >>> check_device(None), check_device("cuda")
    ('auto', 'cuda')
    """
    if device is None:
        return DEFAULT_DEVICE
    if device not in DEVICES:
        raise ValueError(f"device must be one of {', '.join(DEVICES)}, got {device!r}")
    return str(device)


def cupy_module() -> ModuleType | None:
    """CuPy, imported on first use, where it is installed and sees a CUDA device; else None
    (never raises: a missing driver or library is "no GPU"). Set ``FPSCAN_NO_GPU=1`` to hide
    every GPU."""
    if not _CUPY:
        mod: ModuleType | None = None
        if os.environ.get("FPSCAN_NO_GPU", "") not in ("1", "true", "yes"):
            try:
                import cupy

                if cupy.cuda.runtime.getDeviceCount() > 0:
                    mod = cupy
            except Exception:
                mod = None
        _CUPY.append(mod)
    return _CUPY[0]


def gpu_module() -> ModuleType:
    """CuPy, for code that runs on the GPU :func:`choose` picked.

    Returns
    -------
    module
        ``cupy``.

    Raises
    ------
    Unsuited
        No GPU is visible (CuPy missing, no driver or device).
    """
    cp = cupy_module()
    if cp is None:
        raise Unsuited("no CUDA GPU is visible here (CuPy not installed, no driver or no device)")
    return cp


def cuda_devices() -> list[dict[str, Any]]:
    """The CUDA devices CuPy sees (none without CuPy or a driver).

    Returns
    -------
    list of dict
        Per device: ``index``, ``name``, ``memory_total`` and ``memory_free`` (bytes; free as
        the driver reports it, plus what this process's memory pool holds unused).
    """
    cp = cupy_module()
    if cp is None:
        return []
    out = []
    try:
        for index in range(cp.cuda.runtime.getDeviceCount()):
            with cp.cuda.Device(index):
                props = cp.cuda.runtime.getDeviceProperties(index)
                free, total = cp.cuda.runtime.memGetInfo()
                pooled = cp.get_default_memory_pool().free_bytes() if index == cp.cuda.Device().id else 0
            name = props["name"]
            out.append(dict(index=index, name=name.decode() if isinstance(name, bytes) else str(name),
                            memory_total=int(total), memory_free=int(free + pooled)))
    except Exception:
        return []
    return out


_PROBE = ("import json; from fpscan.service.recon.device import cuda_devices; "
          "print(json.dumps([{k: d[k] for k in ('index', 'name', 'memory_total')} for d in cuda_devices()]))")


def probe_devices(timeout: float = 120.0) -> list[dict[str, Any]]:
    """The CUDA devices, asked in a child process (so that the caller — the HTTP server's
    process — never loads CUDA or holds a GPU context); [] without a GPU, CuPy or an answer
    within ``timeout`` seconds.

    Parameters
    ----------
    timeout : float
        Seconds to wait for the child.

    Returns
    -------
    list of dict
        ``index``, ``name``, ``memory_total`` (bytes) per device.
    """
    import importlib.util
    import json
    import subprocess
    import sys

    if os.environ.get("FPSCAN_NO_GPU", "") in ("1", "true", "yes") or importlib.util.find_spec("cupy") is None:
        return []  # no child where CuPy is not even installed (a CPU install)
    try:
        done = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=timeout,
                              cwd=os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
        found = json.loads(done.stdout.strip().splitlines()[-1]) if done.returncode == 0 and done.stdout.strip() else []
    except (OSError, subprocess.SubprocessError, ValueError):
        return []
    return [d for d in found if isinstance(d, dict)]


def choose(device: str, need_bytes: int, unsupported: str | None = None) -> str:
    """The device a request runs on: ``"cpu"`` or ``"cuda"``.

    Parameters
    ----------
    device : {"auto", "cpu", "cuda"}
    need_bytes : int
        The GPU memory the request's GPU path needs (its estimate), bytes.
    unsupported : str, optional
        Why the method's GPU path cannot run this request (None: it can).

    Returns
    -------
    str
        ``"cuda"`` where asked (or chosen by ``"auto"``: a GPU, a supported request, and
        ``need_bytes`` within `GPU_MEMORY_SHARE` of its free memory), else ``"cpu"``.

    Raises
    ------
    Unsuited
        (a ValueError) ``"cuda"`` asked where there is no GPU, the request is unsupported (the
        reason), or it needs more memory than the GPU has free.
    ValueError
        An unknown device.

    Examples
    --------
    >>> from fpscan.service.recon.device import choose
    >>> choose("cpu", 1 << 40)
    'cpu'
    """
    device = check_device(device)
    if device == "cpu":
        return "cpu"
    gpus = cuda_devices()
    if not gpus:
        if device == "cuda":
            raise Unsuited("device 'cuda' was asked, but no CUDA GPU is visible here (CuPy not installed, "
                             "no driver or no device; install fpscan[cuda] on a machine with an NVIDIA GPU)")
        return "cpu"
    if unsupported is not None:
        if device == "cuda":
            raise Unsuited(f"device 'cuda' cannot run this request: {unsupported}")
        return "cpu"
    free = gpus[0]["memory_free"]
    if need_bytes > GPU_MEMORY_SHARE * free:
        if device == "cuda":
            raise Unsuited(f"the GPU path needs about {need_bytes / 2**30:.2f} GiB of GPU memory, the GPU "
                             f"({gpus[0]['name']}) has {free / 2**30:.2f} GiB free")
        return "cpu"
    return "cuda"


def is_gpu_error(exc: BaseException) -> bool:
    """Whether ``exc`` is the GPU failing (CuPy's out-of-memory, CUDA runtime, driver, cuFFT
    or compiler errors), not the request.

    Parameters
    ----------
    exc : BaseException

    Returns
    -------
    bool
    """
    module = type(exc).__module__ or ""
    return module.startswith(("cupy", "cupy_backends", "cupyx")) or type(exc).__name__ in (
        "OutOfMemoryError", "CUDARuntimeError", "CUDADriverError", "CuFFTError", "CompileException")


@contextlib.contextmanager
def gpu_lock(index: int = 0, wait: bool = True, poll: Callable[[], None] | None = None) -> Iterator[bool]:
    """Hold GPU ``index`` for one job (module doc): yields True when held, False when ``wait``
    is False and another process holds it. ``poll()`` is called every 0.2 s while waiting (it
    may raise: a cancelled job stops waiting)."""
    if _HELD[0]:  # this process holds it already
        _HELD[0] += 1
        try:
            yield True
        finally:
            _HELD[0] -= 1
        return
    path = os.path.join(tempfile.gettempdir(), f"fpscan-gpu-{index}.lock")
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if not wait:
                    yield False
                    return
                if poll is not None:
                    poll()
                time.sleep(0.2)
        _HELD[0] += 1
        try:
            yield True
        finally:
            _HELD[0] -= 1
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def release() -> None:
    """Give this process's unused GPU memory back to the driver (CuPy's pools) and drop the GPU
    path's cached taps, so that another process can use it (a job worker calls it after each
    job; a GPU failure too); nothing without CuPy."""
    if not _CUPY or _CUPY[0] is None:
        return
    from fpscan.service.recon import gpu

    gpu.clear_cache()
    cp = _CUPY[0]
    cp.get_default_memory_pool().free_all_blocks()
    cp.get_default_pinned_memory_pool().free_all_blocks()


def run(device: str, need_bytes: int, on_gpu: Callable[[], T], on_cpu: Callable[[], T],
        unsupported: str | None = None, poll: Callable[[], None] | None = None) -> tuple[T, dict[str, Any]]:
    """Run a request on the device :func:`choose` picks, holding the GPU's lock for a GPU run.

    Parameters
    ----------
    device : {"auto", "cpu", "cuda"}
    need_bytes : int
        GPU memory the GPU path needs, bytes.
    on_gpu, on_cpu : callable
        The request on each device (no arguments).
    unsupported : str, optional
        Why the GPU path cannot run this request (None: it can).
    poll : callable, optional
        Called while ``"cuda"`` waits for the GPU's lock (a cancel's checkpoint).

    Returns
    -------
    result, dict
        What ran returned, and the facts for the result's params: ``device`` (``"cpu"`` or
        ``"cuda"``), with ``device_name`` for a GPU and ``device_fallback`` (the reason) where
        ``"auto"`` chose the GPU and the CPU ran.

    Raises
    ------
    ValueError
        As :func:`choose` (:class:`Unsuited`, also where ``on_gpu`` raises it for a ``"cuda"``
        request; for an ``"auto"`` one the CPU runs instead).
    GpuError
        The GPU failed during a ``"cuda"`` request (the CUDA error's text).
    """
    device = check_device(device)
    chosen = choose(device, need_bytes, unsupported)
    if chosen == "cpu":
        return on_cpu(), {"device": "cpu"}
    name = cuda_devices()[0]["name"]
    with gpu_lock(0, wait=device == "cuda", poll=poll) as held:
        if not held:  # another job holds the GPU: "auto" does not wait
            return on_cpu(), {"device": "cpu", "device_fallback": "the GPU was busy with another job"}
        try:
            return on_gpu(), {"device": "cuda", "device_name": name}
        except Unsuited as exc:  # found inside the run (an operator's memory, off-lattice sensors)
            if device == "cuda":
                raise
            release()
            return on_cpu(), {"device": "cpu", "device_fallback": str(exc)}
        except Exception as exc:
            if not is_gpu_error(exc):
                raise
            reason = f"{type(exc).__name__}: {exc}"
            release()
    if device == "cuda":
        raise GpuError(f"the GPU ({name}) failed: {reason}")
    return on_cpu(), {"device": "cpu", "device_fallback": f"the GPU ({name}) failed: {reason}"}
