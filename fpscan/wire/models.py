"""The response models of the HTTP API, each field defined once (pydantic; imports nothing
of fpscan).

Lenient: states and kinds are plain strings and fields a server may omit have defaults.
The server's models (``fpscan.service.api.models``) subclass these and narrow what it guarantees,
so that its OpenAPI schema is theirs; the client's (``fpscan.clients.http.models``) subclass them
keeping unknown fields (``extra="allow"``). A field's description is the one the OpenAPI
schema shows. Units are SI (m, s, Hz, bytes); times are UNIX times in s.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from pydantic import BaseModel, Field

__all__ = ["Plan", "PlanPreview", "JobProgress", "Attempt", "Timings", "Job", "Scanner", "PreviewInfo"]

_SCAN_TIME = "points × averages × wavelengths / PRF, s; null when the plan sets no PRF (unthrottled)"


class Plan(BaseModel):
    """A stored plan's summary.

    Attributes
    ----------
    id : str
        The plan's id (its content hash).
    kind : str
        Its mask kind.
    n_points : int
        Points in the plan.
    requested_points : int or None
        Points the mask asked for.
    shortfall : str or None
        Why the plan has fewer points than asked, one line.
    weight_ratio : float or None
        The mask's outer/inner weight ratio.
    expected_scan_time_s : float or None
        Points × averages × wavelengths / PRF, s; None when the plan sets no PRF.
    lattice : dict
        ``n_x``, ``n_y``, ``pitch`` (m).
    acquisition : dict
        ``n_t``, ``dt`` (s), ``prf`` (Hz), ...
    links : dict of str to str
        Name -> API path.
    """

    id: str
    kind: str
    n_points: int
    requested_points: int | None = None
    shortfall: str | None = Field(None, description="why the plan has fewer points than asked (under 90 %), "
                                  "one line; null when it has about as many")
    weight_ratio: float | None = None
    expected_scan_time_s: float | None = Field(None, description=_SCAN_TIME)
    lattice: dict[str, Any] = Field(default_factory=dict)
    acquisition: dict[str, Any] = Field(default_factory=dict)
    links: dict[str, str] = Field(default_factory=dict)


class PlanPreview(BaseModel):
    """A plan built and drawn, not stored.

    Attributes
    ----------
    points : int
        Points in the plan.
    weight_ratio : float or None
        The mask's outer/inner weight ratio.
    expected_scan_time_s : float or None
        Points × averages × wavelengths / PRF, s; None when the plan sets no PRF.
    preview_png_base64 : str or None
        The mask preview PNG, base64-encoded.
    """

    points: int
    weight_ratio: float | None = None
    expected_scan_time_s: float | None = Field(None, description=_SCAN_TIME)
    preview_png_base64: str | None = None


class JobProgress(BaseModel):
    """A job's progress (the ``progress`` of a :class:`Job`).

    Attributes
    ----------
    fraction : float
        Share of the job done, in [0, 1].
    stage : str
        What the job is doing.
    points_done, points_total : int or None
        Scan points measured / planned.
    alines_done, alines_total : int or None
        A-lines on disk / planned.
    rate_per_s : float or None
        A-lines landed per second, 1/s.
    eta_s : float or None
        Estimated time to completion, s.
    faults_recovered : int or None
        Link faults a scan recovered from.
    reason : str or None
        Why a job is paused with stage ``interrupted``.
    """

    fraction: float = Field(0.0, description="share of the job done, in [0, 1]")
    stage: str = Field("queued", description="what the job is doing: queued; a scan: connecting, acquiring, "
                       "paused, interrupted, done; a reconstruction: its method's stages")
    points_done: int | None = Field(None, description="scan: points measured at every wavelength; "
                                    "a finished reconstruction: the sensor points it used")
    points_total: int | None = Field(None, description="scan: points in the plan")
    alines_done: int | None = Field(None, description="scan: A-lines on disk (points x wavelengths)")
    alines_total: int | None = Field(None, description="scan: A-lines planned (points x wavelengths)")
    rate_per_s: float | None = Field(None, description="scan: A-lines landed per second, 1/s")
    eta_s: float | None = Field(None, description="estimated time to completion, s")
    faults_recovered: int | None = Field(None, description="scan: link faults recovered so far (bad frames, "
                                         "NAKs, timeouts, resets)")
    reason: str | None = Field(None, description="why a job is paused with stage interrupted (lost device, "
                               "full disk), one line; cleared when it resumes")


class Attempt(BaseModel):
    """An attempt of a job that was cut off and re-queued.

    Attributes
    ----------
    attempt : int or None
        Its number (1 for the first run).
    started, ended : float or None
        UNIX times it started and was cut off, s.
    run_s : float or None
        Seconds it ran.
    reason : str or None
        Why it was cut off, one line.
    """

    attempt: int | None = None
    started: float | None = None
    ended: float | None = None
    run_s: float | None = None
    reason: str | None = None


class Timings(BaseModel):
    """When a job was created, started and finished (UNIX times, s) and how long it waited and ran.

    Attributes
    ----------
    created, started, finished : float or None
        UNIX times, s.
    queued_s, run_s : float or None
        Durations, s.
    earlier_attempts : sequence of Attempt
        The attempts cut off before the current one, oldest first.
    """

    created: float | None = None
    started: float | None = None
    finished: float | None = None
    queued_s: float | None = None
    run_s: float | None = None
    #: a Sequence, so that each side narrows it to a list of its own Attempt
    earlier_attempts: Sequence[Attempt] = Field(default_factory=list)


class Job(BaseModel):
    """A scan or reconstruction job.

    Attributes
    ----------
    id : str
        The job's id.
    kind : str
        What it does.
    state : str
        Where it is (``queued``, ``running``, ``paused``, ``succeeded``, ``failed``, ``cancelled``).
    progress : JobProgress
        Its latest progress.
    timings : Timings
        When it was created, started and finished.
    params : dict
        What it was asked to do (SI units).
    links : dict of str to str
        Name -> API path of its resources.
    attempts : int
        Times it was started (default 0).
    error : str or None
        Why it failed, one line.
    """

    id: str
    kind: str
    state: str
    progress: JobProgress = Field(default_factory=JobProgress)
    timings: Timings = Field(default_factory=Timings)
    params: dict[str, Any] = Field(default_factory=dict)
    links: dict[str, str] = Field(default_factory=dict)
    attempts: int = 0
    error: str | None = None


class Scanner(BaseModel):
    """A scanner the server is configured with, and what it is doing.

    Attributes
    ----------
    id : str
        The scanner's id.
    port : str or None
        Its device (serial port) path.
    status : str
        ``idle``, ``busy``, ``unreachable`` or ``unknown`` (the default).
    job_id : str or None
        The scan job it runs.
    identity : str or None
        What the device said when it was last identified.
    """

    id: str
    port: str | None = None
    status: str = "unknown"
    job_id: str | None = None
    identity: str | None = None


class PreviewInfo(BaseModel):
    """A scan's live preview state.

    Attributes
    ----------
    version : int
        Grows with every refresh (0: none yet).
    points_used : int
        The completed points the preview reconstructed.
    wavelength_index : int or None
        The excitation wavelength shown (index into the plan's).
    updated : float or None
        UNIX time of the last refresh, s.
    refresh_s : float or None
        How long the last refresh took, s.
    """

    version: int
    points_used: int
    wavelength_index: int | None = Field(None, description="the excitation wavelength shown (index into the plan's)")
    updated: float | None = Field(None, description="UNIX time of the last refresh")
    refresh_s: float | None = Field(None, description="how long the last refresh took, s")
