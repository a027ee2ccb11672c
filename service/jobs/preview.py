"""Live preview of a running scan: a NEDNER reconstruction of the points acquired so far,
refreshed every few seconds, rendered as MIP PNGs with a version counter.

The reconstruction (``fpscan.service.pipeline.reconstruct`` with ``nedner``: temporal NUFFT +
type-1 NUFFT over the positions, paper §3.2) works on any subset of the sensor mask, so
the user watches the image form. Weights are the clipped Voronoi areas of the subset
(``voronoi_weights``, the default of ``reconstruct_points``), not the plan's weights for
the whole mask. The output grid is the plan's lattice, thinned for speed
(:func:`render_preview`).

:func:`render_preview` runs in a separate process (a one-worker ``spawn`` pool owned by
:class:`PreviewManager`): the scan file is read as an SWMR reader there, and the server's
event loop and serial threads never wait for it. The refreshes run on the jobs' one loop
(:class:`fpscan.service.jobs.dispatcher.Loop`), every ``interval`` seconds.
"""
from __future__ import annotations

import logging
import multiprocessing
import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field

import numpy as np

from fpscan.constants import C_DEFAULT
from fpscan.service.jobs.dispatcher import Loop

__all__ = [
    "PreviewState", "render_preview_png", "preview_grid", "render_preview", "warm_up", "PreviewManager",
    "PREVIEW_WORKER_NICE",
]

log = logging.getLogger("fpscan.preview")


@dataclass
class PreviewState:
    """One refresh of a scan's live preview.

    :meth:`png` draws a plane on first request (``fpscan.service.pictures.render``, the pictures a
    result has) and keeps it.

    Attributes
    ----------
    version : int
        1, 2, ... (0: none yet).
    points_used : int
        The completed points reconstructed.
    updated : float or None
        When the refresh finished, UNIX s.
    refresh_s : float or None
        Seconds the refresh took.
    mips : dict of str to ndarray
        ``{plane: 2-D array}``: ``"xy"`` ``(n_y, n_x)``, ``"xz"`` ``(n_z, n_x)``, ``"yz"``
        ``(n_z, n_y)`` (only ``"xz"`` for a line scan).
    axes : tuple
        Their coordinates ``(z, x, y)`` in m (``y`` None for a line scan).
    wavelength_index : int
        The excitation wavelength shown (an index into the plan's wavelengths).
    p0_unit : str
        The colour bar's unit, ``"Pa"`` or ``"a.u."``.
    planes : tuple of str
        The planes it has (property).
    """

    version: int = 0
    points_used: int = 0
    updated: float | None = None
    refresh_s: float | None = None
    mips: dict = field(default_factory=dict)
    axes: tuple = ()
    wavelength_index: int = 0
    p0_unit: str = "a.u."
    _pngs: dict = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    @property
    def planes(self) -> tuple:
        return tuple(self.mips)

    def png(self, plane: str) -> bytes:
        """The PNG of ``plane``, drawn on first request and kept.

        Parameters
        ----------
        plane : str
            ``"xy"``, ``"xz"`` or ``"yz"``.

        Returns
        -------
        bytes
            The PNG file's bytes.

        Raises
        ------
        KeyError
            When this preview has no such plane.
        """
        with self._lock:
            if plane not in self._pngs:
                self._pngs[plane] = render_preview_png(self.mips[plane], plane, self.axes, self.points_used,
                                                       p0_unit=self.p0_unit)
            return self._pngs[plane]


def render_preview_png(img: np.ndarray, plane: str, axes: tuple, points: int, *, p0_unit: str = "a.u.") -> bytes:
    """A live-preview MIP drawn like a result's MIP.

    ``fpscan.service.pictures.render``: mm axes, equal aspect, row 0 at the top (y down / depth
    down), colour bar; the title names the points used.

    Parameters
    ----------
    img : ndarray, shape (n_v, n_h)
        The MIP: ``(n_y, n_x)`` for ``"xy"``, ``(n_z, n_x)`` for ``"xz"``, ``(n_z, n_y)`` for
        ``"yz"``.
    plane : str
        ``"xy"``, ``"xz"`` or ``"yz"``.
    axes : tuple
        ``(z, x, y)`` coordinate vectors in m (``y`` None for a line scan).
    points : int
        The points the preview used (shown in the title).
    p0_unit : str, optional
        The colour bar's unit; default ``"a.u."``.

    Returns
    -------
    bytes
        The PNG file's bytes.

    Raises
    ------
    ValueError
        If ``img``'s shape does not match the axes (:func:`fpscan.service.pictures.render.render_png`).
    """
    from fpscan.service.pictures.render import render_png

    z, x, y = axes
    h, hlabel = (y, "y") if plane == "yz" else (x, "x")
    v, vlabel = (y, "y") if plane == "xy" else (z, "z")
    name = f"MIP {plane}" if y is not None else "p0 (x, z)"
    return render_png(img, h, v, hlabel=hlabel, vlabel=vlabel,
                      title=f"live preview, {points} points: {name}", colorbar_label=f"p0 ({p0_unit})")


def preview_grid(axis: np.ndarray, max_points: int) -> np.ndarray:
    """A coarser regular grid over the same span as the centred lattice axis ``axis``.

    Stride ``ceil(n / max_points)``, centred (docs/architecture.md convention).

    Parameters
    ----------
    axis : ndarray, shape (n,)
        A centred, evenly spaced lattice axis in m.
    max_points : int
        The most points the grid may have.

    Returns
    -------
    ndarray, shape (m,)
        The coarser axis in m, ``m = ceil(n / stride)``; ``axis`` itself when the stride is 1
        or ``n < 2``.
    """
    n = len(axis)
    step = max(1, -(-n // max_points))
    if step == 1 or n < 2:
        return axis
    from fpscan.physics.axes import centred_axis

    return centred_axis(-(-n // step), float(axis[1] - axis[0]) * step)


def render_preview(scan_path: str, *, wavelength_index: int = 0, eps: float = 1e-3, max_lateral: int = 128,
                   max_samples: int = 512) -> dict:
    """NEDNER reconstruction of the completed points of a scan file at one wavelength → its MIPs.

    A preview trades resolution for speed: the output grid is the plan's lattice thinned
    to at most ``max_lateral`` points per axis, and the A-lines are low-passed and
    decimated in time (means of ``k`` consecutive samples, ``dt·k``) to at most
    ``max_samples`` samples; float32, NUFFT tolerance ``eps``.

    Parameters
    ----------
    scan_path : str
        The scan file (read while it is written).
    wavelength_index : int, optional
        The excitation wavelength, an index into the plan's wavelengths; default 0 (the first).
    eps : float, optional
        The NUFFT tolerance; default 1e-3.
    max_lateral : int, optional
        The most output points per lateral axis; default 128.
    max_samples : int, optional
        The most time samples per A-line; default 512.

    Returns
    -------
    dict
        ``{"points_used": n, "mips": {plane: 2-D array}, "axes": (z, x, y), "seconds": s,
        "p0_unit": "Pa" | "a.u."}`` (MIPs by ``fpscan.service.metrics.mip``, coordinates in m,
        ``seconds`` the time taken; drawn by :func:`render_preview_png` when asked for).
        When fewer than 2 points are complete, ``mips`` is empty, ``axes`` is ``()`` and
        there is no ``p0_unit``.

    Raises
    ------
    FileNotFoundError
        If the scan file does not exist.
    ValueError
        If it is not a readable scan file (:func:`fpscan.service.storage.loader.load_scan`).
    """
    from dataclasses import replace

    from fpscan.service.metrics.projections import mip
    from fpscan.service.pipeline import default_method, reconstruct
    from fpscan.service.storage.loader import load_scan

    t0 = time.perf_counter()
    ds = load_scan(scan_path, allow_empty=True, wavelength_index=wavelength_index)
    n = int(ds.alines.shape[0])
    if n < 2:
        return {"points_used": n, "mips": {}, "axes": (), "seconds": time.perf_counter() - t0}
    alines = ds.alines.astype(np.float32)
    k = max(1, -(-alines.shape[1] // max_samples))
    if k > 1:
        n_keep = (alines.shape[1] // k) * k
        alines = alines[:, :n_keep].reshape(n, n_keep // k, k).mean(axis=2)
    grid = tuple(preview_grid(np.asarray(g), max_lateral) for g in ds.grid)
    preview = replace(ds, alines=alines, dt=ds.dt * k, grid=grid, weights=None, indices=None, lattice=None)
    rec = reconstruct(preview, default_method("points"), eps=eps, dtype="float32")
    y = getattr(rec, "y", None)
    planes = ("xy", "xz", "yz") if y is not None else ("xz",)
    mips = {plane: mip(rec.p0, plane) for plane in planes}
    axes = (np.asarray(rec.z), np.asarray(rec.x), None if y is None else np.asarray(y))
    return {"points_used": n, "mips": mips, "axes": axes, "seconds": time.perf_counter() - t0,
            "p0_unit": rec.p0_unit}


def warm_up() -> float:
    """Import the reconstruction in a fresh worker and compile (or load from numba's cache)
    the kernels of the preview's method (``default_method("points")``: NEDNER) in float32, with
    the method's own warm-up (``fpscan.service.recon.warmup.warm_up``; a tiny run alone stays on the
    numpy path of small transforms and compiled nothing), then run a tiny preview's dispatch.

    So the first live preview of a scan is not slowed by start-up (on a fresh install without
    ``fpscan warmup`` it was the kernels' compilation: 45 s of a 0.64 s scan).

    Returns
    -------
    float
        Seconds the warm-up took.
    """
    from fpscan.service.pipeline import default_method, reconstruct
    from fpscan.service.recon.dataset import GridDataset
    from fpscan.service.recon.warmup import warm_up as warm_kernels

    t0 = time.perf_counter()
    warm_kernels(["float32"], [default_method("points")])
    data = np.zeros((32, 4, 4), dtype=np.float32)
    data[5] = 1.0
    reconstruct(GridDataset(data=data, dx=1e-4, dt=2e-8, sound_speed=C_DEFAULT, dy=1e-4), default_method("points"), eps=1e-3,
                dtype="float32")
    return time.perf_counter() - t0


#: CPU priority (``nice`` increment) of the live-preview worker: below the server's threads and the
#: reconstruction workers (``Settings.worker_nice``, default 0), above the plan worker
#: (``fpscan.service.api.plans.PLAN_WORKER_NICE``).
PREVIEW_WORKER_NICE = 5


class PreviewManager:
    """Refreshes the previews of running scans, in one spawned worker process.

    A refresh runs every ``interval`` s for each tracked scan that has new points
    (:meth:`track`, :meth:`note_progress`, :meth:`untrack`); :meth:`get` gives a scan's
    latest :class:`PreviewState`. :meth:`start` starts the loop and, with ``warm``, the worker
    (warming it up; without, the worker starts at the first refresh); :meth:`stop` ends both.

    Parameters
    ----------
    interval : float
        Seconds between two refreshes.
    warm : bool, optional
        Start and warm the worker at :meth:`start` (:func:`warm_up`); default True
        (``Settings.warm_up``).

    Attributes
    ----------
    interval : float
        As given.
    warm : bool
        As given.
    """

    def __init__(self, interval: float, warm: bool = True):
        self.interval = float(interval)
        self.warm = bool(warm)
        self._pool: ProcessPoolExecutor | None = None
        self._states: dict[str, PreviewState] = {}
        self._active: dict[str, dict] = {}  # job_id -> {"path", "last_points"}
        self._lock = threading.Lock()
        self._loop = Loop("preview", self._refresh_all, period=self.interval, log=log)

    @staticmethod
    def _new_pool() -> ProcessPoolExecutor:
        from fpscan.service.jobs.executors import lower_priority

        return ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"), initializer=lower_priority,
                                   initargs=(PREVIEW_WORKER_NICE, os.getpid()))

    def start(self) -> None:
        self._pool = self._new_pool()  # its process starts with the first task
        if self.warm:
            self._pool.submit(warm_up)  # in the background; a refresh queues behind it
        self._loop.start()

    def stop(self) -> None:
        self._loop.stop(timeout=5)
        if self._pool is not None:
            from fpscan.service.jobs.executors import stop_pool

            stop_pool(self._pool)

    def track(self, job_id: str, scan_path: str, *, wavelength_index: int = 0) -> None:
        """Follow a scan file; the preview shows excitation wavelength ``wavelength_index``."""
        with self._lock:
            self._active[job_id] = {"path": scan_path, "last_points": -1, "points_done": None,
                                    "rendered_at": None, "wavelength_index": int(wavelength_index)}

    def note_progress(self, job_id: str, points_done: int) -> None:
        """The scan thread reports its count (A-lines landed), so refreshes happen only on
        new data."""
        with self._lock:
            if job_id in self._active:
                self._active[job_id]["points_done"] = int(points_done)

    def untrack(self, job_id: str, *, final_refresh: bool = True) -> None:
        with self._lock:
            entry = self._active.pop(job_id, None)
        if entry is not None and final_refresh:
            self._refresh(job_id, entry)

    def get(self, job_id: str) -> PreviewState | None:
        with self._lock:
            return self._states.get(job_id)

    def _refresh_all(self) -> None:
        """Refresh the previews of the scans that have new points (the loop's tick)."""
        with self._lock:
            items = list(self._active.items())
        for job_id, entry in items:
            if entry["points_done"] is not None and entry["points_done"] == entry["rendered_at"]:
                continue
            try:
                self._refresh(job_id, entry)
            except Exception:
                log.exception("preview refresh failed job=%s", job_id)

    def _refresh(self, job_id: str, entry: dict) -> None:
        if self._pool is None:
            self._pool = self._new_pool()
        progress = entry["points_done"]
        try:
            out = self._pool.submit(render_preview, entry["path"],
                                    wavelength_index=entry["wavelength_index"]).result(timeout=300)
        except FileNotFoundError:
            return
        except BrokenProcessPool:
            self._pool = self._new_pool()
            log.warning("preview worker died; restarted it")
            return
        except Exception as exc:
            log.warning("preview job=%s: %s", job_id, exc)
            return
        entry["rendered_at"] = progress
        if not out["mips"] or out["points_used"] == entry["last_points"]:
            return
        entry["last_points"] = out["points_used"]
        with self._lock:
            prev = self._states.get(job_id)
            self._states[job_id] = PreviewState(version=(prev.version if prev else 0) + 1,
                                                points_used=out["points_used"], updated=time.time(),
                                                refresh_s=out["seconds"], mips=out["mips"], axes=out["axes"],
                                                wavelength_index=entry["wavelength_index"],
                                                p0_unit=out.get("p0_unit", "a.u."))
        log.info("preview job=%s points=%d seconds=%.2f", job_id, out["points_used"], out["seconds"])
