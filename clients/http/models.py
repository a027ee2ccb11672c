"""The client's own view of the API responses it parses (pydantic; no server imports).

These mirror the response models of ``docs/api.md`` (the server's ``service.api.models``)
but are lenient, so a client keeps working against a slightly newer or older server:
unknown fields are kept (``extra="allow"``), states and kinds are plain strings, and
fields a server may omit have defaults. A response that does not fit is returned as the
raw JSON (see :func:`clients.http.client.as_model`). Units are SI (m, s, Hz).
"""
from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["Plan", "PlanPreview", "Progress", "Timings", "Job", "Scanner", "PreviewInfo", "MODELS"]


class _Response(BaseModel):
    model_config = ConfigDict(extra="allow")


class Plan(_Response):
    """Summary of a stored plan (``GET /api/plans/{id}``)."""

    id: str
    kind: str
    n_points: int
    requested_points: int | None = None
    shortfall: str | None = None  # why the plan has fewer points than asked
    weight_ratio: float | None = None
    expected_scan_time_s: float | None = None
    lattice: dict[str, Any] = Field(default_factory=dict)
    acquisition: dict[str, Any] = Field(default_factory=dict)
    links: dict[str, str] = Field(default_factory=dict)


class PlanPreview(_Response):
    """A mask preview computed without storing a plan (``POST /api/plans/preview``)."""

    points: int
    weight_ratio: float | None = None
    expected_scan_time_s: float | None = None
    preview_png_base64: str | None = None


class Progress(_Response):
    """A job's progress: ``fraction`` in [0, 1], ``stage``, scan counters and ETA (s)."""

    fraction: float = 0.0
    stage: str = "queued"
    points_done: int | None = None
    points_total: int | None = None
    alines_done: int | None = None
    alines_total: int | None = None
    rate_per_s: float | None = None
    eta_s: float | None = None
    faults_recovered: int | None = None
    reason: str | None = Field(None, description="why a job is paused with stage interrupted (lost device, "
                               "full disk), one line; cleared when it resumes")


class Timings(_Response):
    """UNIX times of a job's creation, start and end, and its queue/run durations (s)."""

    created: float | None = None
    started: float | None = None
    finished: float | None = None
    queued_s: float | None = None
    run_s: float | None = None


class Job(_Response):
    """A job (``GET /api/jobs/{id}``)."""

    id: str
    kind: str
    state: str
    progress: Progress = Field(default_factory=Progress)
    timings: Timings = Field(default_factory=Timings)
    params: dict[str, Any] = Field(default_factory=dict)
    links: dict[str, str] = Field(default_factory=dict)
    attempts: int = 0
    error: str | None = None


class Scanner(_Response):
    """A configured scanner (``GET /api/scanners``)."""

    id: str
    port: str | None = None
    status: str = "unknown"
    job_id: str | None = None
    identity: str | None = None


class PreviewInfo(_Response):
    """The live preview's state: version, points used, last refresh (UNIX time, s), the
    index of the wavelength it shows."""

    version: int
    points_used: int
    updated: float | None = None
    refresh_s: float | None = None
    wavelength_index: int | None = None


MODELS: dict[str, type[BaseModel]] = {
    m.__name__: m for m in (Plan, PlanPreview, Progress, Timings, Job, Scanner, PreviewInfo)
}
