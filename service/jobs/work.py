"""The reconstruction job body: runs inside an executor worker (process pool or dask).

``run_reconstruction(spec)`` runs :func:`fpscan.service.pipeline.run_file` (the one orchestration,
the same call ``fpscan recon`` and ``fpscan unmix`` make locally: the input read with
``fpscan.service.storage.loader``, reconstructed with :func:`fpscan.service.pipeline.reconstruct`, the
result folder written with ``fpscan.service.storage.results.write_result``) with the worker's own
parts (memory admission and bounds, progress and cancel files):

- ``volume.h5``: ``/p0`` (``(n_z, n_y, n_x)`` or ``(n_z, n_x)``, Pa relative to the
  input's units), ``/z``, ``/x`` (and ``/y``) coordinate vectors in m; attributes
  ``method``, ``params`` (JSON of every parameter used), ``input_id``;
- ``mip_xy.png``, ``mip_xz.png``, ``mip_yz.png`` (3-D) or ``mip_xz.png`` (2-D).

Inputs (``spec["input"]``):
- ``{"kind": "dataset", "path": <dataset.h5>}``: the canonical dataset file
  (:func:`fpscan.service.storage.loader.write_dataset`) of an upload;
- ``{"kind": "scan", "path": <scan.h5>}``: a scan file; its completed points are used
  (a full lattice also with the grid methods).

Either may add ``"wavelength"``: an index into a multi-wavelength file's excitation
wavelengths (default: the first, recorded in the result's params as ``wavelength_index``
and ``wavelength_nm``), or ``"all"``: every wavelength reconstructed with the same method
and options, written as the unmixing job writes them (``volume.h5`` + MIPs of the first
at the top, ``wavelength_<k>/`` for each; :func:`fpscan.service.spectral.write_wavelength_results`).

Everything here is a plain function of picklable arguments so dask can ship it.
"""
from __future__ import annotations

import contextlib
import math
import os
import threading
import time
from collections.abc import Iterator
from typing import Any

from fpscan.constants import C_DEFAULT
from fpscan.service.progress import Progress
from fpscan.service.recon.limits import DEFAULT_DTYPE

__all__ = [
    "INPUT_FORMATS", "report_stage", "progress_file", "ProgressLog", "check_memory_limit", "ADDRESS_SPACE_BASE",
    "address_space_limit", "memory_bounded", "run_reconstruction", "worker_pid", "warm_up",
    "warm_heap", "HEAP_MMAP_THRESHOLD", "HEAP_WARM_BYTES", "JobGate", "JOB_GATE", "WARM_QUIET_S", "POOL_QUIET_S",
    "release_when_quiet",
]

INPUT_FORMATS = {"scan": "fpscan", "dataset": "dataset"}


def report_stage(path: str | None, stage: str, fraction: float, **fields: Any) -> None:
    """Append the job's current stage to its progress file ``path``.

    One JSON line ``{"stage", "fraction", **fields}`` per report, written with one ``write``
    in append mode, so a reader sees whole lines in order. The server's job thread reads the
    new lines (:class:`ProgressLog`) and turns them into progress events: no stage is lost,
    however short (a solve that ends between two of its reads still shows its iterations).
    Progress is best effort: a file that cannot be written (a remote worker without the
    folder, a full disk) is ignored.

    Parameters
    ----------
    path : str or None
        The progress file; None or ``""``: nothing is written.
    stage : str
        The stage's name (``"loading"``, ``"reconstructing"``, ...).
    fraction : float
        The fraction of the job done, in [0, 1].
    **fields
        More JSON-serialisable fields of the line (``eta_s``, an iteration's figures, ...).
    """
    if not path:
        return
    import json

    line = (json.dumps({"stage": str(stage), "fraction": fraction, **fields}) + "\n").encode()
    try:
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600)
        try:
            os.write(fd, line)
        finally:
            os.close(fd)
    except OSError:  # progress is best effort (e.g. a remote worker without the folder, a full disk)
        pass


def progress_file(path: str | None) -> Progress:
    """The :data:`fpscan.service.progress.Progress` that writes to the job's progress file ``path``.

    Each report goes through :func:`report_stage`; a report equal to the previous one is not
    written again, unless the ETA it showed has run out meanwhile (then once more, with
    ``eta_s`` null). Each line carries ``elapsed_s``, the seconds since the callback was made
    (the worker's clock: a line's ``elapsed_s + eta_s`` is the end it predicts), and, where
    known, the time left ``eta_s`` (``fpscan.service.progress.Eta``; an iterative method's with
    ``iterations_left_max``, the iterations left at most, its bound, ``eta_max_s``, their time
    at the measured rate, and ``eta_basis``) and an iterative method's iteration, its limit and its
    stopping rule's value and tolerance (``fpscan.service.progress.iteration_fields`` of an
    ``IterationStage``); a field a line no longer knows is written as null, since the job's
    progress merges the lines.

    Parameters
    ----------
    path : str or None
        The progress file; None: the callback writes nothing.

    Returns
    -------
    Progress
        The callback ``progress(fraction, stage)``.
    """
    import time

    from fpscan.service.progress import Eta, IterationStage, iteration_fields

    last: tuple[float, str] | None = None
    eta = Eta()
    before: set[str] = set()
    written: dict[str, Any] = {}  # the last line's fields
    started = time.monotonic()

    def write(fraction: float, stage: str) -> None:
        nonlocal last, before, written
        if last == (fraction, stage):
            # a repeat (a poll inside a long step): written again only when the ETA it showed has
            # run out meanwhile (fpscan.service.progress.Countdown), so that no stale figure stays
            if written.get("eta_s") is None or eta.read() is not None:
                return
            written = {**written, "eta_s": None, "elapsed_s": round(time.monotonic() - started, 2)}
            report_stage(path, stage, fraction, **written)
            return
        last = (fraction, stage)
        fields: dict[str, Any] = iteration_fields(stage) if isinstance(stage, IterationStage) else {}
        seconds = eta(fraction, stage)
        if seconds is not None:
            fields["eta_s"] = round(seconds, 1)
            if eta.bound_iterations is not None:  # an iterative method's: an estimate, and its bound in iterations
                fields.update(iterations_left_max=eta.bound_iterations, eta_max_s=round(eta.limit_s or 0.0, 1),
                              eta_basis=eta.basis)
        known = set(fields)
        fields.update(dict.fromkeys(before - known))  # cleared, not left stale in the merged progress
        before = known
        fields["elapsed_s"] = round(time.monotonic() - started, 2)
        written = fields
        report_stage(path, stage, fraction, **fields)

    return write


class ProgressLog:
    """The reader of a job's progress file (:func:`report_stage`'s lines), used by the server's job thread.

    ``new()`` returns the stages (``{"stage", "fraction", ...}`` dicts) written since its
    last call, in order, without repeats of the stage last returned and thinned to at most
    ``most`` (evenly spaced, the newest always kept) so a solve of thousands of short
    iterations does not flood the job's events. A line still being written waits for the
    next call; a missing file or a line that is not JSON is skipped. At most
    :attr:`READ_MAX` bytes are read per call.

    Parameters
    ----------
    path : str or os.PathLike
        The progress file.
    most : int, optional
        The most stages one ``new()`` returns, >= 1; default 16.

    Attributes
    ----------
    path : str or os.PathLike
        As given.
    most : int
        As given.
    offset : int
        Bytes of the file read so far (whole lines).
    last : dict or None
        The stage last returned.
    READ_MAX : int
        Bytes read per call at most (class attribute, 1 MiB).

    Raises
    ------
    ValueError
        For ``most`` < 1.
    """

    #: bytes read per call at most (the rest waits for the next call)
    READ_MAX = 1 << 20

    def __init__(self, path: str | os.PathLike, most: int = 16) -> None:
        if most < 1:
            raise ValueError(f"ProgressLog needs most >= 1, got {most!r}")
        self.path, self.most, self.offset = path, most, 0
        self.last: dict | None = None

    def new(self) -> list[dict]:
        import json

        try:
            with open(self.path, "rb") as f:
                f.seek(self.offset)
                chunk = f.read(self.READ_MAX)
        except OSError:
            return []
        end = chunk.rfind(b"\n") + 1
        self.offset += end
        out: list[dict] = []
        for line in chunk[:end].splitlines():
            try:
                stage = json.loads(line)
            except ValueError:
                continue
            if isinstance(stage, dict) and stage != (out[-1] if out else self.last):
                out.append(stage)
        if len(out) > self.most:
            step = len(out) / self.most
            out = [out[len(out) - 1 - int(k * step)] for k in range(self.most)][::-1]
        if out:
            self.last = out[-1]
        return out


def check_memory_limit(ds: Any, params: dict, limit: int, estimate: int | None = None) -> None:
    """Admission in the worker: refuse a job that needs more than ``limit`` bytes.

    The limit is the configured one, not the memory free now.

    Parameters
    ----------
    ds : GridDataset or PointDataset
        The dataset as loaded.
    params : dict
        The reconstruction's ``method`` and options.
    limit : int
        The memory limit in bytes.
    estimate : int or None, optional
        The job's own figure in bytes, made once when it was submitted
        (``fpscan.service.jobs.admission``); default None (a job that carries none): estimated here
        from the dataset as loaded (``input_shape``).

    Raises
    ------
    fpscan.service.jobs.admission.AdmissionError
        A ``ValueError`` with the reason, if the job needs more than ``limit``.
    """
    from fpscan.service.jobs.admission import admit, estimate_memory, input_shape

    admit(estimate_memory(input_shape(ds), params) if estimate is None else int(estimate), limit)


#: Address space a worker may use beyond the memory limit (interpreter, libraries, thread
#: stacks and allocator arenas are reserved, mostly never touched).
ADDRESS_SPACE_BASE = 6 * 2**30


@contextlib.contextmanager
def address_space_limit(limit: int | None) -> Iterator[None]:
    """Context manager: bound the process's address space while inside.

    The soft ``RLIMIT_AS`` is set to ``limit + ADDRESS_SPACE_BASE`` (at most the hard
    limit), so a reconstruction past the limit fails with MemoryError instead of swapping
    the machine; it is restored after. No-op without ``limit`` or where not supported.

    Parameters
    ----------
    limit : int or None
        The memory limit in bytes; None or 0: no bound.

    Yields
    ------
    None
    """
    try:
        import resource

        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        supported = True
    except (ImportError, OSError, ValueError):
        supported = False
    if not limit or not supported:
        yield
        return
    want = int(limit) + ADDRESS_SPACE_BASE
    if hard != resource.RLIM_INFINITY:
        want = min(want, hard)
    try:
        resource.setrlimit(resource.RLIMIT_AS, (want, hard))
    except (OSError, ValueError):
        yield
        return
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


@contextlib.contextmanager
def memory_bounded(limit: int | None) -> Iterator[None]:
    """Context manager: :func:`address_space_limit`, with a MemoryError turned into a ValueError.

    Parameters
    ----------
    limit : int or None
        The memory limit in bytes; None or 0: no bound.

    Yields
    ------
    None

    Raises
    ------
    ValueError
        When a MemoryError ends the block under a set ``limit``: the reason a job fails with.
    MemoryError
        Without a limit (a real out-of-memory, raised as it is).
    """
    try:
        with address_space_limit(limit):
            yield
    except MemoryError:
        if not limit:
            raise
        raise ValueError(f"the reconstruction ran out of the memory limit of {int(limit) / 2**30:.2f} GiB; "
                         "reduce the size, upsample or n_z, or use float32") from None


class JobGate:
    """Whether this worker process is running a job, for work that must wait for an idle worker.

    Used by the background warm-up (:func:`warm_up`'s ``rest_in_background``).
    ``with gate.busy():`` marks a job (nestable, thread-safe); ``gate.wait_idle()`` blocks
    while one runs and sets ``gate.waited`` first (so a caller can see that it yielded);
    ``gate.wait_quiet(s)`` blocks until no job has run for ``s`` seconds;
    ``gate.wait_ended(n)`` blocks until more than ``n`` jobs have ended (``gate.ended``).
    Takes no parameters.

    Attributes
    ----------
    waited : threading.Event
        Set once ``wait_idle`` had to wait for a job.
    ended : int
        Jobs ended so far (the outermost ``busy`` blocks).
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._jobs = 0
        self._idle = threading.Event()
        self._idle.set()
        self._last_end = -math.inf  # time.monotonic() when the last job ended
        self._changed = threading.Condition(self._lock)
        self.ended = 0
        self.waited = threading.Event()

    @contextlib.contextmanager
    def busy(self) -> Iterator[None]:
        with self._lock:
            self._jobs += 1
            self._idle.clear()
        try:
            yield
        finally:
            with self._lock:
                self._jobs -= 1
                if self._jobs == 0:
                    self._last_end = time.monotonic()
                    self.ended += 1
                    self._idle.set()
                    self._changed.notify_all()

    def wait_idle(self) -> None:
        if not self._idle.is_set():
            self.waited.set()
        self._idle.wait()

    def wait_quiet(self, seconds: float, since: float | None = None) -> None:
        """Block until no job runs and none has for ``seconds``.

        Parameters
        ----------
        seconds : float
            The quiet time in s, counted from the later of the last job's end and ``since``.
        since : float or None, optional
            A ``time.monotonic()`` value; default None: now.
        """
        since = time.monotonic() if since is None else since
        while True:
            self.wait_idle()
            with self._lock:
                left = max(self._last_end, since) + seconds - time.monotonic()
                if self._jobs == 0 and left <= 0:
                    return
            time.sleep(max(left, 0.0))

    def wait_ended(self, seen: int) -> None:
        """Block until more than ``seen`` jobs have ended.

        Parameters
        ----------
        seen : int
            A value of ``ended``.
        """
        with self._changed:
            self._changed.wait_for(lambda: self.ended > seen)


#: this worker process's jobs: :func:`run_reconstruction` holds it busy, the background
#: warm-up waits for it to be idle (and quiet: :data:`WARM_QUIET_S`) between its steps
JOB_GATE = JobGate()
#: the background warm-up takes a step only after this long without a job (s): a job that
#: comes right after start-up or right after another runs alone
WARM_QUIET_S = 2.0
#: a worker keeps its jobs' work arrays (`fpscan.physics.workspace`: the next job of the same size
#: runs in pages already mapped) until it has been this long without a job (s), then gives them
#: back to the system (:func:`release_when_quiet`)
POOL_QUIET_S = 30.0


def release_when_quiet(gate: JobGate, quiet: float = POOL_QUIET_S) -> None:
    """Forever: once ``gate`` has seen no job for ``quiet`` s after a job ended, release the
    work-array pool's free buffers (`fpscan.physics.workspace.release`); then wait for the next
    job to end. A worker runs it in a daemon thread (:func:`warm_up`), so that jobs back to back
    reuse their arrays' pages and an idle worker holds no more memory than its interpreter.

    Parameters
    ----------
    gate : JobGate
        The worker's (:data:`JOB_GATE`).
    quiet : float, optional
        s without a job (default :data:`POOL_QUIET_S`).
    """
    from fpscan.physics import workspace

    seen = 0
    while True:
        gate.wait_ended(seen)
        seen = gate.ended
        gate.wait_quiet(quiet)
        workspace.release()


def run_reconstruction(spec: dict) -> dict:
    """Executor entry point: run one reconstruction job and write its result folder.

    Holds :data:`JOB_GATE` busy while it runs (the background warm-up waits). The work-array
    pool's free buffers (`fpscan.physics.workspace`) are kept for it where they and the job's
    ``memory_estimate`` fit its ``memory_limit`` together (the address space is bounded to that
    limit, :func:`memory_bounded`), else released first.

    Parameters
    ----------
    spec : dict
        ``input`` (module docstring; or ``inputs``, a list of them, for unmixing with
        ``unmix``), ``params`` (``method`` and the options of
        :func:`fpscan.service.pipeline.reconstruct`), ``out_dir``, ``input_id``; optional
        ``progress_path`` (stages ``loading``, ``reconstructing``, ``writing`` are reported
        there), ``cancel_path`` (the reconstruction stops with ``fpscan.service.pipeline.Cancelled``
        once that file exists), ``memory_limit`` (bytes: admission checked again on the
        loaded input, address space bounded while it runs), ``memory_estimate`` (bytes, the
        figure made at submission) and ``wavelengths``.

    Returns
    -------
    dict
        ``{"shape", "max", "planes", "timings", "points_used", "outcome"}`` (``outcome``: an
        iterative method's one line on how it ended, ``fpscan.service.progress.outcome``).

    Raises
    ------
    ValueError
        For inputs of unknown or mixed kinds, inputs the method cannot use, or a job that
        exceeds the memory limit.
    fpscan.service.pipeline.Cancelled
        When the cancel file appears.
    """
    with JOB_GATE.busy():
        limit = spec.get("memory_limit")
        if limit:  # the last job's free work arrays count in the address space this job is bounded to
            from fpscan.physics import workspace

            if workspace.held() + int(spec.get("memory_estimate") or 0) > int(limit):
                workspace.release()
        return _run_reconstruction(spec)


def _run_reconstruction(spec: dict) -> dict:
    """The job's work: :func:`fpscan.service.pipeline.run_file` (the one orchestration, ``fpscan recon``'s
    and ``fpscan unmix``'s too) with the worker's own parts: the input files of the spec, the
    memory admission on the loaded data and the bounded address space, the progress file and the
    cancel file."""
    from fpscan.service.pipeline import run_file

    progress = spec.get("progress_path")
    cancel = spec.get("cancel_path")
    limit = spec.get("memory_limit")
    params = dict(spec["params"])
    method = params.pop("method", None)
    unmix = spec.get("unmix")
    inputs = spec.get("inputs") or [spec["input"]]
    kinds = {i.get("kind") for i in inputs}
    if len(kinds) != 1 or not kinds <= set(INPUT_FORMATS):
        raise ValueError(f"unknown job input kinds {sorted(map(str, kinds))}")

    def admit(ds: Any, chosen: str) -> None:  # the memory admission, again on the data as loaded
        if limit and unmix is None:
            check_memory_limit(ds, {**params, "method": chosen}, int(limit), spec.get("memory_estimate"))

    # a job that may run on a GPU: CUDA reserves virtual memory far beyond any address-space bound
    # (the memory admission still applies), and the GPU's memory goes back to the driver after it
    on_gpu = params.get("device") in ("auto", "cuda") and bool(_gpus())
    try:
        with memory_bounded(None if on_gpu else limit):
            return run_file([i["path"] for i in inputs], spec["out_dir"], method,
                            format=INPUT_FORMATS[kinds.pop()],
                            wavelength=None if unmix is not None else spec["input"].get("wavelength"),
                            wavelengths=spec.get("wavelengths"), unmix=None if unmix is None else dict(unmix),
                            input_id=spec.get("input_id", ""), progress=progress_file(progress),
                            plan=_plan(spec),
                            should_stop=(lambda: os.path.exists(cancel)) if cancel else None, on_loaded=admit,
                            **params)
    finally:
        if on_gpu:
            from fpscan.service.recon.device import release

            release()


def _gpus() -> list[dict]:
    """The CUDA devices of this worker (`fpscan.service.recon.device.cuda_devices`; CuPy is loaded on the
    first GPU-capable job)."""
    from fpscan.service.recon.device import cuda_devices

    return cuda_devices()


def _plan(spec: dict) -> Any:
    """The plan a job samples its dense dataset with (``spec["plan"]``, its JSON), or None
    for a job without one; ValueError where the job has one and the store no longer does."""
    if "plan" not in spec:
        return None
    if spec["plan"] is None:
        raise ValueError(f"the plan {spec['input'].get('plan_id')} this job samples its dataset with is gone")
    from fpscan.service.plans import Plan

    return Plan.from_json(spec["plan"])


def worker_pid() -> int:
    """The worker process's pid (a no-op job that starts a pool's workers).

    Returns
    -------
    int
        ``os.getpid()`` of the process it runs in.
    """
    return os.getpid()


def warm_up(full: bool = False, rest_in_background: bool = False) -> dict:
    """Make a fresh worker ready for its first job: import the reconstruction and the
    result writer; with ``full`` also compile (or load from numba's cache) every numba
    kernel a job uses, in float32 and float64 (:func:`fpscan.service.recon.warmup.warm_up`, the
    one warm-up ``fpscan warmup`` runs too), run one tiny job's dispatch and write its result
    folder (h5py and the fonts of the MIP pictures) into a temporary folder, start the thread
    that gives the jobs' work arrays back once the worker is idle (:func:`release_when_quiet`),
    and last give the heap written pages for the first job's arrays (:func:`warm_heap`).

    The warm-ups of the methods that are quick to warm (``Method.warm_in_background`` false:
    the planar inversions and the k-Wave modes, ~0.4 s from numba's cache; a first k-Wave job
    that loaded its own kernels took 3x its library time) in the default precision
    (``fpscan.service.recon.limits.DEFAULT_DTYPE``) and the writer come first; with
    ``rest_in_background`` the others (the quick methods in the other precision, 10 s of
    compilation where numba's cache lacks them, as after ``fpscan warmup --quick --dtype float32``;
    then the model-based operator with its pylops import: seconds) warm in a daemon thread
    after this returns, step by step while no job runs (:data:`JOB_GATE`), so the worker takes
    its first job that much sooner and runs it at full speed (a job that needs them meanwhile
    compiles or waits for them under numba's lock).

    Parameters
    ----------
    full : bool, optional
        Also compile the kernels, run a tiny job and write its result; default False (the
        imports only).
    rest_in_background : bool, optional
        With ``full``, take the steps after the first (the other precision, the methods that
        warm in the background) in a background thread rather than before returning; default
        False.

    Returns
    -------
    dict
        ``{"pid", "seconds"}``: the worker's pid and the seconds until return.
    """
    import h5py  # noqa: F401

    from fpscan.service import recon  # noqa: F401

    t0 = time.perf_counter()
    if full:
        import tempfile

        import numpy as np

        from fpscan.service.pipeline import default_method, reconstruct
        from fpscan.service.recon.dataset import GridDataset
        from fpscan.service.recon.warmup import warm_up as compile_kernels
        from fpscan.service.storage.results import write_result

        compile_kernels(dtypes=[DEFAULT_DTYPE], background=False)
        data = np.zeros((32, 4, 4), dtype=np.float32)
        data[5, 1:3, 1:3] = 1.0
        rec = reconstruct(GridDataset(data=data, dx=1e-4, dt=2e-8, sound_speed=C_DEFAULT, dy=1e-4), default_method("grid"))
        with tempfile.TemporaryDirectory(prefix="fpscan-warm-") as tmp:
            write_result(os.path.join(tmp, "result"), rec, input_id="warm-up")
        threading.Thread(target=release_when_quiet, args=(JOB_GATE,), name="work-arrays-release", daemon=True).start()
        if rest_in_background:
            threading.Thread(target=_warm_rest, name="warm-up-rest", daemon=True).start()
        else:
            for methods, dtypes in _later_steps():
                compile_kernels(dtypes=dtypes, methods=methods)
        warm_heap()  # last: no warm-up step takes its pages (the background one runs in its own arena)
    return {"pid": os.getpid(), "seconds": time.perf_counter() - t0}


#: glibc's threshold above which an allocation gets pages of its own (mmap), set by
#: :func:`warm_heap`: the value glibc's dynamic rule reaches anyway after a process frees its
#: first mapping of that size (its maximum on 64-bit systems, ``DEFAULT_MMAP_THRESHOLD_MAX``)
HEAP_MMAP_THRESHOLD = 32 << 20
#: bytes of heap :func:`warm_heap` grows, writes and keeps; the heap's free top is kept up to
#: twice that (``M_TRIM_THRESHOLD``)
HEAP_WARM_BYTES = 64 << 20


def warm_heap() -> bool:
    """Give the worker's heap pages it has already written, so that a first job's arrays reuse
    them instead of faulting in fresh ones (the first job after start-up).

    A fresh process's C library (glibc) maps every allocation above 128 KiB to new pages,
    which the kernel hands out zeroed, one fault per page, on their first write; it raises that
    threshold only after the process frees a mapping (to its size, at most 32 MiB) and then
    serves smaller arrays from the heap, whose written pages it keeps for reuse. A
    reconstruction's first call paid those faults on every work array (NER float32 of
    256 × 128² after the worker's warm-up, fresh interpreters, median of 8: 0.157 s, against
    0.124 s after this and 0.06-0.09 s for later calls; docs/history/measurements.md,
    "a warmed heap for the first job"). Here the
    thresholds are set to what glibc's own rule reaches after such a free (``mallopt``: mmap
    threshold `HEAP_MMAP_THRESHOLD`, trim threshold twice `HEAP_WARM_BYTES`) and
    `HEAP_WARM_BYTES` of heap are allocated in blocks below the threshold, written, and freed:
    they stay in the process as the heap's free top. Arrays above the threshold are mapped as
    before. Costs the worker `HEAP_WARM_BYTES` of resident memory.

    Returns
    -------
    bool
        True when the thresholds were set (glibc); False where the C library has no
        ``mallopt`` (musl's is a stub, macOS has none): nothing is changed there.

    References
    ----------
    .. [1] mallopt(3), the GNU C Library (``M_MMAP_THRESHOLD``, ``M_TRIM_THRESHOLD``).
    """
    import ctypes

    import numpy as np

    m_trim_threshold, m_mmap_threshold = -1, -3  # malloc.h
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError, TypeError):  # no C library to ask, or one without mallopt
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    if not (mallopt(m_mmap_threshold, HEAP_MMAP_THRESHOLD) and mallopt(m_trim_threshold, 2 * HEAP_WARM_BYTES)):
        return False
    block = HEAP_MMAP_THRESHOLD // 2
    blocks = [np.ones(block // 8) for _ in range(HEAP_WARM_BYTES // block)]  # written: the pages are faulted in
    del blocks  # freed into the heap's top, below the trim threshold: kept
    return True


def _later_steps() -> list[tuple[list[str], list[str]]]:
    """The warm-up steps that come after a worker's first job can start, in order, as
    ``(methods, dtypes)``: the quick methods in the precisions other than the default
    (``DEFAULT_DTYPE`` is warmed first: what a job gets unless it asks otherwise), then each
    method that warms in the background (``Method.warm_in_background``) in each precision."""
    from fpscan.service.recon.methods import METHODS
    from fpscan.service.recon.warmup import DTYPES

    quick = [m.name for m in METHODS.values() if m.warm_up is not None and not m.warm_in_background]
    steps = [([name], [dtype]) for dtype in DTYPES if dtype != DEFAULT_DTYPE for name in quick]
    return steps + [([m.name], [dtype]) for m in METHODS.values() if m.warm_in_background and m.warm_up is not None
                    for dtype in DTYPES]


def _warm_rest() -> None:
    """The warm-ups :func:`warm_up` leaves to the background (:func:`_later_steps`), one method
    and precision at a time, each step only while no job runs (:data:`JOB_GATE`); a
    failure is logged (a job then compiles what it needs itself)."""
    try:
        from fpscan.service.recon.warmup import warm_up as compile_kernels

        started = time.monotonic()
        for methods, dtypes in _later_steps():  # small steps, each once the worker has had no job for a
            # while: the warm-up must not take CPU (and the GIL) from a job, nor start a step just as one
            # arrives (the first job after start-up usually comes at once)
            JOB_GATE.wait_quiet(WARM_QUIET_S, since=started)
            compile_kernels(dtypes=dtypes, methods=methods)
    except Exception:  # a warm-up must never stop the worker
        import logging

        logging.getLogger("fpscan.worker").exception("worker warm-up (its background steps) failed")
