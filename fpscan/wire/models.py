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

from fpscan.wire.brief import fields_repr, html_table, one_line

__all__ = ["Plan", "PlanPreview", "JobProgress", "Attempt", "Timings", "Job", "Scanner", "PreviewInfo", "DiskUse",
           "ComputeDevice", "Health", "MethodOption", "MethodInfo", "DatasetFormatInfo", "FormatInfo", "Dataset",
           "DatasetInfo"]

class _Wire(BaseModel):
    """The base of the wire models: a one-line repr of the fields that hold a value, each
    in a few characters (``fpscan.wire.brief.fields_repr``: lists and dicts by their sizes)."""

    def __repr__(self) -> str:
        try:
            return self._brief()
        except Exception:  # an answer kept unvalidated (a field missing or of another type): its fields
            return fields_repr(type(self).__name__, self)

    def _brief(self) -> str:
        """The one line of this model (subclasses name their key fields)."""
        return fields_repr(type(self).__name__, self)


_SCAN_TIME = "points × averages × wavelengths / PRF, s; null when the plan sets no PRF (unthrottled)"


class Plan(_Wire):
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

    def _where(self) -> str:
        lat = self.lattice
        try:
            return f" on {lat['n_x']}x{lat.get('n_y', 1)} at {float(lat['pitch']) * 1e6:.4g} µm"
        except (KeyError, TypeError, ValueError):
            return ""

    def _brief(self) -> str:
        """One line: the id's start, the mask kind, points (of those asked) and the lattice.

        Examples
        --------
        >>> from fpscan.wire.models import Plan
        >>> Plan(id="d1f13f63ebef4fa6", kind="full", n_points=9, requested_points=9,
        ...      lattice={"n_x": 3, "n_y": 3, "pitch": 1e-4})
        Plan(d1f13f63ebef: full, 9 of 9 points on 3x3 at 100 µm)
        """
        asked = f" of {self.requested_points}" if self.requested_points is not None else ""
        time = f", scan {self.expected_scan_time_s:.3g} s" if self.expected_scan_time_s is not None else ""
        return one_line(f"{type(self).__name__}({self.id[:12]}: {self.kind}, {self.n_points}{asked} points"
                        f"{self._where()}{time})")

    def _repr_html_(self) -> str:
        acq = self.acquisition
        return html_table(f"{type(self).__name__} {self.id}", [
            ("kind", self.kind), ("points", self.n_points), ("requested", self.requested_points),
            ("lattice", self._where().removeprefix(" on ") or None), ("weight ratio", self.weight_ratio),
            ("n_t", acq.get("n_t")), ("dt (s)", acq.get("dt")), ("expected scan time (s)", self.expected_scan_time_s),
            ("shortfall", self.shortfall)])


class PlanPreview(_Wire):
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


class JobProgress(_Wire):
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


class Attempt(_Wire):
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


class Timings(_Wire):
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


class Job(_Wire):
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

    def _brief(self) -> str:
        """One line: the id, kind, state, progress (share and stage) and the error's start.

        Examples
        --------
        >>> from fpscan.wire.models import Job
        >>> Job(id="j1", kind="recon", state="running", progress={"fraction": 0.5, "stage": "reconstructing"})
        Job(j1: recon running, 50% reconstructing)
        """
        pr = self.progress
        error = f", error {self.error[:80]!r}" if self.error else ""
        tries = f", attempt {self.attempts}" if self.attempts > 1 else ""
        return one_line(f"{type(self).__name__}({self.id}: {self.kind} {self.state}, {pr.fraction:.0%} {pr.stage}"
                        f"{tries}{error})")

    def _repr_html_(self) -> str:
        pr, t = self.progress, self.timings
        method = self.params.get("method") if isinstance(self.params, dict) else None
        return html_table(f"{type(self).__name__} {self.id}", [
            ("kind", self.kind), ("state", self.state), ("progress", f"{pr.fraction:.0%} {pr.stage}"),
            ("method", method), ("eta (s)", pr.eta_s), ("queued (s)", t.queued_s), ("run (s)", t.run_s),
            ("attempts", self.attempts or None), ("error", self.error)])


class Scanner(_Wire):
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


class PreviewInfo(_Wire):
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


# -- the server itself ---------------------------------------------------------------
class DiskUse(_Wire):
    """Bytes the data folder uses, by part, and the free space of its file system.

    Attributes
    ----------
    total_bytes : int
        The sum of the parts.
    scans_bytes, results_bytes, datasets_bytes, exports_bytes : int
        Scan files, reconstruction results, uploaded datasets, exports.
    other_bytes : int
        The job database, plans and anything else.
    free_bytes : int or None
        Free bytes of the data folder's file system; None when unknown.
    """

    total_bytes: int
    scans_bytes: int
    results_bytes: int
    datasets_bytes: int
    exports_bytes: int
    other_bytes: int = Field(description="the job database, plans and anything else")
    free_bytes: int | None = None


class ComputeDevice(_Wire):
    """A device reconstructions can run on (the ``devices`` of :class:`Health`).

    Attributes
    ----------
    kind : str
        ``cpu`` or ``cuda``.
    name : str
        The GPU's name, or ``"cpu"``.
    cores : int or None
        The CPU's cores (None for a GPU).
    memory_total : int or None
        A GPU's memory, bytes (None for the CPU).
    """

    kind: str
    name: str
    cores: int | None = None
    memory_total: int | None = None


class Health(_Wire):
    """The server is alive, what it runs and what keeps jobs from running.

    Attributes
    ----------
    status : str
        ``"ok"``.
    version : str
        The server's version.
    executor : str
        Where reconstructions run (``"local"`` or ``"dask"``).
    jobs_running : int
        Reconstruction jobs running now (default 0).
    disk : DiskUse or None
        Bytes the data folder uses by part, and its free space.
    problems : list of str
        What keeps jobs from running now, one line each.
    devices : sequence of ComputeDevice
        What reconstructions can run on: the CPU, then each CUDA GPU.
    """

    status: str = "ok"
    version: str
    executor: str
    jobs_running: int = 0
    disk: DiskUse | None = None
    problems: list[str] = Field(default_factory=list, description="what keeps jobs from running now "
                                "(e.g. a scan paused by a full disk or a lost device), one line each")
    #: a Sequence, so that each side narrows it to a list of its own ComputeDevice
    devices: Sequence[ComputeDevice] = Field(default_factory=list, description="what reconstructions can run on: "
                                             "the CPU, then each CUDA GPU found at the server's start")


# -- reconstruction methods and file formats -----------------------------------------
class MethodOption(_Wire):
    """One option of a reconstruction method, or a file format's load option.

    Attributes
    ----------
    name : str
        The option's name in the reconstruction options (``sound_speed``: the speed of sound).
    description : str
        What it is, for a person.
    default : any
        The method's default (None: derived from the data).
    value_schema : dict
        JSON schema of a value: ``type``, ``minimum``/``maximum``/``exclusiveMinimum`` or ``enum``,
        ``unit`` (SI), ``quantity``.
    """

    name: str = Field(description="the option's name in the request's params (sound_speed: the speed of sound)")
    description: str
    default: Any = Field(None, description="this method's default (null: derived from the data, e.g. n_z = n_t)")
    value_schema: dict[str, Any] = Field(default_factory=dict, description="JSON schema of a value: type, "
                                         "minimum/maximum/exclusiveMinimum or enum, and unit (SI), quantity "
                                         "(length/time: text with a unit accepted); forms are built from it")


class MethodInfo(_Wire):
    """One reconstruction method.

    Attributes
    ----------
    name : str
        The method's name (a reconstruction request's ``method``).
    title : str
        What a person reads.
    needs_grid : bool
        Needs data on a full regular grid (every lattice point).
    options : sequence of MethodOption
        The options it takes.
    source : str
        Where the algorithm comes from.
    iterative : bool
        An iterative solver (default False).
    time_limited : bool
        Takes ``time_limit`` (s) (default False).
    cancellable : bool
        A cancel ends it within a step (default True).
    default_for : list of str
        The inputs it is the default method for: ``grid``, ``points``.
    summary : list of dict
        The fields of its result it shows after its outcome.
    """

    name: str
    title: str
    needs_grid: bool = Field(description="needs data on a full regular grid (every lattice point)")
    #: a Sequence, so that each side narrows it to a list of its own MethodOption
    options: Sequence[MethodOption]
    source: str
    iterative: bool = Field(False, description="an iterative solver: sound_speed 'auto' searches with the input's "
                                               "default direct method, then runs it once")
    time_limited: bool = Field(False, description="takes time_limit (s), capped by the server's time_limit_s")
    cancellable: bool = Field(True, description="reports progress between steps; a cancel ends it within a step")
    default_for: list[str] = Field(default_factory=list, description="the inputs it is the default method for: "
                                                                     "'grid' (a full lattice), 'points' (any mask)")
    summary: list[dict[str, Any]] = Field(
        default_factory=list, description="the fields of its result's params_used it shows after its outcome, in order "
        "(fpscan.service.progress.Shown: key, label, title, id, format, flag, words, note, suffix, also): the web page's "
        "summary rows")


class DatasetFormatInfo(_Wire):
    """One format a dataset upload accepts.

    Attributes
    ----------
    name : str
        The value of the upload's ``format`` field.
    title : str
        What a person reads.
    wavelengths : bool
        May hold several excitation wavelengths.
    """

    name: str = Field(description="the value of the upload's format field")
    title: str = Field(description="what a person reads")
    wavelengths: bool = Field(description="may hold several excitation wavelengths (the upload's wavelength "
                                          "chooses one)")


class FormatInfo(_Wire):
    """One file format of the server's registry: what it reads and what it exports.

    Attributes
    ----------
    name : str
        The format's name (an upload's ``format``, an export's name).
    title : str
        What a person reads.
    noun : str
        The format in a sentence (``"a scan file"``).
    input, upload, wavelengths : bool
        A reconstruction input; accepted by an upload; may hold several wavelengths.
    export_from : str or None
        The format whose files it exports; None: no export.
    suffix : str
        The ending of an export's file name.
    media_type : str
        An export's ``Content-Type``.
    folder : bool
        An export that is a folder (served zipped).
    options : sequence of MethodOption
        Its load options (an upload's fields).
    """

    name: str = Field(description="the format's name (an upload's format field, --format, an export's name)")
    title: str = Field(description="what a person reads")
    noun: str = Field(description="the format in a sentence ('a scan file')")
    input: bool = Field(description="a reconstruction input")
    upload: bool = Field(description="accepted by POST /api/datasets")
    wavelengths: bool = Field(description="may hold several excitation wavelengths")
    export_from: str | None = Field(description="the format whose files it exports (a scan job's: fpscan; a "
                                                "reconstruction's: result); null: no export")
    suffix: str = Field(description="the ending of an export's file name")
    media_type: str = Field(description="an export's Content-Type (a folder export is served as application/zip)")
    folder: bool = Field(description="an export that is a folder (OME-Zarr), served zipped")
    #: a Sequence, so that each side narrows it to a list of its own MethodOption
    options: Sequence[MethodOption] = Field(default_factory=list, description="its load options (an upload's fields)")


# -- datasets ------------------------------------------------------------------------
class Dataset(_Wire):
    """An uploaded dataset as the upload stored it.

    Attributes
    ----------
    dataset_id : str
        Its id.
    format : str
        The format it was read as.
    layout : str
        ``grid``, ``points`` or ``scan``.
    shape : list of int
        The stored data's shape.
    dt : float or None
        Sample interval, s.
    wavelength_nm : float or None
        The excitation wavelength whose data it holds, nm.
    deduplicated : bool
        The same file with the same import options was stored before (default False).
    content_sha256 : str or None
        SHA-256 of the uploaded file's bytes.
    """

    dataset_id: str
    format: str
    layout: str
    shape: list[int]
    dt: float | None = None
    wavelength_nm: float | None = Field(None, description="the excitation wavelength whose data the dataset holds "
                                                          "(a scan or IPASC file that records it)")
    deduplicated: bool = Field(False, description="the same file with the same import options was stored before: "
                                                  "this is that dataset, nothing new was stored")
    content_sha256: str | None = Field(None, description="SHA-256 of the uploaded file's bytes")


class DatasetInfo(_Wire):
    """A stored dataset as the list of datasets shows it.

    Attributes
    ----------
    dataset_id : str
        Its id.
    name : str or None
        The uploaded file's name (display only).
    format, layout : str or None
        As in :class:`Dataset`.
    shape : list of int or None
        As in :class:`Dataset`.
    dt, wavelength_nm : float or None
        As in :class:`Dataset` (s, nm).
    wavelength_index : int or None
        The index of its wavelength among the uploaded file's.
    content_sha256 : str or None
        As in :class:`Dataset`.
    size_bytes : int
        Bytes of its files on disk.
    created : float
        UNIX time of the upload, s.
    last_used : float or None
        UNIX time of the upload or of the latest identical upload answered with it, s.
    jobs : list of str
        Ids of the reconstruction jobs that read it.
    in_use : bool
        A queued, running or paused job reads it (it cannot be deleted).
    """

    dataset_id: str
    name: str | None = Field(None, description="the uploaded file's name (display only)")
    format: str | None = None
    layout: str | None = None
    shape: list[int] | None = None
    dt: float | None = None
    wavelength_nm: float | None = None
    wavelength_index: int | None = None
    content_sha256: str | None = None
    size_bytes: int = Field(description="bytes of its files on disk")
    created: float = Field(description="UNIX time of the upload")
    last_used: float | None = Field(None, description="UNIX time of the upload or of the latest identical upload "
                                                      "answered with it (retention by age counts from it)")
    jobs: list[str] = Field(default_factory=list, description="ids of the reconstruction jobs that read it")
    in_use: bool = Field(False, description="a queued, running or paused job reads it (it cannot be deleted)")
