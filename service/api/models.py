"""Request and response models of the HTTP API (pydantic; the plan request is derived from
the mask kinds declared in ``fpscan.service.plans.kinds``).

The response models of plans, jobs, scanners, previews, health, methods, formats and datasets
subclass ``fpscan.wire.models`` (their fields defined once, shared with the client's lenient
``fpscan.clients.http.models``) and narrow what the server guarantees (literal states and
kinds, required fields). Units are SI (m, s,
m/s, Hz, bytes). Request models refuse unknown fields, NaN and infinities (``ValueError`` →
HTTP 422 with the reason).
Contract: docs/api.md.
"""
from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, Annotated, Any, Literal, Union

from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    create_model,
    model_validator,
)

from fpscan.service.formats import upload_formats
from fpscan.service.pipeline import METHODS
from fpscan.service.plans.kinds import KINDS, MaskKind, resolve_kind
from fpscan.service.plans.plan import ORDER_NAMES, Acquisition
from fpscan.service.plans.plan import Plan as PlanJson
from fpscan.service.recon import methods as _methods
from fpscan.service.recon.methods.options import MethodOptions, plausible_speeds
from fpscan.wire import models as wire

__all__ = [
    "JobState", "JobKind", "ReconMethod", "Plane", "DATASET_FORMATS", "DatasetFormat", "ID_PATTERN", "LatticeIndex",
    "Error", "DiskUse", "ComputeDevice", "Health", "AuthInfo", "Deleted", "Retention", "MAX_LATTICE_POINTS", "Pitch", "Lattice",
    "PlanDocument", "PlanCreate", "MethodOption", "DatasetFormatInfo", "FormatInfo", "MethodInfo", "MaskKindInfo", "Plan",
    "PlanPreview", "JobProgress", "Attempt", "Timings", "Job", "ScanRequest", "Scanner", "PreviewInfo", "Dataset",
    "DatasetInfo", "PARAMS_MODELS", "UnmixOptions", "ReconRequestBase", "ReconRequestDefaultMethod", "REQUEST_MODELS",
    "DEFAULT_METHOD_TAG", "ReconRequest",
]


def _one_of(values: Iterable[str]) -> Any:
    """A string type accepting only ``values`` (listed as the schema's ``enum``), so
    that the vocabularies stay those of their owner (``fpscan.service.pipeline``)."""
    allowed = tuple(values)

    def check(v: str) -> str:
        if v not in allowed:
            raise ValueError(f"must be one of {', '.join(allowed)}, got {v!r}")
        return v

    return Annotated[str, AfterValidator(check), Field(json_schema_extra={"enum": list(allowed)})]


JobState = Literal["queued", "running", "paused", "succeeded", "failed", "cancelled"]
JobKind = Literal["scan", "recon"]
ReconMethod = _one_of(METHODS)
Plane = Literal["xy", "xz", "yz"]
#: the formats ``POST /api/datasets`` accepts: the registry's (``fpscan.service.formats``, ``upload``)
DATASET_FORMATS = tuple(f["name"] for f in upload_formats())
DatasetFormat = Literal[DATASET_FORMATS]  # type: ignore[valid-type]  # a Literal of the registry's names

ID_PATTERN = r"^[A-Za-z0-9_-]{1,128}$"

LatticeIndex = Annotated[int, Field(ge=0, le=1023)]


class _Request(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class Error(BaseModel):
    """Every 4xx/5xx body: ``{"detail": "<reason>"}``.

    Attributes
    ----------
    detail : str
        The reason, one line.
    """

    detail: str


class DiskUse(wire.DiskUse):
    """Bytes the data folder uses, by part, and the free space of its file system.

    Attributes
    ----------
    total_bytes : int
        The sum of the parts.
    scans_bytes : int
        Scan files.
    results_bytes : int
        Reconstruction results.
    datasets_bytes : int
        Uploaded datasets.
    exports_bytes : int
        Exports.
    other_bytes : int
        The job database, plans and anything else.
    free_bytes : int or None
        Free bytes of the data folder's file system; null when unknown.
    """


class ComputeDevice(wire.ComputeDevice):
    """A device reconstructions can run on (``GET /api/health``'s ``devices``).

    Attributes
    ----------
    kind : {"cpu", "cuda"}
        The CPU (the worker processes' cores) or a CUDA GPU (`fpscan.service.recon.device`).
    name : str
        The GPU's name, or ``"cpu"``.
    cores : int or None
        The CPU's cores (null for a GPU).
    memory_total : int or None
        A GPU's memory in bytes (null for the CPU).
    """

    kind: Literal["cpu", "cuda"]


class Health(wire.Health):
    """``GET /api/health``: the server is alive, what it runs and what keeps jobs from running.

    Attributes
    ----------
    status : "ok"
        Always ``"ok"``.
    version : str
        The server's version.
    executor : str
        Where reconstructions run (the server's ``executor`` setting: ``"local"`` or ``"dask"``).
    jobs_running : int
        Reconstruction jobs running now (default 0).
    disk : DiskUse or None
        Bytes the data folder uses by part, and its free space.
    problems : list of str
        What keeps jobs from running now (e.g. a scan paused by a full disk or a lost
        device), one line each.
    devices : list of ComputeDevice
        What reconstructions can run on: the CPU, then each CUDA GPU the server found at its
        start (asked in a child process; listed once it answered).
    """

    status: Literal["ok"] = "ok"
    disk: DiskUse | None = None
    devices: list[ComputeDevice] = Field(default_factory=list, description="what reconstructions can run on: the CPU, "
                                         "then each CUDA GPU found at the server's start")


class AuthInfo(BaseModel):
    """``GET /api/auth``: whether the server needs a bearer token (then every ``/api``
    route but this one needs it) and whether the request carried the right one.

    Attributes
    ----------
    token_required : bool
        The server needs a bearer token.
    authenticated : bool
        True when no token is needed or the one sent is right.
    """

    token_required: bool
    authenticated: bool = Field(description="true when no token is needed or the one sent is right")


class Deleted(BaseModel):
    """What a DELETE removed.

    Attributes
    ----------
    id : str
        The id of what was removed.
    kind : str
        What it was: a job's kind (``"scan"``, ``"recon"``), ``"plan"`` or ``"dataset"``.
    bytes_freed : int
        Bytes of files removed (default 0).
    """

    id: str
    kind: str
    bytes_freed: int = 0


class Retention(_Request):
    """Retention policy: keep the newest ``keep_results`` finished reconstruction results
    and at most ``keep_bytes`` bytes of result files (null = no limit); the oldest finished
    are deleted first. Scan files only with ``include_scans``.

    Attributes
    ----------
    keep_results : int or None
        Finished reconstruction results kept, newest first (0 to 10^9); null: no limit.
    keep_bytes : int or None
        Bytes of result files kept at most (0 to 10^18); null: no limit.
    include_scans : bool
        Scan files count and may be deleted too (default false).
    datasets_keep_bytes : int or None
        Bytes of uploaded datasets no active job reads kept at most; the oldest go first.
    datasets_max_age_s : float or None
        Uploaded datasets no active job reads are deleted once older than this, s.
    """

    keep_results: int | None = Field(None, ge=0, le=10**9)
    #: at most 10^18 (1 EB): a bound a float states exactly (the OpenAPI document writes bounds
    #: as floats; 2^62 read back as 4.611686018427388e+18, above 2^62, so schema-valid values got 422)
    keep_bytes: int | None = Field(None, ge=0, le=10**18)
    include_scans: bool = False
    datasets_keep_bytes: int | None = Field(None, ge=0, le=2**62, description="keep at most this many bytes of "
                                            "uploaded datasets no active job reads; the oldest go first")
    datasets_max_age_s: float | None = Field(None, ge=0, le=1e10, description="delete uploaded datasets no active "
                                             "job reads once older than this, s")


# -- plans ---------------------------------------------------------------------------
#: Most lattice points a plan request may span: a mask's weights and the plan's JSON cost
#: time linear in the points, so a request beyond this is refused (422) before any work.
MAX_LATTICE_POINTS = 1 << 18


def _pitch(v: Any) -> Any:
    """Before-validator of a pitch: text with a unit ("60um") → m; then the plausible
    range of ``fpscan.driver.units`` (a pitch of 60 means 60 m: 422 naming µm)."""
    from fpscan.driver.units import check_plausible, parse_quantity

    if isinstance(v, str):
        v = parse_quantity(v, "length", name="pitch")
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        check_plausible(pitch=float(v))
    return v


Pitch = Annotated[float, BeforeValidator(_pitch)]


class Lattice(_Request):
    """The scanner lattice: ``n_x × n_y`` points at ``pitch`` (m), centred on the axis;
    at most ``MAX_LATTICE_POINTS`` (262144, e.g. 512 × 512) points in all.

    Attributes
    ----------
    n_x : int
        Points along x (1 to 1024).
    n_y : int
        Points along y (1 to 1024; default 1: a line).
    pitch : float
        Lattice pitch, m (1 µm to 10 mm; text with a unit such as ``"60um"`` is accepted).
    """

    n_x: int = Field(ge=1, le=1024)
    n_y: int = Field(1, ge=1, le=1024)
    pitch: Pitch = Field(description="lattice pitch, m (1 µm to 10 mm; text with a unit such as "
                                     "\"60um\" is accepted)")

    @model_validator(mode="after")
    def _bounded(self) -> Lattice:
        if self.n_x * self.n_y > MAX_LATTICE_POINTS:
            raise ValueError(f"a lattice of {self.n_x} x {self.n_y} points is more than the "
                             f"{MAX_LATTICE_POINTS} lattice points a plan request may span")
        return self


def _plan_body_tag(v: Any) -> str | None:
    """Which variant of a plan request ``v`` is: ``"plan"`` for a plan JSON
    (``format``), else the canonical mask kind (``points`` when only a point list is given)."""
    if isinstance(v, BaseModel):
        v = v.model_dump()
    if not isinstance(v, dict):
        return None
    if "format" in v:
        return "plan"
    kind = v.get("kind")
    if kind is None and "points" in v:
        return "points"
    try:
        return resolve_kind(kind).name
    except ValueError:
        return None


class _PlanCreate(_Request):
    lattice: Lattice
    order: Literal[ORDER_NAMES] | None = Field(  # type: ignore[valid-type]
        None, description="scan order (default auto: rings for equisteradian, given for a point list, "
                          "serpentine otherwise)")
    acquisition: Acquisition = Field(default_factory=Acquisition)
    force: bool = Field(False, description=f"accept a sound speed outside {plausible_speeds()} m/s")

    @model_validator(mode="before")
    @classmethod
    def _units_first(cls, data: Any) -> Any:
        """Text with a unit ("8 ns", "500Hz", "1.5 km/s", "750 nm"; the kind's parameters:
        "3.6 mm") → SI numbers, then the plausibility rules of ``fpscan.driver.units`` on the
        raw values (dt, PRF, sound speed, the depth of the point of interest), so that a unit
        mistake (dt 8 s, depth 3.6 m) is named before the range checks of ``Acquisition`` and
        the kind's parameter model."""
        if not isinstance(data, dict):
            return data
        from fpscan.driver.plan import MAX_WAVELENGTHS
        from fpscan.driver.units import parse_quantity
        from fpscan.service.plans import check_plausible_request
        from fpscan.service.plans.kinds import si_params

        acq = data.get("acquisition")
        if isinstance(acq, dict):
            acq = dict(acq)
            for name, unit_kind in (("dt", "time"), ("prf", "frequency"), ("sound_speed", "speed")):
                if isinstance(acq.get(name), str):
                    acq[name] = parse_quantity(acq[name], unit_kind, name=name)
            wl = acq.get("wavelengths")
            if isinstance(wl, list) and len(wl) <= MAX_WAVELENGTHS:  # a longer list is refused by its range
                acq["wavelengths"] = [parse_quantity(w, "length", name="wavelength") if isinstance(w, str) else w
                                      for w in wl]
            data = {**data, "acquisition": acq}
        try:
            kind = resolve_kind(data.get("kind")).name if isinstance(data.get("kind"), str) else None
        except ValueError:
            kind = None  # the discriminator names an unknown kind
        if kind is not None and isinstance(data.get("params"), dict):
            data = {**data, "params": si_params(KINDS[kind].params, data["params"])}
        check_plausible_request(None, kind, None, data.get("params"), acq if isinstance(acq, dict) else None,
                                force=data.get("force") is True)
        return data


def _plan_create(k: MaskKind) -> type[_PlanCreate]:
    names = (k.name, *k.aliases)
    needs = any(f.is_required() for f in k.params.model_fields.values())
    fields: dict[str, Any] = {
        "kind": (Literal[names], Field(k.name if k.name == "points" else ...,
                                       description=f"mask kind {k.name!r}" + (f" (aliases: {', '.join(k.aliases)})"
                                                                             if k.aliases else ""))),
        "params": (k.params | None if k.name == "points" else k.params,
                   Field(None) if k.name == "points" else (Field(...) if needs else Field(default_factory=k.params))),
    }
    if k.name == "points":
        fields["points"] = (list[tuple[LatticeIndex, LatticeIndex]] | None, Field(
            None, max_length=1024 * 1024, description="lattice indices [[i_x, i_y], ...]: short for params.indices"))
    model = create_model(f"PlanCreate_{k.name}", __base__=_PlanCreate, **fields)
    if k.name == "points":  # the schema states what build_plan enforces: one of points, params
        model.model_config["json_schema_extra"] = {"oneOf": [
            {"required": [a], "properties": {b: {"type": "null"}}} for a, b in (("points", "params"), ("params", "points"))]}
    model.__doc__ = f"A plan from a {k.label.lower()} mask: {k.description}"
    return model


class PlanDocument(PlanJson):
    """A plan JSON as ``fpscan plan --out plan.json`` writes it (``fpscan-plan/1``,
    docs/architecture.md); stored under its own id after the plan contract's checks.

    Attributes
    ----------
    format : str
        ``"fpscan-plan/1"``.
    id : str
        The plan's content hash.
    lattice, mask, points, order, acquisition
        As in ``fpscan.service.plans.plan.Plan`` (the points in scan order).
    """


#: The body of ``POST /api/plans`` and ``/api/plans/preview``: one variant per mask kind
#: (keyed on ``kind``; ``params`` is that kind's parameter model from
#: ``fpscan.service.plans.kinds``), or a whole plan JSON (keyed on ``format``).
PlanCreate: Any = Annotated[
    Union[tuple(Annotated[_plan_create(k), Tag(k.name)] for k in KINDS.values())  # noqa: UP007
          + (Annotated[PlanDocument, Tag("plan")],)],
    Discriminator(_plan_body_tag, custom_error_type="plan_body", custom_error_message=(
        "give a mask kind (" + ", ".join(KINDS) + ") with its params, a point list ('points'), "
        "or a plan JSON ('format': 'fpscan-plan/1')")),
]


class MethodOption(wire.MethodOption):
    """One option of a reconstruction method (its field in the method's options model,
    ``fpscan.service.recon.methods``), or a file format's load option (:class:`FormatInfo`).

    Attributes
    ----------
    name : str
        The option's name, as the library, the request's ``params`` and the files name it.
    description : str
        What it is, for a person.
    default : Any
        This method's default (null: derived from the data, e.g. n_z = n_t).
    value_schema : dict
        JSON schema of a value: type, minimum/maximum/exclusiveMinimum or enum, and unit
        (SI), quantity (length/time: text with a unit accepted); forms are built from it.
    """


class DatasetFormatInfo(wire.DatasetFormatInfo):
    """One format ``POST /api/datasets`` accepts, as ``GET /api/datasets/formats`` lists it
    (the registry ``fpscan.service.formats``; the web page's and the HTTP client's choices)."""


class FormatInfo(wire.FormatInfo):
    """One file format of the server's registry (``fpscan.service.formats``), as ``GET /api/formats``
    lists it: what it reads and what it exports."""

    options: list[MethodOption] = Field(default_factory=list, description="its load options (an upload's fields)")

    @classmethod
    def of(cls, fmt: Any) -> FormatInfo:
        """The public view of a registered ``fpscan.service.formats.Format``."""
        from fpscan.service.recon.methods import option_schemas

        options = [MethodOption(name=o["name"], description=o["description"], default=o["default"],
                                value_schema=o["schema"]) for o in option_schemas(fmt.options)] if fmt.options else []
        return cls(name=fmt.name, title=fmt.title, noun=fmt.what, input=fmt.input, upload=fmt.upload,
                   wavelengths=fmt.wavelengths, export_from=fmt.export_from, suffix=fmt.suffix,
                   media_type=fmt.media_type, folder=fmt.folder, options=options)


class MethodInfo(wire.MethodInfo):
    """One reconstruction method as ``GET /api/reconstructions/methods`` lists it
    (``fpscan.service.pipeline.METHODS``; the web page's method choices are built from these).

    Attributes
    ----------
    name : str
        The method's name (``ReconRequest.method``).
    title : str
        What a person reads.
    needs_grid : bool
        Needs data on a full regular grid (every lattice point).
    options : list of MethodOption
        The options it takes.
    source : str
        Where the algorithm comes from.
    iterative : bool
        An iterative solver: sound_speed 'auto' searches with the input's default direct
        method, then runs it once (default false).
    time_limited : bool
        Takes time_limit (s), capped by the server's time_limit_s (default false).
    cancellable : bool
        Reports progress between steps; a cancel ends it within a step (default true).
    default_for : list of str
        The inputs it is the default method for: 'grid' (a full lattice), 'points' (any mask).
    summary : list of dict
        The fields of its result it shows after its outcome (``Method.summary``, each a
        ``fpscan.service.progress.Shown`` as JSON); empty for most methods.
    """

    options: list[MethodOption]


class MaskKindInfo(BaseModel):
    """One mask kind as ``GET /api/plans/kinds`` lists it (forms are built from these).

    Attributes
    ----------
    kind : str
        The kind's name (a plan request's ``kind``).
    label : str
        What a person reads.
    description : str
        The kind in one line.
    aliases : list of str
        Other names the kind is accepted by.
    fields : list of dict
        Its parameters as plain descriptors (``fpscan.service.plans.kinds.kind_fields``).
    params_schema : dict
        The JSON schema of its parameter model (a plan request's ``params``).
    """

    kind: str
    label: str
    description: str
    aliases: list[str]
    fields: list[dict[str, Any]]
    params_schema: dict[str, Any]


class Plan(wire.Plan):
    """A stored plan's summary (``POST /api/plans``, ``GET /api/plans``, ``GET /api/plans/{id}``).

    Attributes
    ----------
    id : str
        The plan's id (its content hash).
    kind : str
        Its mask kind (``"points"`` for a point list).
    n_points : int
        Points in the plan.
    requested_points : int or None
        Points the mask asked for (the mask's ``requested_points``); null when not recorded.
    shortfall : str or None
        Why the plan has fewer points than asked (under 90 %), one line; null when it has
        about as many.
    weight_ratio : float or None
        The mask's outer/inner weight ratio (``fpscan.service.plans.mask.weight_ratio``).
    expected_scan_time_s : float or None
        Points × averages × wavelengths / PRF, s; null when the plan sets no PRF (unthrottled).
    lattice : dict
        The plan's lattice (``n_x``, ``n_y``, ``pitch`` in m).
    acquisition : dict
        The plan's acquisition settings (``fpscan.service.plans.plan.Acquisition``: ``n_t``, ``dt``
        in s, ``prf`` in Hz, ...).
    links : dict of str to str
        Name -> API path: ``self``, ``preview`` (the mask preview PNG).
    """

    lattice: dict[str, Any]
    acquisition: dict[str, Any]


class PlanPreview(wire.PlanPreview):
    """``POST /api/plans/preview``: a plan built and drawn, not stored.

    Attributes
    ----------
    points : int
        Points in the plan.
    weight_ratio : float or None
        The mask's outer/inner weight ratio (``fpscan.service.plans.mask.weight_ratio``).
    expected_scan_time_s : float or None
        Points × averages × wavelengths / PRF, s; null when the plan sets no PRF (unthrottled).
    preview_png_base64 : str
        The mask preview PNG, base64-encoded.
    """

    preview_png_base64: str


# -- jobs ----------------------------------------------------------------------------
class JobProgress(wire.JobProgress):
    """A job's progress on the wire (the ``progress`` of a :class:`Job`; the callback type of
    the library is ``fpscan.service.progress.Progress``). Each field's unit is in its description,
    which the OpenAPI document (``/openapi.json``) serves."""

    model_config = ConfigDict(extra="allow")


class Attempt(wire.Attempt):
    """An attempt of a job that was cut off and re-queued (a dead worker, a shutdown, a restart).

    Attributes
    ----------
    attempt : int
        Its number (1 for the first run).
    started : float or None
        UNIX time it started, s.
    ended : float
        UNIX time it was cut off, s.
    run_s : float or None
        Seconds it ran (on a monotonic clock).
    reason : str or None
        Why it was cut off, one line.
    """

    attempt: int
    ended: float


class Timings(wire.Timings):
    """When a job was created, started and finished (UNIX times, s) and how long it waited and ran.

    The times of the current (or last) attempt: a job re-queued after its run was cut off
    starts its timing anew, and the attempts before it are listed in ``earlier_attempts``.

    Attributes
    ----------
    created : float
        UNIX time the job was submitted, s.
    started : float or None
        UNIX time its current attempt started, s; null until then (again null while it waits
        after a cut-off attempt).
    finished : float or None
        UNIX time it ended, s; null until then.
    queued_s : float or None
        Seconds from created to started; null until it started. Measured on a monotonic clock
        (not the difference of the wall times above: a wall clock set meanwhile does not change it).
    run_s : float or None
        Seconds from started to finished (the attempt that ended it); null until it ended.
        Monotonic, as ``queued_s``.
    earlier_attempts : list of Attempt
        The attempts cut off before the current one, oldest first (empty for most jobs).
    """

    created: float
    earlier_attempts: list[Attempt] = Field(default_factory=list)


class Job(wire.Job):
    """A scan or reconstruction job as ``GET /api/jobs/{id}`` shows it.

    Attributes
    ----------
    id : str
        The job's id.
    kind : {"scan", "recon"}
        What it does.
    state : {"queued", "running", "paused", "succeeded", "failed", "cancelled"}
        Where it is.
    progress : JobProgress
        Its latest progress.
    timings : Timings
        When it was created, started and finished.
    params : dict
        What it was asked to do (a reconstruction's method and options, its ``result``
        summary once it succeeded; the speed of sound named ``sound_speed``).
    links : dict of str to str
        Name -> API path of its resources (``self``, ``events``, ``cancel``, ``delete``; a
        scan's ``file``, ``preview``, ...; a succeeded reconstruction's ``volume``, ``slice``,
        ``mip_<plane>``; ``export_<format>``).
    attempts : int
        Times it was started (default 0).
    error : str or None
        Why it failed, one line; null otherwise.
    """

    kind: JobKind
    state: JobState
    progress: JobProgress
    timings: Timings
    params: dict[str, Any]
    links: dict[str, str]


# -- scans ---------------------------------------------------------------------------
class ScanRequest(_Request):
    """``POST /api/scans``: scan a stored plan on a scanner.

    Attributes
    ----------
    plan_id : str
        The stored plan's id.
    scanner_id : str
        The scanner's id (``GET /api/scanners``, the server's configured devices).
    preview_wavelength : int
        Index into the plan's excitation wavelengths: the wavelength the live preview shows
        (default 0, the first).
    """

    plan_id: str = Field(pattern=ID_PATTERN)
    scanner_id: str = Field(pattern=ID_PATTERN)
    preview_wavelength: int = Field(0, ge=0, description="index into the plan's excitation wavelengths: "
                                    "the wavelength the live preview shows (default the first)")


class Scanner(wire.Scanner):
    """One scanner the server is configured with, and what it is doing.

    Attributes
    ----------
    id : str
        The scanner's id (a ``ScanRequest``'s ``scanner_id``).
    port : str
        Its device (serial port) path.
    status : {"idle", "busy", "unreachable", "unknown"}
        ``busy``: it runs a scan; ``unreachable``: its device is missing; ``unknown``: the
        server has no scanning (no driver).
    job_id : str or None
        The scan job it runs; null when none.
    identity : str or None
        What the device said when it was last identified (at the start of a scan); null
        until then.
    """

    port: str
    status: Literal["idle", "busy", "unreachable", "unknown"]


class PreviewInfo(wire.PreviewInfo):
    """A scan's live preview state (``GET /api/scans/{id}/preview``).

    Attributes
    ----------
    version : int
        Grows with every refresh (0: none yet).
    points_used : int
        The completed points the preview reconstructed.
    wavelength_index : int
        The excitation wavelength shown (index into the plan's; default 0).
    updated : float or None
        UNIX time of the last refresh, s.
    refresh_s : float or None
        How long the last refresh took, s.
    """

    wavelength_index: int = Field(
        0, description=wire.PreviewInfo.model_fields["wavelength_index"].description)


# -- datasets and reconstructions ----------------------------------------------------
class Dataset(wire.Dataset):
    """An uploaded dataset as ``POST /api/datasets`` stored it.

    Attributes
    ----------
    dataset_id : str
        Its id (a ``ReconRequest``'s ``dataset_id``).
    format : str
        The format it was read as (one of ``DATASET_FORMATS``).
    layout : {"grid", "points", "scan"}
        ``grid``: data on a full lattice; ``points``: A-lines at sensor points.
    shape : list of int
        The stored data's shape: ``[n_t, n_y, n_x]`` or ``[n_t, n_x]`` for a grid,
        ``[n_points, n_t]`` for points.
    dt : float or None
        Sample interval, s.
    wavelength_nm : float or None
        The excitation wavelength whose data the dataset holds, nm (a scan or IPASC file that
        records it).
    deduplicated : bool
        The same file with the same import options was stored before: this is that dataset,
        nothing new was stored (default false).
    content_sha256 : str or None
        SHA-256 of the uploaded file's bytes.
    """

    format: DatasetFormat
    layout: Literal["grid", "points", "scan"]


class DatasetInfo(wire.DatasetInfo):
    """A stored dataset in ``GET /api/datasets``.

    Attributes
    ----------
    dataset_id : str
        Its id.
    name : str or None
        The uploaded file's name (display only).
    format, layout, shape, dt, wavelength_nm, content_sha256
        As in :class:`Dataset`.
    wavelength_index : int or None
        The index of its wavelength among the uploaded file's.
    size_bytes : int
        Bytes of its files on disk.
    created : float
        UNIX time of the upload, s.
    last_used : float or None
        UNIX time of the upload or of the latest identical upload answered with it
        (retention by age counts from it), s.
    jobs : list of str
        Ids of the reconstruction jobs that read it.
    in_use : bool
        A queued, running or paused job reads it (it cannot be deleted).
    """


def _params_model(method: _methods.Method) -> type[MethodOptions]:
    """``method``'s options as the request body carries them: its own model
    (``Method.options_model``) under a name of its own in the OpenAPI document
    (``NerOptions``, ``TvOptions``, ...), refusing another method's option with this method's
    words (``method 'ner' takes no option lam (its options: ...)``)."""
    title = "".join(part.capitalize() for part in method.name.replace("-", "_").split("_")) + "Options"

    def _its_own(data: Any) -> Any:
        if isinstance(data, dict):
            METHODS[method.name].refuse_foreign(data)
        return data

    def _can_search(model: Any) -> Any:
        METHODS[method.name].refuse_search(model)
        return model

    validators: dict[str, Any] = {"_its_own": model_validator(mode="before")(_its_own),
                                  "_can_search": model_validator(mode="after")(_can_search)}
    return create_model(title, __base__=method.options_model, __module__=__name__,
                        __doc__=f"The options of method {method.name!r} ({method.title}; "
                                f"fpscan.service.recon.methods.get({method.name!r}).options_model).",
                        __validators__=validators)


#: each method's request options model, by name (:func:`_params_model`)
PARAMS_MODELS: dict[str, type[MethodOptions]] = {name: _params_model(m) for name, m in METHODS.items()}


def __getattr__(name: str) -> Any:
    """``ReconParams``, an earlier release's flat union of every method's options, is gone: a
    request's ``params`` is its method's own model (:data:`PARAMS_MODELS`)."""
    if name == "ReconParams":
        raise AttributeError("ReconParams is gone: a request's params are its method's own options model "
                             "(fpscan.service.api.models.PARAMS_MODELS[method], fpscan.service.recon.methods."
                             "get(method).options_model)")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class UnmixOptions(_Request):
    """Spectral unmixing into HbO2 and Hb (``fpscan.service.recon.unmix``: NNLS per voxel)."""

    threshold: float = Field(0.1, ge=0, lt=1, description="mask voxels whose THb is below this fraction of the maximum")
    fluence: list[Annotated[float, Field(gt=0, allow_inf_nan=False)]] | None = Field(
        None, max_length=16, description="fluence at each wavelength, J/m² (default: assumed equal everywhere)")


class ReconRequestBase(_Request):
    """Reconstruct a scan job's file or an uploaded dataset (exactly one of them); with
    ``unmix``: every wavelength of a multi-wavelength scan job, or one uploaded dataset
    per wavelength (``dataset_ids`` with ``wavelengths``), then HbO2/Hb unmixing.

    Attributes
    ----------
    scan_job_id : str or None
        A scan job whose file to reconstruct; exclusive with dataset_id(s).
    dataset_id : str or None
        An uploaded dataset to reconstruct; exclusive with scan_job_id.
    dataset_ids : list of str or None
        One dataset per wavelength (1 to 16; with unmix only).
    wavelengths : list of float or None
        Excitation wavelength of each of dataset_ids, m.
    method : str or None
        Reconstruction method; absent or null: the default for the input
        (``fpscan.service.pipeline.default_method``). The request is a union keyed on it
        (:data:`ReconRequest`): each method's variant carries its own options.
    params : MethodOptions or dict
        The method's own options (its model, :data:`PARAMS_MODELS`; null: the method's
        default); without a method, a dict validated by the default method's model once the
        input is known.
    wavelength : int or "all" or None
        Excitation wavelength of a multi-wavelength input: an index (0 to 15), or ``"all"``
        (one volume per wavelength); absent: the first. Not with unmix.
    unmix : UnmixOptions or None
        Unmix HbO2/Hb after reconstructing every wavelength.
    plan_id : str or None
        With dataset_id (dense data): reconstruct the A-lines this stored plan's sensor mask
        picks out of it (``fpscan.service.subsample``: what a replay scan of the data records).

    Raises
    ------
    pydantic.ValidationError
        (a ValueError; 422 over HTTP) Not exactly one of scan_job_id, dataset_id and
        dataset_ids; dataset_ids without unmix; plan_id without dataset_id; a field out of its range.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, json_schema_extra={
        "oneOf": [{"required": ["scan_job_id"], "not": {"anyOf": [{"required": ["dataset_id"]},
                                                                  {"required": ["dataset_ids"]}]}},
                  {"required": ["dataset_id"], "not": {"anyOf": [{"required": ["scan_job_id"]},
                                                                 {"required": ["dataset_ids"]}]}},
                  {"required": ["dataset_ids", "wavelengths", "unmix"],
                   "not": {"anyOf": [{"required": ["scan_job_id"]}, {"required": ["dataset_id"]}]}}],
        "description": "Reconstruct a scan job's file or an uploaded dataset: exactly one of "
                       "scan_job_id and dataset_id; with unmix also dataset_ids (one per wavelength)."})

    scan_job_id: str | None = Field(None, pattern=ID_PATTERN, description="exclusive with dataset_id(s)")
    dataset_id: str | None = Field(None, pattern=ID_PATTERN, description="exclusive with scan_job_id")
    dataset_ids: list[Annotated[str, Field(pattern=ID_PATTERN)]] | None = Field(
        None, min_length=1, max_length=16, description="one dataset per wavelength (with unmix)")
    wavelengths: list[Annotated[float, Field(gt=0, allow_inf_nan=False)]] | None = Field(
        None, max_length=16, description="excitation wavelength of each of dataset_ids, m")
    method: str | None = None
    params: Any = None
    wavelength: Annotated[int, Field(ge=0, le=15)] | Literal["all"] | None = Field(
        None, description="excitation wavelength of a multi-wavelength input: an index into its wavelengths, or "
                          "'all' (one volume per wavelength, same method and options; download each with "
                          "volume.h5?wavelength=k). Absent: the first (index 0), recorded in the result's params "
                          "(wavelength_index, wavelength_nm). Not with unmix (it uses every wavelength)")
    unmix: UnmixOptions | None = Field(None, description="unmix HbO2/Hb after reconstructing every wavelength")
    plan_id: str | None = Field(None, pattern=ID_PATTERN, description=(
        "with dataset_id (dense data: a sensor plane or line, or a full-lattice scan): reconstruct the A-lines "
        "this stored plan's sensor mask picks out of it, as a replay scan of the data records them "
        "(fpscan.subsample); the plan's lattice pitch and dt must be the data's, its lattice centred on the data's grid"))

    @model_validator(mode="after")
    def _exactly_one_input(self) -> ReconRequestBase:
        given = [self.scan_job_id is not None, self.dataset_id is not None, self.dataset_ids is not None]
        if sum(given) != 1:
            raise ValueError("give exactly one of scan_job_id or dataset_id (or dataset_ids with unmix)")
        if self.dataset_ids is not None and self.unmix is None:
            raise ValueError("dataset_ids (one dataset per wavelength) need unmix")
        if self.plan_id is not None and (self.dataset_id is None or self.unmix is not None):
            raise ValueError("plan_id samples an uploaded dataset: it needs dataset_id (and no unmix)")
        return self


#: the discriminator's tag of a request that names no method (its params wait for the input's default method)
DEFAULT_METHOD_TAG = "default-method"


class ReconRequestDefaultMethod(ReconRequestBase):
    """A reconstruction request that names no method: the input's default
    (``fpscan.service.pipeline.default_method``) is chosen once the input is known, and ``params``
    are then validated by that method's model (:data:`PARAMS_MODELS`), once."""

    method: ReconMethod | None = Field(  # type: ignore[valid-type]
        None, description="reconstruction method; absent or null: the default for the input "
                          f"(fpscan.service.pipeline.default_method: {_methods.default_for('grid')} for grid data, "
                          f"{_methods.default_for('points')} for sensor points)")
    params: dict[str, Any] = Field(default_factory=dict, description="the options of the input's default method")


def _request_model(name: str) -> type[ReconRequestBase]:
    """The request variant of method ``name``: ``method`` the literal name, ``params`` its own options."""
    params = PARAMS_MODELS[name]
    title = params.__name__.removesuffix("Options")
    return create_model(f"ReconRequest{title}", __base__=ReconRequestBase, __module__=__name__,
                        __doc__=f"A reconstruction request with method {name!r} and its own options.",
                        method=(Literal[name], Field(description=f"reconstruction method: {METHODS[name].title}")),
                        params=(params, Field(default_factory=params,
                                              description=f"the options of {name} (null: its default)")))


#: each method's request variant, by name (:func:`_request_model`)
REQUEST_MODELS: dict[str, type[ReconRequestBase]] = {name: _request_model(name) for name in METHODS}


def _method_tag(value: Any) -> str:
    """The variant of a request body: its method's, else :data:`DEFAULT_METHOD_TAG` (no method, or
    an unknown one, which that variant refuses naming the methods)."""
    method = value.get("method") if isinstance(value, dict) else getattr(value, "method", None)
    return method if isinstance(method, str) and method in REQUEST_MODELS else DEFAULT_METHOD_TAG


#: ``POST /api/reconstructions``' body: a union of :data:`REQUEST_MODELS` keyed on ``method``
#: (pydantic's discriminated union by a callable discriminator, which FastAPI documents as ``oneOf``),
#: and :class:`ReconRequestDefaultMethod` for a request without a method. A request's ``params``
#: are thus its method's own options model from the method registry, validated once, at the door.
if TYPE_CHECKING:
    ReconRequest = ReconRequestBase
else:
    _VARIANTS = tuple(Annotated[model, Tag(name)] for name, model in REQUEST_MODELS.items()) + \
        (Annotated[ReconRequestDefaultMethod, Tag(DEFAULT_METHOD_TAG)],)
    ReconRequest = Annotated[Union.__getitem__(_VARIANTS), Discriminator(_method_tag)]
