"""The hostile-input suite as data: one row per case — the upload or request,
the expected status and a fragment of the reason. Files are built with h5py/numpy here,
from a real scan file written by ``fpscan.driver.scanfile``."""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from fpscan.driver.plan import plan_id_of
from fpscan.driver.scanfile import ScanFile

PITCH = 1e-4


@dataclass
class Upload:
    """``POST /api/datasets`` of the file ``make(folder)`` returns."""

    name: str
    fmt: str
    make: object
    status: int
    reason: str
    form: dict = field(default_factory=dict)


def small_plan(n_x: int = 6, n_y: int = 5, n_t: int = 64) -> dict:
    idx = [[i, j] for j in range(n_y) for i in range(n_x)]
    pos = [[(i - (n_x - 1) / 2) * PITCH, (j - (n_y - 1) / 2) * PITCH] for i, j in idx]
    plan = {"format": "fpscan-plan/1", "lattice": {"n_x": n_x, "n_y": n_y, "pitch": PITCH},
            "mask": {"kind": "full", "params": {}},
            "points": {"indices": idx, "positions": pos, "weights": [PITCH ** 2] * len(idx)},
            "order": "rows",
            "acquisition": {"n_t": n_t, "dt": 2e-8, "averages": 1, "wavelengths": [7.5e-7],
                            "prf": 0.0, "sound_speed": 1500.0}}
    plan["id"] = plan_id_of(plan)
    return plan


def meta(k: int) -> dict:
    return dict(run_id=1, boot_id=9, point_index=k, pulse_number=k, timestamp_s=0.01 * k,
                bias_wavelength_m=1.55e-6, dc_level=0.8, pulse_energy_j=2e-3, dt_s=2e-8,
                scale=1e-3, offset=0.0)


def scan_file(folder: Path, name: str = "scan.h5", *, plan: dict | None = None) -> Path:
    """A complete, valid scan file (every point acquired)."""
    plan = plan or small_plan()
    path = folder / name
    if path.exists():
        return path
    n, n_t = len(plan["points"]["indices"]), plan["acquisition"]["n_t"]
    rng = np.random.default_rng(1)
    with ScanFile.create(path, plan, instrument={"idn": "test"}, software_version="test") as sf:
        for k in range(n):
            sf.append(k, rng.integers(-3000, 3000, n_t).astype(np.int16), meta(k))
    return path


def truncated(fraction: float):
    def make(folder: Path) -> Path:
        src = scan_file(folder).read_bytes()
        out = folder / f"trunc-{fraction}.h5"
        out.write_bytes(src[:int(len(src) * fraction)])
        return out
    return make


def corrupted(offset_fraction: float, n: int = 512):
    """A scan file with ``n`` bytes of noise written from ``offset_fraction`` of its size."""
    def make(folder: Path) -> Path:
        src = bytearray(scan_file(folder).read_bytes())
        at = int(len(src) * offset_fraction)
        src[at:at + n] = np.random.default_rng(at).integers(0, 256, min(n, len(src) - at), dtype=np.uint8).tobytes()
        out = folder / f"corrupt-{offset_fraction}-{n}.h5"
        out.write_bytes(bytes(src))
        return out
    return make


def writer_flagged_corrupt(folder: Path) -> Path:
    """A scan file whose superblock says a writer has it open (file-consistency flags set,
    superblock checksum valid: what a killed SWMR writer leaves), with 256 bytes of noise
    over its root group's metadata at 10 %: opened as an SWMR reader, HDF5 retries that
    metadata for ever while holding the GIL (read_scan did not return in 20 s)."""
    from tests.hdf5_superblock import SWMR_WRITER_FLAGS, set_status_flags

    src = bytearray(scan_file(folder).read_bytes())
    set_status_flags(src, SWMR_WRITER_FLAGS)  # superblock checksum rewritten: still valid
    at = int(len(src) * 0.1)
    src[at:at + 256] = np.random.default_rng(at).integers(0, 256, 256, dtype=np.uint8).tobytes()
    out = folder / "writer-flagged-corrupt.h5"
    out.write_bytes(bytes(src))
    return out


def signature_then_noise(folder: Path) -> Path:
    out = folder / "noise.h5"
    out.write_bytes(b"\x89HDF\r\n\x1a\n" + np.random.default_rng(3).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    return out


def external_storage(folder: Path) -> Path:
    secret = folder / "server-secret.bin"
    secret.write_bytes(b"root:x:0:0:root:/root:/bin/bash\n" * 80)
    out = folder / "external.h5"
    with h5py.File(out, "w") as f:
        f.create_dataset("sensor_data", shape=(10, 32), dtype="u1", external=[(str(secret), 0, 320)])
        f.attrs.update({"dt_s": 1e-8, "dx_m": 1e-4})
    return out


def external_link(folder: Path) -> Path:
    target = folder / "other.h5"
    with h5py.File(target, "w") as f:
        f.create_dataset("data", data=np.ones((16, 8)))
    out = folder / "extlink.h5"
    with h5py.File(out, "w") as f:
        f["sensor_data"] = h5py.ExternalLink(str(target), "/data")
        f.attrs.update({"dt_s": 1e-8, "dx_m": 1e-4})
    return out


def virtual_dataset(folder: Path) -> Path:
    target = folder / "vsource.h5"
    with h5py.File(target, "w") as f:
        f.create_dataset("data", data=np.ones((16, 8)))
    layout = h5py.VirtualLayout(shape=(16, 8), dtype="f8")
    layout[:] = h5py.VirtualSource(str(target), "data", shape=(16, 8))
    out = folder / "virtual.h5"
    with h5py.File(out, "w") as f:
        f.create_virtual_dataset("sensor_data", layout)
        f.attrs.update({"dt_s": 1e-8, "dx_m": 1e-4})
    return out


def fill_value_bomb(folder: Path) -> Path:
    out = folder / "bomb.h5"
    with h5py.File(out, "w") as f:
        f.create_dataset("sensor_data", shape=(100, 2048, 2048), dtype="f4", chunks=(1, 256, 256),
                         fillvalue=1.0)
        f.attrs.update({"dt_s": 1e-8, "dx_m": 1e-4})
    return out


def gzip_fill_bomb(shape: tuple[int, int] = (2**13, 2**13 - 1)):
    """A gzip-filtered chunked float32 dataset of ``shape`` that is never written (fill
    value 0.5): a few kB that declare ``shape`` x 4 bytes (test_upload_bomb.py's: 2**15 x (2**14 - 1),
    2 GiB; the default here fits the hostile server's 256 MiB declared limit, so the
    unwritten-chunk check is what refuses it)."""
    def make(folder: Path) -> Path:
        out = folder / f"gzip-bomb-{shape[0]}x{shape[1]}.h5"
        with h5py.File(out, "w") as f:
            f.create_dataset("sensor_data", shape=shape, dtype="f4", compression="gzip", fillvalue=0.5)
            f.attrs.update({"dt_s": 1e-8, "dx_m": 1e-4})
        return out
    return make


def gzip_zeros(folder: Path) -> Path:
    """64 MiB of written zeros, gzip 9: every chunk stored, about 1000:1 (deflate's limit)."""
    out = folder / "gzip-zeros.h5"
    with h5py.File(out, "w") as f:
        d = f.create_dataset("sensor_data", shape=(2048, 8192), dtype="f4", chunks=(256, 1024),
                             compression="gzip", compression_opts=9)
        for i in range(0, 2048, 256):
            d[i:i + 256] = 0.0
        f.attrs.update({"dt_s": 1e-8, "dx_m": 1e-4})
    return out


def absurd_shape(folder: Path) -> Path:
    out = folder / "absurd.h5"
    with h5py.File(out, "w") as f:
        f.create_dataset("sensor_data", shape=(2**40, 2**20), dtype="f8", chunks=(1, 1024))
        f.attrs.update({"dt_s": 1e-8, "dx_m": 1e-4})
    return out


def npy_absurd_header(folder: Path) -> Path:
    out = folder / "absurd.npy"
    header = "{'descr': '<f8', 'fortran_order': False, 'shape': (1000000000, 1000000), }"
    header = header + " " * (118 - len(header)) + "\n"
    out.write_bytes(b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header.encode() + b"\0" * 64)
    return out


def npy_file(name: str, array: np.ndarray, *, allow_pickle: bool = False):
    def make(folder: Path) -> Path:
        out = folder / name
        np.save(out, array, allow_pickle=allow_pickle)
        return out
    return make


def scan_with_plan(n_x: int):
    """A valid scan file whose stored plan JSON claims an ``n_x``-wide lattice."""
    def make(folder: Path) -> Path:
        src = scan_file(folder)
        out = folder / f"plan-nx-{n_x}.h5"
        out.write_bytes(src.read_bytes())
        with h5py.File(out, "a") as f:
            plan = json.loads(f["plan_json"][()].decode())
            plan["lattice"]["n_x"] = n_x
            del f["plan_json"]
            f["plan_json"] = json.dumps(plan)
        return out
    return make


def scan_edited(label: str, edit):
    """A valid scan file with ``edit(h5py.File)`` applied: numbers a damaged or hostile writer left."""
    def make(folder: Path) -> Path:
        out = folder / f"scan-{label}.h5"
        out.write_bytes(scan_file(folder).read_bytes())
        with h5py.File(out, "a") as f:
            edit(f)
        return out
    return make


def _dc_level_zero(f: h5py.File) -> None:
    """One completed A-line at DC level 0: its pressure (the AC over the DC level) is not finite."""
    m = f["aline_meta"][...]
    np.put(m["dc_level"], 3, 0.0)
    f["aline_meta"][...] = m


def _weights(value: float):
    def edit(f: h5py.File) -> None:
        w = f["weights"][...]
        w[2] = value
        f["weights"][...] = w
    return edit


UPLOADS = [
    Upload("truncated 10 %", "fpscan", truncated(0.10), 422, "truncated"),
    Upload("truncated 50 %", "fpscan", truncated(0.50), 422, "truncated"),
    Upload("truncated 99 %", "fpscan", truncated(0.99), 422, "truncated"),
    Upload("noise in the superblock", "fpscan", corrupted(0.0, 40), 422, "HDF5"),
    # 256 (512) bytes of noise over the metadata of the 18 kB scan file, at offsets that hit
    # object headers, B-trees and heaps (0.5 % to 10 %: root group and links; 2048 to
    # 10014 B, 11 % to 55 %, is raw data, where noise is just other data; 60 % to 95 %:
    # the datasets' headers and attributes). Offsets that land in unused space (55 %, 70 %,
    # 90 % with this layout) leave a readable file and are not rows.
    *(Upload(f"noise at {100 * f:g} %", "fpscan", corrupted(f, n), 422, "corrupt")
      for f, n in ((0.005, 256), (0.02, 512), (0.04, 256), (0.1, 256), (0.6, 256), (0.8, 256), (0.95, 256))),
    # a writer has it open (SWMR) and its metadata is damaged: HDF5 blocks; the import's time limit answers
    Upload("writer-flagged, corrupt metadata", "fpscan", writer_flagged_corrupt, 422, "within"),
    Upload("HDF5 signature then noise", "kwave-hdf5", signature_then_noise, 422, "HDF5"),
    Upload("HDF5 signature then noise (fpscan)", "fpscan", signature_then_noise, 422, "HDF5"),
    Upload("external storage", "kwave-hdf5", external_storage, 422, "external storage"),
    Upload("external link", "kwave-hdf5", external_link, 422, "external link"),
    Upload("virtual dataset", "kwave-hdf5", virtual_dataset, 422, "virtual dataset"),
    Upload("fill-value bomb", "kwave-hdf5", fill_value_bomb, 422, "declares"),
    Upload("gzip fill-value bomb", "kwave-hdf5", gzip_fill_bomb(), 422, "never written"),
    Upload("gzip fill-value bomb (ipasc)", "ipasc", gzip_fill_bomb(), 422, "never written"),
    Upload("gzip fill-value bomb (fpscan)", "fpscan", gzip_fill_bomb(), 422, "never written"),
    Upload("gzip of zeros, 1000:1", "kwave-hdf5", gzip_zeros, 422, "more than 100:1"),
    Upload("absurd declared shape", "kwave-hdf5", absurd_shape, 422, "declares"),
    Upload("npy with an absurd header", "npy", npy_absurd_header, 422, "",
           {"dt": "1e-8", "dx": "1e-4"}),
    Upload("scan plan with n_x = 1e8", "fpscan", scan_with_plan(10**8), 422, "lattice"),
    Upload("scan plan with n_x = 1e12", "fpscan", scan_with_plan(10**12), 422, "lattice"),
    # numbers of a scan file the import must refuse before they are stored: a non-finite A-line
    # (its NaN noise figure made the datasets table unreadable to every later upload), a speed of
    # sound or sample interval of another unit, weights no reconstruction can use
    Upload("scan with an A-line at DC level 0", "fpscan", scan_edited("dc0", _dc_level_zero), 422, "NaN or inf"),
    Upload("scan with a sound speed of 1e-30 m/s", "fpscan",
           scan_edited("c", lambda f: f.attrs.__setitem__("sound_speed", 1e-30)), 422, "sound_speed"),
    Upload("scan with dt of 10 s", "fpscan", scan_edited("dt", lambda f: f.attrs.__setitem__("dt_s", 10.0)), 422,
           "implausible"),
    Upload("scan with a negative weight", "fpscan", scan_edited("w", _weights(-1e-8)), 422, "weights"),
    Upload("scan with a NaN weight", "fpscan", scan_edited("w-nan", _weights(math.nan)), 422, "weights"),
    # A-lines of fewer samples than the file's n_t read as another, shorter record
    Upload("scan whose A-lines are shorter than its n_t", "fpscan",
           scan_edited("short", lambda f: f.attrs.__setitem__("n_t", f["alines"].shape[-1] + 16)), 422, "/alines"),
    # the structural checks do not depend on the format the upload claims
    Upload("external storage (ipasc)", "ipasc", external_storage, 422, "external storage"),
    Upload("external link (fpscan)", "fpscan", external_link, 422, "external link"),
    Upload("truncated 50 % (ipasc)", "ipasc", truncated(0.50), 422, "truncated"),
    # 2 MiB: over the form parser's in-memory size, so the body is spooled to a temporary file
    Upload("npy of NaN", "npy", npy_file("nan.npy", np.full((128, 64, 64), np.nan, np.float32)), 422, "NaN",
           {"dt": "1e-8", "dx": "1e-4"}),
    Upload("npy holding a pickle", "npy", npy_file("pickle.npy", np.array([{"a": 1}] * 3, dtype=object),
                                                   allow_pickle=True), 422, "pickle", {"dt": "1e-8", "dx": "1e-4"}),
    Upload("npy with one time sample", "npy", npy_file("one.npy", np.zeros((1, 4, 4), np.float32)), 422,
           "2 samples", {"dt": "1e-8", "dx": "1e-4"}),
]

#: Values every plan parameter and reconstruction option is tried with: zero, negative,
#: huge, non-finite, tiny positives (the smallest normal-ish and the smallest subnormal
#: double), a string and null.
BAD_VALUES = [0, -1, 1e300, math.nan, math.inf, 1e-12, 5e-324, "x", None]

#: mask kind -> (lattice, the valid parameters the bad values replace one at a time).
#: ``test_rows_cover_every_mask_parameter`` checks this names every parameter of every kind.
MASK_PARAMS = {
    "full": ({"n_x": 8, "n_y": 8, "pitch": 1e-4}, {}),
    "equispaced": ({"n_x": 32, "n_y": 32, "pitch": 1e-4}, {"interval": 2, "n_per_side": 8}),
    "hexagonal": ({"n_x": 32, "n_y": 32, "pitch": 1e-4}, {"spacing": 3e-4}),
    "random": ({"n_x": 32, "n_y": 32, "pitch": 1e-4}, {"n_points": 50, "seed": 1}),
    "poisson": ({"n_x": 32, "n_y": 32, "pitch": 1e-4}, {"min_distance": 3e-4, "seed": 1, "n_points": 40}),
    "equiangular": ({"n_x": 64, "n_y": 1, "pitch": 1e-4}, {"depth": 2e-3, "n_points": 20, "poi": 1e-4}),
    "equisteradian": ({"n_x": 64, "n_y": 64, "pitch": 1e-4},
                      {"depth": 2e-3, "n_points": 200, "poi": [1e-4, -1e-4]}),
    "points": ({"n_x": 16, "n_y": 16, "pitch": 1e-4}, {"points": [[0.0, 0.0], [2e-4, 3e-4]]}),
}
#: The other variant of the points kind (exactly one of points/indices is given).
POINTS_BY_INDEX = {"indices": [[0, 0], [4, 5]]}

#: (kind, case, value) that are legal (200; case: a parameter, or ``param[0]`` for its
#: first element): a parameter's default (null) or a valid seed; a zero or tiny Poisson
#: distance on 32 x 32 (every lattice point: bounded by the lattice); a point of
#: interest, a point or an index at (or a tiny offset from) the centre or the corner. (A tiny
#: depth is refused: below one lattice pitch.)
LEGAL = {("random", "seed", 0), ("poisson", "seed", 0), ("poisson", "n_points", None),
         ("equispaced", "n_per_side", None), ("equiangular", "poi", None), ("equisteradian", "poi", None),
         *(("poisson", "min_distance", v) for v in (1e-12, 5e-324)),
         *((k, c, v) for k, c in (("equiangular", "poi"), ("equisteradian", "poi[0]"), ("points", "points[0]"))
           for v in (0, 1e-12, 5e-324)),
         ("points", "indices[0]", 0)}
def _param_rows(kind: str, lattice: dict, good: dict) -> list[tuple[str, str, dict, int, str]]:
    """The rows of one kind: each parameter at each bad value (and, for list parameters,
    one element at each bad value), the reason naming the parameter."""
    out = []
    for param in good:
        for value in BAD_VALUES:
            variants = [(f"{param}={value}", value)]
            if isinstance(good[param], list):  # a pair or a point list: one element bad
                first = good[param][0]
                variants.append((f"{param}[0]={value}", [[value, value], *good[param][1:]]
                                 if isinstance(first, list) else [value, *good[param][1:]]))
            for label, v in variants:
                params = dict(good, **{param: v})
                legal = (kind, label.split("=")[0], value) in LEGAL
                reason = "position" if label.startswith("points[0]") and value in (-1, 1e300) else param
                out.append((f"{kind}-{label}", "/api/plans/preview",
                            {"kind": kind, "lattice": lattice, "params": params},
                            200 if legal else 422, "" if legal else reason))
    return out


#: The rest of a plan request: lattice, acquisition, order and force, tried on a small
#: full mask.
PLAN_BASE = {"kind": "full", "lattice": {"n_x": 8, "n_y": 8, "pitch": 1e-4}, "params": {},
             "acquisition": {"n_t": 256, "dt": 2e-8, "averages": 1, "wavelengths": [7.5e-7], "prf": 100.0,
                             "sound_speed": 1500.0, "wavelength_order": "per_point"},
             "order": "serpentine", "force": False}
#: (section, field, value) of ``PLAN_BASE`` that are legal: prf 0 (as fast as possible) or
#: tiny (a long scan, stated as such), unset options, force false (0 is not a bool:
#: pydantic's lax mode takes 0 as false).
PLAN_LEGAL = {("acquisition", "prf", 0), ("acquisition", "prf", 1e-12), ("acquisition", "prf", 5e-324),
              ("acquisition", "wavelength_order", None), (None, "order", None), (None, "force", 0)}


def plan_document() -> dict:
    """A valid plan JSON (what ``fpscan plan --out`` writes) for ``POST /api/plans``."""
    plan = small_plan(4, 3, 64)
    plan["mask"] = {"kind": "full", "params": {}, "requested_points": 12, "obtained_points": 12,
                    "weight_ratio": None}
    plan["id"] = plan_id_of(plan)
    return plan


#: (case, value) of a plan document that are legal (201): the optional weight ratio
#: unset, prf 0 or tiny (as for requests), the planner's record (mask.kind, order: labels
#: the contract does not check, ``fpscan.driver.plan.check_plan``), a first index (0, 0) (the
#: document's own first point), tiny positive weights (a point that counts for little).
DOC_LEGAL = {("mask.weight_ratio", None), ("mask.kind", "x"), ("order", "x"), ("points.indices[0]", 0),
             *(("acquisition.prf", v) for v in (0, 1e-12, 5e-324)),
             *(("points.weights[0]", v) for v in (1e-12, 5e-324))}


def _doc_paths(doc: dict, prefix: str = "") -> list[str]:
    """Every field of a plan document, dotted (``points.indices``), down to the sections'
    fields (lists and ``mask.params`` are fields, not descended into)."""
    out = []
    for key, v in doc.items():
        path = prefix + key
        out += _doc_paths(v, path + ".") if isinstance(v, dict) and key != "params" else [path]
    return out


def _doc_rows() -> list[tuple[str, str, dict, int, str]]:
    """A plan document with each field at each bad value (lists also with one bad
    element): ``POST /api/plans``, the id recomputed so that the field's own check answers."""
    out = []
    for path in _doc_paths(plan_document()):
        *parents, name = path.split(".")
        for value in BAD_VALUES:
            doc = plan_document()
            good = doc
            for p in parents:
                good = good[p]
            variants = [(f"{path}={value}", value)]
            if isinstance(good[name], list):
                first = good[name][0]
                variants.append((f"{path}[0]={value}", [[value, value], *good[name][1:]]
                                 if isinstance(first, list) else [value, *good[name][1:]]))
            for label, v in variants:
                doc = plan_document()
                section = doc
                for p in parents:
                    section = section[p]
                # a whole number where the contract has a float: sent as the float (0 -> 0.0),
                # so that the id computed here is the one the server computes
                section[name] = float(v) if isinstance(good[name], float) and type(v) is int else v
                if path == "lattice.pitch" and isinstance(v, float) and math.isfinite(v):
                    n_x, n_y = doc["lattice"]["n_x"], doc["lattice"]["n_y"]  # positions on that pitch
                    doc["points"]["positions"] = [[(i - (n_x - 1) / 2) * v, (j - (n_y - 1) / 2) * v]
                                                  for i, j in doc["points"]["indices"]]
                if name != "id":
                    try:
                        doc["id"] = plan_id_of(doc)
                    except (TypeError, ValueError):
                        pass  # not hashable as JSON: the id stays; the field's check answers first
                legal = (label.split("=")[0], value) in DOC_LEGAL
                out.append((f"document {label}", "/api/plans", doc, 201 if legal else 422,
                            "" if legal else ("id" if name == "id" else name)))
    return out


def plan_cases() -> list[tuple[str, str, dict, int, str]]:
    """Every plan parameter at every bad value: ``(case id, route, request body, expected
    status, reason fragment)``: 422 with a reason naming the parameter, or 200/201 for the
    few legal values (``LEGAL``, ``PLAN_LEGAL``, ``DOC_LEGAL``). Mask parameters per kind
    (previews), the lattice, acquisition, order and force of ``PLAN_BASE``, the points
    shortcut of a point list, and every field of a plan document (``POST /api/plans``)."""
    out = []
    for kind, (lattice, good) in MASK_PARAMS.items():
        out += _param_rows(kind, lattice, good)
    out += _param_rows("points", MASK_PARAMS["points"][0], POINTS_BY_INDEX)
    for section in ("lattice", "acquisition", None):
        names = list(PLAN_BASE[section]) if section else ["order", "force"]
        for name in names:
            for value in BAD_VALUES:
                body = json.loads(json.dumps(PLAN_BASE))
                (body[section] if section else body)[name] = value
                legal = (section, name, value) in PLAN_LEGAL
                out.append((f"{section or 'plan'}.{name}={value}", "/api/plans/preview", body,
                            200 if legal else 422, "" if legal else name))
    for value in BAD_VALUES:  # the request-level point list: {"points": [[i_x, i_y], ...]}
        for label, pts in ((f"{value}", value), (f"[0]={value}", [[value, value], [1, 1]])):
            legal = label == "[0]=0"  # [[0, 0], [1, 1]]: two valid indices
            out.append((f"points-shortcut{label}", "/api/plans/preview",
                        {"points": pts, "lattice": MASK_PARAMS["points"][0]}, 200 if legal else 422,
                        "" if legal else "points"))
    return out + _doc_rows()


def mask_parameters_covered() -> set[tuple[str, str]]:
    """(kind, parameter) pairs the plan rows try."""
    covered = {(kind, p) for kind, (_, good) in MASK_PARAMS.items() for p in good}
    return covered | {("points", p) for p in POINTS_BY_INDEX}


#: A reconstruction request's options (every method's options model) and the valid value each replaces
#: (``recon_cases`` checks that this names every option the API has).
RECON_PARAMS = {"sound_speed": 1500.0, "sound_speed_range": [1400.0, 1600.0], "eps": 1e-6, "dtype": "float32", "upsample": 1, "positivity": False, "lam": 1.0,
                "max_iter": 10, "time_limit": 60.0, "n_z": 64, "dz": 1e-5, "interp": "*nearest",
                "debias": False, "whole_record": False, "tol": 1e-3, "force": False}
#: the method each option is tried with (one that takes it: an option the method does not take is a 422)
RECON_METHOD = {"lam": "tv", "max_iter": "tv", "time_limit": "tv", "debias": "tv", "whole_record": "tv", "tol": "tv",
                "interp": "kwave"}
#: Options whose value among ``BAD_VALUES`` is legal: unset (None: the method's default),
#: positivity, debias and force 0 (false), λ = 0 (no
#: regularisation) or tiny, the tolerance 1e-12, tv's stopping threshold 0 (run every
#: iteration) or tiny.
RECON_LEGAL = {(name, None) for name in RECON_PARAMS} | {
    ("positivity", 0), ("debias", 0), ("whole_record", 0), ("force", 0), ("lam", 0), ("lam", 1e-12), ("lam", 5e-324), ("eps", 1e-12),
    ("time_limit", 1e-12), ("time_limit", 5e-324), ("tol", 0), ("tol", 1e-12), ("tol", 5e-324)}
#: A dataset id no server has: a request that passes validation is answered 404.
NO_DATASET = "0" * 32


def _new_option_cases(names: set[str]) -> list[tuple[str, dict, int, str]]:
    """An option a method added after this list was written (a new method is one file:
    ``service/recon/methods/``) is tried at every bad value too, with the first method that
    takes it; which values are legal is its options model's answer (the hand-made
    ``RECON_LEGAL`` covers the options listed above), and whatever the answer, the server
    must give it as a 404 or a 422 naming the option, never a 5xx or a hang."""
    from pydantic import ValidationError

    from fpscan.service.recon.methods import METHODS

    out = []
    for name in sorted(names):
        method = next(m for m, spec in METHODS.items() if name in spec.options_model.model_fields)
        for value in BAD_VALUES:
            try:
                METHODS[method].options_model(**{name: value})
                legal = True
            except (ValidationError, ValueError, TypeError):
                legal = False
            body = {"dataset_id": NO_DATASET, "method": method, "params": {name: value}}
            out.append((f"params.{name}={value} ({method})", body, 404 if legal else 422, "" if legal else name))
    return out


def recon_cases() -> list[tuple[str, dict, int, str]]:
    """Every reconstruction option, the method and the input ids at every bad value (and a
    path trick for the ids): ``(case id, request body, expected status, reason fragment)``:
    422 with a reason naming the option, or 404 (valid, but no such dataset or scan job)
    for the legal values (an id "x")."""
    from fpscan.service.api.models import PARAMS_MODELS

    fields = {name for model in PARAMS_MODELS.values() for name in model.model_fields}
    assert set(RECON_PARAMS) <= fields, "an option listed here is gone from the API"
    out = []
    for name in RECON_PARAMS:
        for value in BAD_VALUES:
            body = {"dataset_id": NO_DATASET, "method": RECON_METHOD.get(name, "ner"), "params": {name: value}}
            legal = (name, value) in RECON_LEGAL
            out.append((f"params.{name}={value}", body, 404 if legal else 422, "" if legal else name))
    out += _new_option_cases(fields - set(RECON_PARAMS))
    for pair in ([0, 0], [1600.0, 1400.0], [1500.0, 1500.0], [1e300, 1e300], [math.nan, 1500.0], [1500.0]):
        out.append((f"params.sound_speed_range={pair}", {"dataset_id": NO_DATASET,
                                                          "params": {"sound_speed_range": pair}}, 422,
                    "sound_speed_range"))
    for name in ("method", "dataset_id", "scan_job_id"):
        for value in [*BAD_VALUES, "../../etc/passwd"]:
            body = {"dataset_id": NO_DATASET, "method": "ner", name: value}
            if name == "scan_job_id":
                del body["dataset_id"]
            legal = (name != "method" and value == "x") or (name == "method" and value is None)  # the default
            out.append((f"{name}={value}", body, 404 if legal else 422, "" if legal else name))
    return out
