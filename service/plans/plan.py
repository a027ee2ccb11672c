"""Scan plans: an ordered mask plus acquisition settings, identified by a content hash.

The JSON form is fixed by docs/architecture.md ("Plan JSON", format ``fpscan-plan/1``).
The plan contract itself — canonical JSON, the content hash (the id) and the checks every
plan must pass — is owned by ``fpscan.driver.plan`` (the lowest layer: the scanner side reads the
same JSON without importing ``service``); this module builds plans (``make_plan``: the one
plan builder for every mask kind, user point lists included) and gives them a typed model.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

from fpscan.constants import C_DEFAULT, C_LIMITS
from fpscan.driver.plan import (
    MAX_AVERAGES,
    MAX_DT,
    MAX_N_T,
    MAX_PRF,
    MAX_WAVELENGTHS,
    MIN_N_T,
    PLAN_FORMAT,
    canonical_json,
    check_acquisition,
    check_plan,
    check_wavelengths,
    plan_id_of,
)
from fpscan.service.plans.kinds import make_mask, resolve_kind
from fpscan.service.plans.lattice import Lattice
from fpscan.service.plans.mask import Mask, weight_ratio
from fpscan.service.plans.ordering import ORDERS, auto_order, scan_order
from fpscan.wire.brief import fields_repr, html_table, one_line

if TYPE_CHECKING:
    import h5py

__all__ = ["PLAN_FORMAT", "Plan", "Acquisition", "make_plan", "plan_from_spec", "canonical_json", "content_id",
           "ORDER_NAMES", "LatticeSpec", "MaskSpec", "Points", "check_plausible_request"]

#: Scan order names ``make_plan`` takes (``auto``: rings for ring-structured masks,
#: serpentine otherwise); a plan records the resolved one.
ORDER_NAMES = ("auto", *ORDERS)


def content_id(plan_dict: dict) -> str:
    """The plan's content hash (its id): ``fpscan.driver.plan.plan_id_of``.

    Parameters
    ----------
    plan_dict : dict
        A plan as JSON-safe dict (``Plan.to_dict()``); its ``id`` is ignored.

    Returns
    -------
    str
        SHA-256 hex digest of the canonical JSON of everything but ``id``.

    Raises
    ------
    ValueError
        Not a dict, or values JSON cannot represent.

    Examples
    --------
    >>> from fpscan.service.plans import content_id, make_plan
    >>> plan = make_plan("full", lattice={"n_x": 3, "n_y": 1, "pitch": 1e-4})
    >>> content_id(plan.to_dict()) == plan.id
    True
    >>> len(plan.id)
    64
    """
    return plan_id_of(plan_dict)


def _finite(name: str, v: float) -> float:
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {v}")
    return v


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    def __repr__(self) -> str:  # one line, lists and dicts by their sizes (fpscan.wire.brief)
        return fields_repr(type(self).__name__, self, skip_none=False)


class LatticeSpec(_Strict):
    """The plan's lattice, as its JSON holds it (see ``Lattice``).

    Attributes
    ----------
    n_x, n_y : int
        Points along x and y, >= 1.
    pitch : float
        m, > 0 and finite.

    Raises
    ------
    pydantic.ValidationError
        (a ValueError) for bad values.

    Examples
    --------
    >>> from fpscan.service.plans.plan import LatticeSpec
    >>> LatticeSpec(n_x=226, n_y=226, pitch=6e-5)
    LatticeSpec(n_x=226, n_y=226, pitch=6e-05)
    >>> LatticeSpec(n_x=0, n_y=1, pitch=1e-4)
    Traceback (most recent call last):
    ...
    pydantic_core._pydantic_core.ValidationError: 1 validation error for LatticeSpec
    n_x
      Input should be greater than or equal to 1 ...
    """

    n_x: int = Field(ge=1)
    n_y: int = Field(ge=1)
    pitch: float = Field(gt=0, description="m")

    @field_validator("pitch")
    @classmethod
    def _pitch(cls, v: float) -> float:
        return _finite("pitch", v)


class MaskSpec(_Strict):
    """The plan's mask summary, as its JSON holds it.

    Attributes
    ----------
    kind : str
        The mask kind.
    params : dict
        The parameters it was made from (SI units).
    requested_points, obtained_points : int
        Points asked for and held, >= 1.
    weight_ratio : float or None
        Outer/inner weight ratio (``weight_ratio``), > 0.

    Examples
    --------
    >>> from fpscan.service.plans import make_plan
    >>> plan = make_plan("equispaced", lattice={"n_x": 9, "n_y": 9, "pitch": 1e-4}, params={"interval": 4})
    >>> plan.mask
    MaskSpec(kind='equispaced', params={'interval': 4, 'n_per_side': [3, 3]}, requested_points=9, obtained_points=9, weight_ratio=1.0)
    >>> plan.mask.obtained_points == plan.n_points
    True
    """

    kind: str
    params: dict[str, Any] = Field(default_factory=dict)
    requested_points: int = Field(ge=1)
    obtained_points: int = Field(ge=1)
    weight_ratio: float | None = Field(default=None, gt=0, allow_inf_nan=False)


class Points(_Strict):
    """The plan's points in scan order.

    Their checks (shapes, lattice membership, finite positions, weights) are the plan
    contract's, ``fpscan.driver.plan.check_plan``, run by :class:`Plan`.

    Attributes
    ----------
    indices : list of (int, int)
        Lattice indices (i_x, i_y), n of them.
    positions : list of (float, float)
        Positions (x, y), m.
    weights : list of float
        Quadrature weights, m² (m on a line lattice).

    Examples
    --------
    >>> from fpscan.service.plans import make_plan
    >>> plan = make_plan("full", lattice={"n_x": 3, "n_y": 1, "pitch": 1e-4})
    >>> plan.points.indices
    [(0, 0), (1, 0), (2, 0)]
    >>> [round(w, 12) for w in plan.points.weights]  # m on a line lattice
    [0.0001, 0.0001, 0.0001]
    """

    indices: list[tuple[int, int]]
    positions: list[tuple[float, float]] = Field(description="(x, y) in m")
    weights: list[float] = Field(description="m² (m on a line lattice)")


class Acquisition(_Strict):
    """Acquisition settings of a plan.

    The limits are the plan contract's, checked by ``fpscan.driver.plan.check_acquisition`` (the
    scanner side's check: one set of limits for the library, the API and the scanner); the
    JSON schema states the same numbers (``fpscan.driver.plan``'s constants).

    Attributes
    ----------
    n_t : int
        Samples per A-line (default 1024).
    dt : float
        Sample interval, s (default 8 ns).
    averages : int
        Pulses averaged per point and wavelength (default 1).
    wavelengths : list of float
        Excitation wavelengths, m (400 nm to 2000 nm, no repeats; default [750 nm]).
    prf : float
        Laser pulse repetition frequency, Hz (0 = as fast as the scanner can; default 50).
    sound_speed : float
        Speed of sound, m/s (default 1500).
    wavelength_order : {"per_point", "per_pass"} or None
        With several wavelengths, tune the laser at every point (default) or once per pass;
        left out of the JSON when not set.

    Raises
    ------
    pydantic.ValidationError
        (a ValueError) with the driver's reason.

    Examples
    --------
    >>> from fpscan.service.plans import Acquisition
    >>> Acquisition(n_t=2048, dt=4e-9, wavelengths=[5.32e-7, 7.5e-7])
    Acquisition(n_t=2048, dt=4e-09, averages=1, wavelengths=[5.32e-07, 7.5e-07], prf=50.0, sound_speed=1500.0, wavelength_order=None)
    >>> Acquisition(dt=-1)
    Traceback (most recent call last):
    ...
    pydantic_core._pydantic_core.ValidationError: 1 validation error for Acquisition
      Value error, plan acquisition.dt must be finite and > 0 s, got -1.0 ...
    """

    n_t: int = Field(default=1024, description="samples per A-line",
                     json_schema_extra={"minimum": MIN_N_T, "maximum": MAX_N_T})
    dt: float = Field(default=8e-9, description="sample interval, s",
                      json_schema_extra={"unit": "s", "display_unit": "ns", "exclusiveMinimum": 0,
                                         "maximum": MAX_DT})
    averages: int = Field(default=1, description="pulses averaged per point",
                          json_schema_extra={"minimum": 1, "maximum": MAX_AVERAGES})
    wavelengths: list[float] = Field(default_factory=lambda: [7.5e-7],
                                     description="excitation wavelengths, m (400 nm to 2000 nm, no repeats)",
                                     json_schema_extra={"unit": "m", "display_unit": "nm", "minItems": 1,
                                                        "maxItems": MAX_WAVELENGTHS})
    prf: float = Field(default=50.0, description="pulse repetition frequency, Hz (0 = as fast as possible)",
                       json_schema_extra={"unit": "Hz", "display_unit": "Hz", "minimum": 0, "maximum": MAX_PRF})
    sound_speed: float = Field(default=C_DEFAULT, description="speed of sound, m/s",
                               json_schema_extra={"unit": "m/s", "display_unit": "m/s",
                                                  "exclusiveMinimum": C_LIMITS[0], "maximum": C_LIMITS[1]})
    #: several wavelengths: tune the laser at every point ("per_point", the default when
    #: absent) or once per full pass ("per_pass"); docs/protocol.md §4.1. Left out of the
    #: JSON when not set, so plans without it keep their ids.
    wavelength_order: Literal["per_point", "per_pass"] | None = Field(
        default=None, exclude_if=lambda v: v is None,
        description="per_point (default) or per_pass: when the laser is tuned between wavelengths")

    @field_validator("wavelengths")
    @classmethod
    def _wl(cls, v: Any) -> list[float]:
        return check_wavelengths(v)

    @model_validator(mode="after")
    def _contract(self) -> Acquisition:
        check_acquisition(self.model_dump())  # the plan contract's limits (NaN kept: not mode="json")
        return self


class Plan(_Strict):
    """A scan plan (architecture.md "Plan JSON"): an ordered mask plus acquisition settings.

    ``points`` are in scan order: point index k in the scanner protocol and the scan file is
    the k-th entry. Made by ``make_plan`` / ``plan_from_spec``; read by ``from_json``,
    ``from_dict``, ``from_hdf5``; written by ``to_json``, ``to_dict``, ``to_hdf5``.

    Attributes
    ----------
    format : str
        ``"fpscan-plan/1"``.
    id : str
        The content hash (``content_id``).
    lattice : LatticeSpec
    mask : MaskSpec
    points : Points
        In scan order.
    order : str
        The scan order the points are in (serpentine, rings, nearest, given).
    acquisition : Acquisition
    n_points : int
        Number of points.
    lattice_obj : Lattice
        The lattice as a ``Lattice``.
    expected_scan_time_s : float or None
        Points × averages × wavelengths / PRF, s; None when prf = 0.

    Raises
    ------
    ValueError
        (pydantic.ValidationError) wrong format, ``id`` not the content hash, indices outside
        the lattice or duplicated, positions not the lattice positions of the indices, count
        mismatches, non-finite or non-positive values.

    Examples
    --------
    >>> from fpscan.service.plans import Plan, make_plan
    >>> plan = make_plan("equispaced", lattice={"n_x": 9, "n_y": 9, "pitch": 1e-4}, params={"interval": 4})
    >>> plan.n_points, plan.order, plan.expected_scan_time_s  # 9 points at 50 Hz
    (9, 'serpentine', 0.18)
    >>> plan.positions_array().shape, plan.weights_array()[0]  # (x, y) in m; (0.4 mm)²
    ((9, 2), np.float64(1.6e-07))
    >>> Plan.from_json(plan.to_json()).id == plan.id
    True
    >>> Plan.from_dict({**plan.to_dict(), "id": "0" * 64})
    Traceback (most recent call last):
    ...
    pydantic_core._pydantic_core.ValidationError: 1 validation error for Plan
    ...
    """

    format: Literal["fpscan-plan/1"] = PLAN_FORMAT
    id: str
    lattice: LatticeSpec
    mask: MaskSpec
    points: Points
    order: str = Field(description="the scan order the points are in (serpentine, rings, nearest, given)")
    acquisition: Acquisition

    @model_validator(mode="after")
    def _consistent(self, info: ValidationInfo) -> Plan:
        n = len(self.points.indices)
        if self.mask.obtained_points != n:
            raise ValueError(f"mask.obtained_points = {self.mask.obtained_points} but the plan has {n} points")
        d = self.model_dump(mode="json")
        if info.context and info.context.get("assign_id") and self.id == "":
            object.__setattr__(self, "id", plan_id_of(d))  # make_plan: the id is computed here once
            d["id"] = self.id
        check_plan(d)  # the plan contract: lattice membership, duplicates, positions, the id
        ratio, w = self.mask.weight_ratio, self.points.weights
        if ratio is not None:  # a ratio of means of weights (> 0): within their spread
            spread = max(w) / min(w)
            if not (1 - 1e-9) / spread <= ratio <= spread * (1 + 1e-9):
                raise ValueError(f"mask.weight_ratio {ratio:g} is outside the range of the plan's weights "
                                 f"({1 / spread:g} to {spread:g})")
        return self

    # -- arrays ---------------------------------------------------------------------
    def __repr__(self) -> str:
        """One line: the id's start, the mask kind, points (of those asked) on the lattice, the
        order and the acquisition (never the points or weights).

        Examples
        --------
        >>> from fpscan.service.plans import Lattice, full_mask, make_plan
        >>> make_plan(full_mask(Lattice(3, 3, 1e-4)))  # doctest: +ELLIPSIS
        Plan(...: full, 9 of 9 points on 3x3 at 100 µm, serpentine, n_t 1024 x dt 8 ns, 1 wavelength)
        """
        lat, acq, n_wl = self.lattice, self.acquisition, len(self.acquisition.wavelengths)
        return one_line(f"Plan({self.id[:12]}: {self.mask.kind}, {self.n_points} of {self.mask.requested_points} points "
                        f"on {lat.n_x}x{lat.n_y} at {lat.pitch * 1e6:.4g} µm, {self.order}, n_t {acq.n_t} x dt "
                        f"{acq.dt * 1e9:.4g} ns, {n_wl} wavelength{'s' if n_wl != 1 else ''})")

    def _repr_html_(self) -> str:
        """A table for notebooks: id, mask, lattice, order, acquisition and the expected scan time."""
        lat, acq = self.lattice, self.acquisition
        return html_table(f"Plan {self.id}", [
            ("mask", f"{self.mask.kind}: {self.n_points} of {self.mask.requested_points} points"),
            ("lattice", f"{lat.n_x}x{lat.n_y} at {lat.pitch * 1e6:.4g} µm"), ("order", self.order),
            ("weight ratio", self.mask.weight_ratio), ("n_t", acq.n_t), ("dt", f"{acq.dt * 1e9:.4g} ns"),
            ("averages", acq.averages), ("wavelengths (nm)", ", ".join(f"{w * 1e9:g}" for w in acq.wavelengths)),
            ("PRF", f"{acq.prf:g} Hz"), ("sound speed", f"{acq.sound_speed:g} m/s"),
            ("expected scan time", f"{t:.3g} s" if (t := self.expected_scan_time_s) is not None else None)])

    @property
    def n_points(self) -> int:
        return len(self.points.indices)

    @property
    def lattice_obj(self) -> Lattice:
        return Lattice(self.lattice.n_x, self.lattice.n_y, self.lattice.pitch)

    def indices_array(self) -> np.ndarray:
        """Lattice indices in scan order.

        Returns
        -------
        ndarray of int64, shape ``(n, 2)``
            (i_x, i_y).

        Examples
        --------
        >>> from fpscan.service.plans import make_plan
        >>> make_plan("full", lattice={"n_x": 3, "n_y": 1, "pitch": 1e-4}).indices_array().tolist()
        [[0, 0], [1, 0], [2, 0]]
        """
        return np.asarray(self.points.indices, dtype=np.int64).reshape(-1, 2)

    def positions_array(self) -> np.ndarray:
        """Positions in scan order.

        Returns
        -------
        ndarray, shape ``(n, 2)``
            (x, y), m.

        Examples
        --------
        >>> from fpscan.service.plans import make_plan
        >>> make_plan("full", lattice={"n_x": 3, "n_y": 1, "pitch": 1e-4}).positions_array().shape
        (3, 2)
        """
        return np.asarray(self.points.positions, dtype=np.float64).reshape(-1, 2)

    def weights_array(self) -> np.ndarray:
        """Quadrature weights in scan order.

        Returns
        -------
        ndarray, shape ``(n,)``
            m² (m on a line lattice).

        Examples
        --------
        >>> from fpscan.service.plans import make_plan
        >>> make_plan("full", lattice={"n_x": 3, "n_y": 3, "pitch": 1e-4}).weights_array().shape
        (9,)
        """
        return np.asarray(self.points.weights, dtype=np.float64)

    def recon_positions(self) -> np.ndarray:
        """The positions in the form ``fpscan.service.recon`` takes them.

        Returns
        -------
        ndarray, shape ``(n, 1)`` (line lattice: x) or ``(n, 2)`` ((x, y))
            m, in scan order.

        Examples
        --------
        >>> from fpscan.service.plans import make_plan
        >>> make_plan("full", lattice={"n_x": 3, "n_y": 1, "pitch": 1e-4}).recon_positions().ravel().tolist()
        [-0.0001, 0.0, 0.0001]
        """
        pos = self.positions_array()
        return pos[:, :1].copy() if self.lattice.n_y == 1 else pos

    @property
    def expected_scan_time_s(self) -> float | None:
        """Points × averages × wavelengths / PRF in s; None when prf = 0 (unthrottled: the
        scanner's own pulse rate decides, the plan cannot say)."""
        a = self.acquisition
        if a.prf == 0:
            return None
        return self.n_points * a.averages * len(a.wavelengths) / a.prf

    # -- JSON -------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The plan as JSON-safe dict (``Plan JSON`` of docs/architecture.md).

        Returns
        -------
        dict

        Examples
        --------
        >>> from fpscan.service.plans import make_plan
        >>> d = make_plan("full", lattice={"n_x": 3, "n_y": 1, "pitch": 1e-4}).to_dict()
        >>> sorted(d)
        ['acquisition', 'format', 'id', 'lattice', 'mask', 'order', 'points']
        """
        return self.model_dump(mode="json")

    def to_json(self, path: str | Path | None = None, *, indent: int | None = None) -> str:
        """The plan as JSON text.

        Parameters
        ----------
        path : str or Path, optional
            Also write it there (with a final newline).
        indent : int, optional
            Indent (keys sorted); None (default): the canonical form (``canonical_json``).

        Returns
        -------
        str

        Examples
        --------
        >>> from fpscan.service.plans import make_plan
        >>> text = make_plan("full", lattice={"n_x": 3, "n_y": 1, "pitch": 1e-4}).to_json()
        >>> text[:30]
        '{"acquisition":{"averages":1,"'
        """
        d = self.to_dict()
        text = canonical_json(d) if indent is None else json.dumps(d, indent=indent, sort_keys=True)
        if path is not None:
            Path(path).write_text(text + "\n", encoding="utf-8")
        return text

    @classmethod
    def from_dict(cls, d: dict) -> Plan:
        """Read a plan from its dict; validates it (including the id).

        Parameters
        ----------
        d : dict
            The plan JSON as dict.

        Returns
        -------
        Plan

        Raises
        ------
        ValueError
            Not a dict, or any rule of the plan contract broken (pydantic.ValidationError).

        Examples
        --------
        >>> from fpscan.service.plans import Plan, make_plan
        >>> plan = make_plan("full", lattice={"n_x": 3, "n_y": 1, "pitch": 1e-4})
        >>> Plan.from_dict(plan.to_dict()) == plan
        True
        >>> Plan.from_dict([1])
        Traceback (most recent call last):
        ...
        ValueError: a plan must be a JSON object, got list
        """
        if not isinstance(d, dict):
            raise ValueError(f"a plan must be a JSON object, got {type(d).__name__}")
        return cls.model_validate(d)

    @classmethod
    def from_json(cls, text_or_path: str | Path) -> Plan:
        """Read a plan from JSON text or a file path; validates it (including the id).

        Parameters
        ----------
        text_or_path : str or Path
            JSON text (starting with ``{``) or the path of a file holding it.

        Returns
        -------
        Plan

        Raises
        ------
        ValueError
            Not valid JSON, or any rule of the plan contract broken.
        OSError
            A path that cannot be read.

        Examples
        --------
        >>> from fpscan.service.plans import Plan, make_plan
        >>> plan = make_plan("full", lattice={"n_x": 3, "n_y": 1, "pitch": 1e-4})
        >>> Plan.from_json(plan.to_json(indent=2)).id == plan.id
        True
        >>> Plan.from_json("{not json")
        Traceback (most recent call last):
        ...
        ValueError: plan is not valid JSON: ...
        """
        if isinstance(text_or_path, Path) or (
            isinstance(text_or_path, str) and not text_or_path.lstrip().startswith("{")
        ):
            text = Path(text_or_path).read_text(encoding="utf-8")
        else:
            text = text_or_path
        try:
            d = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"plan is not valid JSON: {exc}") from None
        return cls.from_dict(d)

    # -- HDF5 ---------------------------------------------------------------------------
    def to_hdf5(self, group: h5py.Group) -> None:
        """Write the plan into an h5py group.

        Attributes ``format``, ``id``, ``order``, ``lattice``, ``mask``, ``acquisition`` (the last
        three as canonical JSON text) and datasets ``indices`` (n, 2) int64, ``positions`` (n, 2)
        float64 in m, ``weights`` (n,) float64 in m² (m on a line lattice).

        Parameters
        ----------
        group : h5py.Group
            An empty group (or file) open for writing.

        Examples
        --------
        >>> import h5py
        >>> from fpscan.service.plans import make_plan
        >>> plan = make_plan("full", lattice={"n_x": 3, "n_y": 1, "pitch": 1e-4})
        >>> with h5py.File("plan.h5", "w", driver="core", backing_store=False) as f:  # in memory
        ...     plan.to_hdf5(f.create_group("plan"))
        ...     sorted(f["plan"]), f["plan/positions"].shape
        (['indices', 'positions', 'weights'], (3, 2))
        """
        group.attrs["format"] = self.format
        group.attrs["id"] = self.id
        group.attrs["order"] = self.order
        for key in ("lattice", "mask", "acquisition"):
            group.attrs[key] = canonical_json(getattr(self, key).model_dump(mode="json"))
        group.create_dataset("indices", data=self.indices_array())
        group.create_dataset("positions", data=self.positions_array())
        group.create_dataset("weights", data=self.weights_array())

    @classmethod
    def from_hdf5(cls, group: h5py.Group) -> Plan:
        """Read a plan written by ``to_hdf5``; validates it (including the id).

        Parameters
        ----------
        group : h5py.Group

        Returns
        -------
        Plan

        Raises
        ------
        ValueError
            A group without a complete plan (naming what is missing), or a plan that breaks the
            contract.

        Examples
        --------
        >>> import h5py
        >>> from fpscan.service.plans import Plan, make_plan
        >>> plan = make_plan("full", lattice={"n_x": 3, "n_y": 1, "pitch": 1e-4})
        >>> with h5py.File("plan.h5", "w", driver="core", backing_store=False) as f:
        ...     plan.to_hdf5(f.create_group("plan"))
        ...     Plan.from_hdf5(f["plan"]).id == plan.id
        True
        """

        def _s(v: bytes | str) -> str:
            return v.decode("utf-8") if isinstance(v, bytes) else str(v)

        try:
            d = {
                "format": _s(group.attrs["format"]),
                "id": _s(group.attrs["id"]),
                "order": _s(group.attrs["order"]),
                "lattice": json.loads(_s(group.attrs["lattice"])),
                "mask": json.loads(_s(group.attrs["mask"])),
                "acquisition": json.loads(_s(group.attrs["acquisition"])),
                "points": {
                    "indices": np.asarray(group["indices"][()]).astype(np.int64).tolist(),
                    "positions": np.asarray(group["positions"][()]).astype(np.float64).tolist(),
                    "weights": np.asarray(group["weights"][()]).astype(np.float64).tolist(),
                },
            }
        except KeyError as exc:
            raise ValueError(f"HDF5 group holds no complete plan: missing {exc}") from None
        return cls.from_dict(d)


def _json_safe(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj)
    if obj is None or isinstance(obj, str):
        return obj
    raise ValueError(f"parameter value {obj!r} is not JSON-serialisable")


def check_plausible_request(mask: Mask | None, kind: str | None, lattice: dict | Lattice | None, params: dict | None,
                            acquisition: Acquisition | dict | None, *, force: bool = False) -> None:
    """The plausibility rules of ``fpscan.driver.units.check_plausible`` on a plan request.

    Judged: the lattice pitch, dt, the PRF against the recording, the sound speed (unless
    ``force``) and the depth of the point of interest of the equiangular/equi-steradian kinds.
    Run before any range check, so that a unit mistake is named as such.

    Parameters
    ----------
    mask : Mask or None
        A mask (its lattice, kind and params are used), or None with ``kind``, ``lattice``
        and ``params``.
    kind : str or None
        Mask kind name.
    lattice : dict or Lattice or None
        ``n_x``, ``n_y``, ``pitch`` (m).
    params : dict or None
        The kind's parameters (SI units).
    acquisition : Acquisition or dict or None
        The acquisition settings (SI units); missing ones take the defaults.
    force : bool, optional
        Skip the sound-speed rule.

    Raises
    ------
    fpscan.driver.units.ImplausibleValue
        (a ValueError) naming the implausible value and the likely unit mistake.

    Examples
    --------
    >>> from fpscan.service.plans import check_plausible_request
    >>> check_plausible_request(None, "full", {"n_x": 9, "n_y": 9, "pitch": 6e-5}, {}, {"dt": 8e-9})
    >>> check_plausible_request(None, "full", {"n_x": 9, "n_y": 9, "pitch": 60}, {}, {})
    Traceback (most recent call last):
    ...
    fpscan.driver.units.ImplausibleValue: pitch 60 m is implausible for a planar FP scanner ... did you mean 60 µm (60um)? ...
    """
    from fpscan.driver.units import check_plausible

    if acquisition is None:
        acquisition = {}
    if not isinstance(acquisition, dict):
        acquisition = acquisition.model_dump()
    defaults = {k: f.default for k, f in Acquisition.model_fields.items()}
    acq = {**defaults, **acquisition}  # the raw values: a unit mistake is named before any range check

    pitch: Any
    if mask is not None and isinstance(mask, Mask):
        pitch, kind, params = mask.lattice.pitch, mask.kind, mask.params or {}
    else:
        pitch = lattice.get("pitch") if isinstance(lattice, dict) else getattr(lattice, "pitch", None)
    try:
        poi = resolve_kind(kind).poi_depth
    except ValueError:  # an unknown kind is named by make_mask
        poi = False
    depth = params.get("depth") if isinstance(params, dict) and poi else None
    num = (int, float)

    def value(v: Any) -> float | None:
        return float(v) if isinstance(v, num) and not isinstance(v, bool) else None

    n_t = acq.get("n_t")
    check_plausible(pitch=value(pitch), dt=value(acq.get("dt")),
                    n_t=int(n_t) if isinstance(n_t, int) and not isinstance(n_t, bool) else None,
                    prf=value(acq.get("prf")), sound_speed=value(acq.get("sound_speed")),
                    depth=value(depth), force=force)


def make_plan(mask: Mask | str | None = None, *, kind: str | None = None, lattice: Lattice | dict | None = None,
              params: dict | None = None, order: str = "auto",
              acquisition: Acquisition | dict | None = None, force: bool = False, **settings: Any) -> Plan:
    """A plan: a mask's points put in scan order, with acquisition settings.

    The mask is either given (``make_plan(mask)``) or made here from a kind name
    (``make_plan("equisteradian", lattice=..., params={...})`` or
    ``make_plan(kind=..., lattice=..., params=...)``, see ``make_mask``).
    ``mask.weight_ratio`` is ``fpscan.service.plans.weight_ratio`` (outer/inner, paper §6) for every
    kind, point lists included. Values a person types are checked for plausibility first
    (``fpscan.driver.units.check_plausible``: pitch, dt, the point of interest's depth, the PRF
    against the recording, the sound speed unless ``force``).

    Parameters
    ----------
    mask : Mask or str, optional
        A mask, or a kind name (then ``lattice`` and ``params`` make it).
    kind : str, optional
        Mask kind name (instead of a positional one).
    lattice : Lattice or dict, optional
        The scanner lattice (``n_x``, ``n_y``, ``pitch`` in m) when the mask is made here.
    params : dict, optional
        The kind's parameters, SI units.
    order : str, optional
        ``auto`` (default: rings for equi-steradian, given for point lists, serpentine
        otherwise), ``serpentine``, ``rings``, ``nearest`` or ``given``.
    acquisition : Acquisition or dict, optional
        Acquisition settings; or give them as keywords.
    force : bool, optional
        Skip the sound-speed plausibility rule.
    **settings
        n_t, dt (s), averages, wavelengths (m), prf (Hz), sound_speed (m/s); defaults 1024,
        8 ns, 1, [750 nm], 50 Hz, 1500 m/s.

    Returns
    -------
    Plan
        With its id (the content hash) and the resolved order.

    Raises
    ------
    ValueError
        An unknown order (naming it), bad settings or bad mask parameters;
        ``fpscan.driver.units.ImplausibleValue`` (a ValueError) names a likely unit mistake.

    References
    ----------
    .. [1] J. Schmid et al., "Computational Realization of a Non-Equidistant Grid Sampling in
       Photoacoustics with a Non-Uniform FFT", §6 (the weight ratio).

    Examples
    --------
    >>> from fpscan.service.plans import Lattice, make_plan
    >>> plan = make_plan("equisteradian", lattice=Lattice(41, 41, 1e-4),
    ...                  params={"depth": 2e-3, "n_points": 50}, n_t=512, prf=100)
    >>> plan.n_points, plan.order, plan.acquisition.n_t
    (53, 'rings', 512)
    >>> make_plan("full", lattice={"n_x": 3, "n_y": 1, "pitch": 1e-4}, order="spiral")
    Traceback (most recent call last):
    ...
    ValueError: unknown order 'spiral'; known: auto, serpentine, rings, nearest, given
    """
    order = order or "auto"
    if not isinstance(order, str) or order not in ORDER_NAMES:
        raise ValueError(f"unknown order {order!r}; known: {', '.join(ORDER_NAMES)}")
    if isinstance(mask, str):
        if kind is not None and kind != mask:
            raise ValueError("mask kind given twice")
        kind, mask = mask, None
    raw = {**acquisition, **settings} if isinstance(acquisition, dict) else \
        (acquisition if acquisition is not None else dict(settings))
    check_plausible_request(mask, kind, lattice, params, raw, force=force)  # before any range check
    if isinstance(acquisition, dict):
        acquisition = Acquisition(**{**acquisition, **settings})
        settings = {}
    if mask is None:
        if kind is None or lattice is None:
            raise ValueError("give a Mask, or a mask kind with a lattice (and params)")
        if params is not None and not isinstance(params, dict):
            raise ValueError("mask params must be an object")
        mask = make_mask(kind, lattice, **(params or {}))
    elif not isinstance(mask, Mask):
        raise ValueError(f"make_plan needs a Mask or a mask kind, got {type(mask).__name__}")
    elif kind is not None or params is not None:
        raise ValueError("give either a Mask or a kind with params, not both")
    if acquisition is None:
        acquisition = Acquisition(**settings)
    elif isinstance(acquisition, dict):
        acquisition = Acquisition(**{**acquisition, **settings})
    elif settings:
        raise ValueError("give acquisition settings either as acquisition=... or as keywords, not both")
    perm = scan_order(mask, order)
    resolved = order if order != "auto" else auto_order(mask)
    idx = mask.indices[perm]
    pos = mask.positions[perm]
    w = mask.weights[perm]
    body = {
        "format": PLAN_FORMAT,
        "lattice": mask.lattice.to_dict(),
        "mask": {
            "kind": mask.kind,
            "params": _json_safe(mask.params),
            "requested_points": int(mask.requested_points),
            "obtained_points": int(mask.obtained_points),
            "weight_ratio": float(weight_ratio(pos, w, mask.centre)),
        },
        "points": {
            "indices": idx.tolist(),
            "positions": pos.tolist(),
            "weights": w.tolist(),
        },
        "order": resolved,
        "acquisition": acquisition.model_dump(mode="json"),
    }
    body["id"] = ""
    return Plan.model_validate(body, context={"assign_id": True})


def plan_from_spec(spec: dict) -> Plan:
    """A plan from a request body (HTTP layer, CLI).

    Parameters
    ----------
    spec : dict
        ``{"lattice": {"n_x", "n_y", "pitch"}, "mask": {"kind", "params"}, "order",
        "acquisition"}``; ``order`` and ``acquisition`` optional, SI units; ``mask`` may also
        be ``{"kind": "points", "params": {"points": [[x, y], ...]}}``.

    Returns
    -------
    Plan

    Raises
    ------
    ValueError
        With the reason, for anything missing or wrong.

    Examples
    --------
    >>> from fpscan.service.plans import plan_from_spec
    >>> plan = plan_from_spec({"lattice": {"n_x": 9, "n_y": 1, "pitch": 1e-4}, "mask": {"kind": "full"},
    ...                        "acquisition": {"n_t": 256, "prf": 100}})
    >>> plan.n_points, plan.recon_positions().shape, plan.expected_scan_time_s  # x in m; s
    (9, (9, 1), 0.09)
    >>> plan_from_spec({"mask": {"kind": "full"}})
    Traceback (most recent call last):
    ...
    ValueError: plan request needs 'lattice' and 'mask'
    """
    if not isinstance(spec, dict):
        raise ValueError("plan request must be a JSON object")
    unknown = set(spec) - {"lattice", "mask", "order", "acquisition"}
    if unknown:
        raise ValueError(f"unknown plan request field(s): {', '.join(sorted(unknown))}")
    if "lattice" not in spec or "mask" not in spec:
        raise ValueError("plan request needs 'lattice' and 'mask'")
    m = spec["mask"]
    if not isinstance(m, dict) or "kind" not in m:
        raise ValueError("'mask' must be an object with 'kind' and optional 'params'")
    params = m.get("params") or {}
    if not isinstance(params, dict):
        raise ValueError("'mask.params' must be an object")
    acq = spec.get("acquisition") or {}
    if not isinstance(acq, dict):
        raise ValueError("'acquisition' must be an object")
    return make_plan(kind=m["kind"], lattice=spec["lattice"], params=params,
                     order=spec.get("order") or "auto", acquisition=acq)
