"""The client's own view of the API responses it parses (pydantic; no server imports).

They subclass the response models of ``docs/api.md`` as ``fpscan.wire.models`` defines their
fields once (the server's ``fpscan.service.api.models`` narrow the same ones) and stay lenient,
so a client keeps working against a slightly newer or older server: unknown fields are
kept (``extra="allow"``), states and kinds are plain strings, and fields a server may omit
have defaults. A response that does not fit is returned as the raw JSON (see
:func:`fpscan.clients.http.calls.as_model`). Units are SI (m, s, Hz).
"""
from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from fpscan.wire import models as wire

__all__ = ["Plan", "PlanPreview", "JobProgress", "Attempt", "Timings", "Job", "Scanner", "PreviewInfo", "MODELS"]


#: unknown fields are kept (a newer server's)
_LENIENT = ConfigDict(extra="allow")


class Plan(wire.Plan):
    """Summary of a stored plan (``GET /api/plans/{id}``).

    Attributes
    ----------
    id : str
        The plan's content hash.
    kind : str
        Mask kind.
    n_points : int
        Points in the plan.
    requested_points : int or None
        Points asked for.
    shortfall : str or None
        Why the plan has fewer points than asked.
    weight_ratio : float or None
        Outer/inner weight ratio.
    expected_scan_time_s : float or None
        s; None when the PRF is 0 (unthrottled).
    lattice : dict
        ``n_x``, ``n_y``, ``pitch`` (m).
    acquisition : dict
        ``n_t``, ``dt`` (s), ``averages``, ``wavelengths`` (m), ``prf`` (Hz), ``sound_speed`` (m/s).
    links : dict of str to str
        Related URLs (plan JSON, preview).

    Examples
    --------
    >>> from fpscan.clients.http.models import Plan
    >>> plan = Plan.model_validate({"id": "abc", "kind": "full", "n_points": 9, "order": "serpentine"})
    >>> plan.n_points, plan.weight_ratio, plan.order  # a field this client does not know is kept
    (9, None, 'serpentine')
    """

    model_config = _LENIENT


class PlanPreview(wire.PlanPreview):
    """A mask preview computed without storing a plan (``POST /api/plans/preview``).

    Attributes
    ----------
    points : int
        Points the mask holds.
    weight_ratio : float or None
        Outer/inner weight ratio.
    expected_scan_time_s : float or None
        s.
    preview_png_base64 : str or None
        The preview picture, PNG in base64.

    Examples
    --------
    >>> from fpscan.clients.http.models import PlanPreview
    >>> PlanPreview.model_validate({"points": 53, "weight_ratio": 2.83})
    PlanPreview(points=53, weight_ratio=2.83, expected_scan_time_s=None, preview_png_base64=None)
    """

    model_config = _LENIENT


class JobProgress(wire.JobProgress):
    """A job's progress (the ``progress`` of a :class:`Job`).

    Attributes
    ----------
    fraction : float
        In [0, 1].
    stage : str
        What the job is doing (``queued``; a scan: ``connecting``, ``acquiring``, ``paused``,
        ``interrupted``, ``done``; ...).
    points_done, points_total : int or None
        Scan points measured / planned.
    alines_done, alines_total : int or None
        A-lines recorded / planned.
    rate_per_s : float or None
        A-lines landed per second, 1/s.
    eta_s : float or None
        Estimated time to completion, s.
    faults_recovered : int or None
        Device faults the scan recovered from.
    reason : str or None
        Why a job is paused with stage ``interrupted`` (lost device, full disk); cleared when
        it resumes.

    Examples
    --------
    >>> from fpscan.clients.http.models import JobProgress
    >>> p = JobProgress.model_validate({"fraction": 0.5, "stage": "acquiring", "points_done": 800, "eta_s": 16.0})
    >>> p.fraction, p.stage, p.points_total
    (0.5, 'acquiring', None)
    >>> JobProgress().stage  # a job nobody has started
    'queued'
    """

    model_config = _LENIENT


class Attempt(wire.Attempt):
    """An attempt of a job that was cut off and re-queued (a dead worker, a shutdown, a restart).

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

    Examples
    --------
    >>> from fpscan.clients.http.models import Attempt
    >>> a = Attempt.model_validate({"attempt": 1, "started": 100.0, "ended": 102.5, "run_s": 2.5,
    ...                             "reason": "the worker process died"})
    >>> a.run_s, a.reason
    (2.5, 'the worker process died')
    """

    model_config = _LENIENT


class Timings(wire.Timings):
    """UNIX times of a job's creation, start and end (s), and its queue/run durations (s):
    those of its current attempt (a job re-queued after its run was cut off starts them anew).

    Attributes
    ----------
    created, started, finished : float or None
        UNIX times, s.
    queued_s, run_s : float or None
        Durations, s.
    earlier_attempts : list of Attempt
        The attempts cut off before the current one, oldest first.

    Examples
    --------
    >>> from fpscan.clients.http.models import Timings
    >>> t = Timings.model_validate({"created": 100.0, "started": 101.5, "queued_s": 1.5})
    >>> t.queued_s, t.finished
    (1.5, None)
    """

    model_config = _LENIENT

    earlier_attempts: list[Attempt] = Field(default_factory=list)


class Job(wire.Job):
    """A job (``GET /api/jobs/{id}``).

    Attributes
    ----------
    id : str
    kind : str
        ``scan``, ``reconstruction``, ``unmix``, ...
    state : str
        ``queued``, ``running``, ``paused``, ``succeeded``, ``failed`` or ``cancelled``.
    progress : JobProgress
    timings : Timings
    params : dict
        The job's parameters (SI units).
    links : dict of str to str
        Result URLs.
    attempts : int
        Times the job was started (a job whose worker died is requeued and started again).
    error : str or None
        Why it failed.

    Examples
    --------
    >>> from fpscan.clients.http.models import Job
    >>> job = Job.model_validate({"id": "j1", "kind": "scan", "state": "running",
    ...                           "progress": {"fraction": 0.25, "stage": "acquiring"}})
    >>> job.state, job.progress.fraction, job.error
    ('running', 0.25, None)
    """

    model_config = _LENIENT

    progress: JobProgress = Field(default_factory=JobProgress)
    timings: Timings = Field(default_factory=Timings)


class Scanner(wire.Scanner):
    """A configured scanner (``GET /api/scanners``).

    Attributes
    ----------
    id : str
    port : str or None
        Serial port.
    status : str
        ``idle``, ``busy``, ``unreachable`` or ``unknown``.
    job_id : str or None
        The scan job it runs.
    identity : str or None
        What the device reported about itself.

    Examples
    --------
    >>> from fpscan.clients.http.models import Scanner
    >>> Scanner.model_validate({"id": "sim", "status": "idle"})
    Scanner(id='sim', port=None, status='idle', job_id=None, identity=None)
    """

    model_config = _LENIENT


class PreviewInfo(wire.PreviewInfo):
    """The live preview's state during a scan.

    Attributes
    ----------
    version : int
        Increases with every refresh.
    points_used : int
        Scan points in the current preview.
    wavelength_index : int or None
        The wavelength it shows (index into the plan's wavelengths).
    updated : float or None
        UNIX time of the last refresh, s.
    refresh_s : float or None
        Refresh interval, s.

    Examples
    --------
    >>> from fpscan.clients.http.models import PreviewInfo
    >>> info = PreviewInfo.model_validate({"version": 3, "points_used": 120, "updated": 1700000000.0})
    >>> info.version, info.points_used, info.wavelength_index
    (3, 120, None)
    """

    model_config = _LENIENT


MODELS: dict[str, type[BaseModel]] = {
    m.__name__: m for m in (Plan, PlanPreview, JobProgress, Attempt, Timings, Job, Scanner, PreviewInfo)
}
