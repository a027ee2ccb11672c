"""The client's own view of the API responses it parses (pydantic; no server imports).

They subclass the response models of ``docs/api.md`` as ``fpscan.wire.models`` defines their
fields once (the server's ``fpscan.service.api.models`` narrow the same ones) and stay lenient,
so a client keeps working against a slightly newer or older server: unknown fields are
kept (``extra="allow"``), states and kinds are plain strings, and fields a server may omit
have defaults. An answer that does not fit is kept unvalidated as the same model (see
:func:`fpscan.clients.http.calls.as_model`). Every model is an :class:`Answer`: its fields read
like a dict's too (``health["version"]``, ``fmt.get("suffix")``). Units are SI (m, s, Hz).

The answers the wire models do not cover yet (auth, retention, deletions, mask kinds) are
plain ``dict`` s typed by the ``TypedDict`` s :class:`AuthInfo`, :class:`Retention`,
:class:`Deleted` and :class:`MaskKindInfo` (their keys are the server's schemas', checked
against its OpenAPI document by the tests).
"""
from __future__ import annotations

from typing import Any, TypedDict

from pydantic import BaseModel, ConfigDict, Field

from fpscan.wire import models as wire

__all__ = ["Answer", "Plan", "PlanPreview", "JobProgress", "Attempt", "Timings", "Job", "Scanner", "PreviewInfo",
           "DiskUse", "ComputeDevice", "Health", "MethodOption", "MethodInfo", "DatasetFormatInfo", "FormatInfo",
           "Dataset", "DatasetInfo", "AuthInfo", "Retention", "Deleted", "MaskKindInfo", "MODELS", "DICTS"]


class Answer(BaseModel):
    """What every response model of the client is: lenient (unknown fields kept,
    ``extra="allow"``) and readable like the ``dict`` of its JSON, so that code written for
    plain-dict answers keeps working (``answer["field"]``, ``answer.get("field", default)``,
    ``"field" in answer``, ``dict(answer)``). Values read so are the model's: a nested
    model stays a model (:func:`fpscan.clients.http.to_dict` gives plain JSON data).

    Attributes
    ----------
    model_extra : dict or None
        The fields a newer server sent that this client does not know (pydantic's).

    Examples
    --------
    >>> from fpscan.clients.http.models import Health
    >>> h = Health.model_validate({"status": "ok", "version": "1.2", "executor": "local", "uptime_s": 3.5})
    >>> h["version"], h.get("uptime_s"), h.get("nothing", "-"), "executor" in h
    ('1.2', 3.5, '-', True)
    >>> h["nothing"]
    Traceback (most recent call last):
    ...
    KeyError: 'nothing'
    >>> sorted(dict(h))[:3]
    ['devices', 'disk', 'executor']
    """

    model_config = ConfigDict(extra="allow")

    def keys(self) -> list[str]:
        """The names of the fields that hold a value (known, then unknown ones).

        Returns
        -------
        list of str

        Examples
        --------
        >>> from fpscan.clients.http.models import DatasetFormatInfo
        >>> DatasetFormatInfo(name="npy", title="NumPy array", wavelengths=False).keys()
        ['name', 'title', 'wavelengths']
        """
        return [name for name, _ in self]

    def __getitem__(self, key: str) -> Any:
        for name, value in self:
            if name == key:
                return value
        raise KeyError(key)

    def __contains__(self, key: object) -> bool:
        return key in self.keys()

    def get(self, key: str, default: Any = None) -> Any:
        """A field's value, or ``default`` when the answer has no such field.

        Parameters
        ----------
        key : str
            The field's name (as in the JSON).
        default : any, optional
            Returned for a missing field (default None).

        Returns
        -------
        any

        Examples
        --------
        >>> from fpscan.clients.http.models import Job
        >>> job = Job(id="j1", kind="scan", state="queued")
        >>> job.get("state"), job.get("colour", "none")
        ('queued', 'none')
        """
        try:
            return self[key]
        except KeyError:
            return default


class Plan(Answer, wire.Plan):
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


class PlanPreview(Answer, wire.PlanPreview):
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
    PlanPreview(points=53, weight_ratio=2.83)
    """


class JobProgress(Answer, wire.JobProgress):
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


class Attempt(Answer, wire.Attempt):
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


class Timings(Answer, wire.Timings):
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

    earlier_attempts: list[Attempt] = Field(default_factory=list)


class Job(Answer, wire.Job):
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

    progress: JobProgress = Field(default_factory=JobProgress)
    timings: Timings = Field(default_factory=Timings)


class Scanner(Answer, wire.Scanner):
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
    Scanner(id='sim', status='idle')
    """


class PreviewInfo(Answer, wire.PreviewInfo):
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


# -- the server itself ---------------------------------------------------------------
class DiskUse(Answer, wire.DiskUse):
    """Bytes the server's data folder uses, by part, and its free space (the ``disk`` of
    :class:`Health`).

    Attributes
    ----------
    total_bytes : int
        The sum of the parts.
    scans_bytes, results_bytes, datasets_bytes, exports_bytes, other_bytes : int
        Scan files, reconstruction results, uploaded datasets, exports, the rest.
    free_bytes : int or None
        Free bytes of its file system; None when unknown.

    Examples
    --------
    >>> from fpscan.clients.http.models import DiskUse
    >>> d = DiskUse.model_validate({"total_bytes": 10, "scans_bytes": 4, "results_bytes": 6, "datasets_bytes": 0,
    ...                             "exports_bytes": 0, "other_bytes": 0})
    >>> d.total_bytes, d.free_bytes
    (10, None)
    """


class ComputeDevice(Answer, wire.ComputeDevice):
    """A device the server's reconstructions can run on (the ``devices`` of :class:`Health`).

    Attributes
    ----------
    kind : str
        ``cpu`` or ``cuda``.
    name : str
        The GPU's name, or ``"cpu"``.
    cores : int or None
        The CPU's cores.
    memory_total : int or None
        A GPU's memory, bytes.

    Examples
    --------
    >>> from fpscan.clients.http.models import ComputeDevice
    >>> cpu = ComputeDevice.model_validate({"kind": "cpu", "name": "cpu", "cores": 16})
    >>> cpu.kind, cpu["cores"], cpu.memory_total
    ('cpu', 16, None)
    """


class Health(Answer, wire.Health):
    """``GET /api/health``: the server is alive, its version, and what keeps jobs from running.

    Attributes
    ----------
    status : str
        ``"ok"``.
    version : str
        The server's version.
    executor : str
        Where reconstructions run (``"local"`` or ``"dask"``).
    jobs_running : int
        Reconstruction jobs running now.
    disk : DiskUse or None
        The data folder's use and free space.
    problems : list of str
        What keeps jobs from running now, one line each.
    devices : list of ComputeDevice
        The CPU, then each CUDA GPU.

    Examples
    --------
    >>> from fpscan.clients.http.models import Health
    >>> h = Health.model_validate({"version": "1.2", "executor": "local", "devices": [{"kind": "cpu", "name": "cpu"}]})
    >>> h.status, h["version"], h.devices[0].kind
    ('ok', '1.2', 'cpu')
    """

    disk: DiskUse | None = None
    devices: list[ComputeDevice] = Field(default_factory=list)


# -- reconstruction methods and file formats -----------------------------------------
class MethodOption(Answer, wire.MethodOption):
    """One option of a reconstruction method (or a file format's load option).

    Attributes
    ----------
    name : str
        Its name in the reconstruction's ``params`` (an upload's field for a format).
    description : str
        What it is.
    default : any
        The method's default (None: derived from the data).
    value_schema : dict
        JSON schema of a value (``type``, bounds or ``enum``, ``unit``).

    Examples
    --------
    >>> from fpscan.clients.http.models import MethodOption
    >>> o = MethodOption.model_validate({"name": "eps", "description": "regularisation", "default": 0.01})
    >>> o.name, o["default"], o.value_schema
    ('eps', 0.01, {})
    """


class MethodInfo(Answer, wire.MethodInfo):
    """A reconstruction method (``GET /api/reconstructions/methods``).

    Attributes
    ----------
    name, title, source : str
        Its name (a reconstruction's ``method``), what a person reads, where it comes from.
    needs_grid : bool
        Needs data on a full regular grid.
    options : list of MethodOption
        The options it takes.
    iterative, time_limited, cancellable : bool
        An iterative solver; takes ``time_limit``; a cancel ends it within a step.
    default_for : list of str
        The inputs it is the server's default for (``grid``, ``points``).
    summary : list of dict
        The fields of its result it shows.

    Examples
    --------
    >>> from fpscan.clients.http.models import MethodInfo
    >>> m = MethodInfo.model_validate({"name": "ner", "title": "NER", "needs_grid": True, "source": "paper",
    ...                                "options": [{"name": "eps", "description": "regularisation"}],
    ...                                "default_for": ["grid"]})
    >>> m.options[0].name, m["default_for"], m.get("default_for")
    ('eps', ['grid'], ['grid'])
    """

    options: list[MethodOption] = Field(default_factory=list)


class DatasetFormatInfo(Answer, wire.DatasetFormatInfo):
    """A format a dataset upload takes (``GET /api/datasets/formats``).

    Attributes
    ----------
    name : str
        The upload's ``format``.
    title : str
        What a person reads.
    wavelengths : bool
        May hold several wavelengths.

    Examples
    --------
    >>> from fpscan.clients.http.models import DatasetFormatInfo
    >>> f = DatasetFormatInfo.model_validate({"name": "npy", "title": "NumPy array", "wavelengths": False})
    >>> f.name, f["wavelengths"]
    ('npy', False)
    """


class FormatInfo(Answer, wire.FormatInfo):
    """A file format of the server's registry (``GET /api/formats``): what it reads and exports.

    Attributes
    ----------
    name, title, noun : str
        Its name, what a person reads, the format in a sentence.
    input, upload, wavelengths, folder : bool
        A reconstruction input; an upload choice; may hold several wavelengths; an export
        that is a folder (served zipped).
    export_from : str or None
        The format whose files it exports (None: no export).
    suffix, media_type : str
        An export's file-name ending and ``Content-Type``.
    options : list of MethodOption
        Its load options.

    Examples
    --------
    >>> from fpscan.clients.http.models import FormatInfo
    >>> f = FormatInfo.model_validate({"name": "npz", "title": "NumPy", "noun": "an npz file", "input": True,
    ...                                "upload": True, "wavelengths": False, "export_from": "result",
    ...                                "suffix": ".npz", "media_type": "application/zip", "folder": False})
    >>> f["export_from"], f.get("suffix"), f.options
    ('result', '.npz', [])
    """

    options: list[MethodOption] = Field(default_factory=list)


# -- datasets ------------------------------------------------------------------------
class Dataset(Answer, wire.Dataset):
    """An uploaded dataset as ``POST /api/datasets`` stored it.

    Attributes
    ----------
    dataset_id, format, layout : str
        Its id, the format it was read as, ``grid``/``points``/``scan``.
    shape : list of int
        The stored data's shape.
    dt : float or None
        Sample interval, s.
    wavelength_nm : float or None
        Its excitation wavelength, nm.
    deduplicated : bool
        An identical earlier upload answered.
    content_sha256 : str or None
        SHA-256 of the file's bytes.

    Examples
    --------
    >>> from fpscan.clients.http.models import Dataset
    >>> d = Dataset.model_validate({"dataset_id": "d1", "format": "npy", "layout": "grid", "shape": [64, 8, 8]})
    >>> d.dataset_id, d["shape"], d.deduplicated
    ('d1', [64, 8, 8], False)
    """


class DatasetInfo(Answer, wire.DatasetInfo):
    """A stored dataset as ``GET /api/datasets`` lists it.

    Attributes
    ----------
    dataset_id : str
        Its id.
    name, format, layout : str or None
        The file's name, its format and layout.
    shape : list of int or None
        The stored data's shape.
    dt, wavelength_nm : float or None
        s, nm.
    wavelength_index : int or None
        Its wavelength's index in the uploaded file.
    content_sha256 : str or None
        SHA-256 of the file's bytes.
    size_bytes : int
        Bytes on disk.
    created, last_used : float or None
        UNIX times, s.
    jobs : list of str
        The reconstruction jobs that read it.
    in_use : bool
        An active job reads it (it cannot be deleted).

    Examples
    --------
    >>> from fpscan.clients.http.models import DatasetInfo
    >>> d = DatasetInfo.model_validate({"dataset_id": "d1", "size_bytes": 2048, "created": 1.7e9})
    >>> d["dataset_id"], d.get("in_use"), d.jobs
    ('d1', False, [])
    """


# -- answers typed as dicts ----------------------------------------------------------
class AuthInfo(TypedDict):
    """``GET /api/auth``: whether the server needs a token, and whether this client's is right.

    Attributes
    ----------
    token_required : bool
        Every ``/api`` route but this one needs a bearer token.
    authenticated : bool
        No token is needed, or the one sent is right.

    Examples
    --------
    >>> from fpscan.clients.http.models import AuthInfo
    >>> info: AuthInfo = {"token_required": True, "authenticated": False}
    >>> sorted(AuthInfo.__annotations__), info["authenticated"]
    (['authenticated', 'token_required'], False)
    """

    token_required: bool
    authenticated: bool


class Retention(TypedDict):
    """``GET`` / ``PUT /api/retention``: what the server keeps (None: no limit).

    Attributes
    ----------
    keep_results : int or None
        Finished reconstruction results kept, newest first.
    keep_bytes : int or None
        Bytes of result files kept at most.
    include_scans : bool
        Scan files count and may be deleted too.
    datasets_keep_bytes : int or None
        Bytes of uploaded datasets no active job reads kept at most.
    datasets_max_age_s : float or None
        Such datasets are deleted once older than this, s.

    Examples
    --------
    >>> from fpscan.clients.http.models import Retention
    >>> policy: Retention = {"keep_results": 10, "keep_bytes": None, "include_scans": False,
    ...                      "datasets_keep_bytes": None, "datasets_max_age_s": 86400.0}
    >>> len(Retention.__annotations__), policy["keep_results"]
    (5, 10)
    """

    keep_results: int | None
    keep_bytes: int | None
    include_scans: bool
    datasets_keep_bytes: int | None
    datasets_max_age_s: float | None


class Deleted(TypedDict):
    """What a ``DELETE`` of a job, plan or dataset removed.

    Attributes
    ----------
    id : str
        What was removed.
    kind : str
        A job's kind (``scan``, ``recon``), ``plan`` or ``dataset``.
    bytes_freed : int
        Bytes of files removed.

    Examples
    --------
    >>> from fpscan.clients.http.models import Deleted
    >>> gone: Deleted = {"id": "d1", "kind": "dataset", "bytes_freed": 2048}
    >>> gone["bytes_freed"], sorted(Deleted.__annotations__)
    (2048, ['bytes_freed', 'id', 'kind'])
    """

    id: str
    kind: str
    bytes_freed: int


class MaskKindInfo(TypedDict):
    """A mask kind as ``GET /api/plans/kinds`` lists it.

    Attributes
    ----------
    kind, label, description : str
        Its name (a plan's ``kind``), what a person reads, the kind in one line.
    aliases : list of str
        Other names it is accepted by.
    fields : list of dict
        Its parameters as plain descriptors.
    params_schema : dict
        The JSON schema of its parameters.

    Examples
    --------
    >>> from fpscan.clients.http.models import MaskKindInfo
    >>> kind: MaskKindInfo = {"kind": "full", "label": "Full", "description": "every point", "aliases": [],
    ...                       "fields": [], "params_schema": {}}
    >>> kind["kind"], len(MaskKindInfo.__annotations__)
    ('full', 6)
    """

    kind: str
    label: str
    description: str
    aliases: list[str]
    fields: list[dict[str, Any]]
    params_schema: dict[str, Any]


#: the client's response models by name (the server's schema of the same name has the same fields)
MODELS: dict[str, type[Answer]] = {
    m.__name__: m for m in (Plan, PlanPreview, JobProgress, Attempt, Timings, Job, Scanner, PreviewInfo, DiskUse,
                            ComputeDevice, Health, MethodOption, MethodInfo, DatasetFormatInfo, FormatInfo, Dataset,
                            DatasetInfo)
}

#: the answers typed as plain dicts, by name (the server's schema of the same name has the same keys)
DICTS: dict[str, type] = {d.__name__: d for d in (AuthInfo, Retention, Deleted, MaskKindInfo)}
