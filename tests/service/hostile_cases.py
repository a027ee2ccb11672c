"""The hostile-input suite as data (issue 14): one row per case — the upload or request,
the expected status and a fragment of the reason. Files are built with h5py/numpy here,
from a real scan file written by ``driver.scanfile``."""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from driver.plan import plan_id_of
from driver.scanfile import ScanFile

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
        out = folder / f"corrupt-{offset_fraction}.h5"
        out.write_bytes(bytes(src))
        return out
    return make


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


UPLOADS = [
    Upload("truncated 10 %", "fpscan", truncated(0.10), 422, "truncated"),
    Upload("truncated 50 %", "fpscan", truncated(0.50), 422, "truncated"),
    Upload("truncated 99 %", "fpscan", truncated(0.99), 422, "truncated"),
    Upload("noise at 2 %", "fpscan", corrupted(0.02), 422, ""),
    Upload("noise in the superblock", "fpscan", corrupted(0.0, 40), 422, ""),
    Upload("HDF5 signature then noise", "kwave-hdf5", signature_then_noise, 422, "HDF5"),
    Upload("HDF5 signature then noise (fpscan)", "fpscan", signature_then_noise, 422, "HDF5"),
    Upload("external storage", "kwave-hdf5", external_storage, 422, "external storage"),
    Upload("external link", "kwave-hdf5", external_link, 422, "external link"),
    Upload("virtual dataset", "kwave-hdf5", virtual_dataset, 422, "virtual dataset"),
    Upload("fill-value bomb", "kwave-hdf5", fill_value_bomb, 422, "declares"),
    Upload("absurd declared shape", "kwave-hdf5", absurd_shape, 422, "declares"),
    Upload("npy with an absurd header", "npy", npy_absurd_header, 422, "",
           {"dt": "1e-8", "dx": "1e-4"}),
    Upload("scan plan with n_x = 1e8", "fpscan", scan_with_plan(10**8), 422, "lattice"),
    Upload("scan plan with n_x = 1e12", "fpscan", scan_with_plan(10**12), 422, "lattice"),
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

#: Plan parameter values every mask parameter is tried with.
BAD_VALUES = [0, -1, 1e300, math.nan, math.inf, "x", None]

#: mask kind -> (lattice, the valid parameters the bad values replace one at a time).
MASK_PARAMS = {
    "subgrid": ({"n_x": 32, "n_y": 32, "pitch": 1e-4}, {"interval": 2, "n_per_side": 8}),
    "hexagonal": ({"n_x": 32, "n_y": 32, "pitch": 1e-4}, {"spacing": 3e-4}),
    "random": ({"n_x": 32, "n_y": 32, "pitch": 1e-4}, {"n_points": 50, "seed": 1}),
    "poisson": ({"n_x": 32, "n_y": 32, "pitch": 1e-4}, {"min_distance": 3e-4, "seed": 1, "n_points": 40}),
    "equiangular": ({"n_x": 64, "n_y": 1, "pitch": 1e-4}, {"depth": 2e-3, "n_points": 20}),
    "equisteradian": ({"n_x": 64, "n_y": 64, "pitch": 1e-4}, {"depth": 2e-3, "n_points": 200}),
}


#: (parameter, value) pairs that are legal: the parameter's default or a valid seed.
LEGAL = {("seed", 0), ("n_per_side", None), ("n_points", None)}


#: The rest of a plan request: lattice, acquisition and order, tried on a small full mask.
PLAN_BASE = {"kind": "full", "lattice": {"n_x": 8, "n_y": 8, "pitch": 1e-4}, "params": {},
             "acquisition": {"n_t": 256, "dt": 2e-8, "averages": 1, "wavelengths": [7.5e-7], "prf": 100.0,
                             "sound_speed": 1500.0, "wavelength_order": "per_point"},
             "order": "serpentine"}
#: (section, field, value) of ``PLAN_BASE`` that are legal: prf 0 (as fast as possible), unset options.
PLAN_LEGAL = {("acquisition", "prf", 0), ("acquisition", "wavelength_order", None), (None, "order", None)}


def plan_cases() -> list[tuple[str, dict, int]]:
    """Every plan parameter at every bad value: ``(case id, request body, expected
    status)``: 422, or 200 for the few legal values (``LEGAL``, ``PLAN_LEGAL``). Mask
    parameters per kind, then the lattice, acquisition and order of ``PLAN_BASE``."""
    out = []
    for kind, (lattice, good) in MASK_PARAMS.items():
        for param in good:
            for value in BAD_VALUES:
                params = dict(good, **{param: value})
                legal = (param, value) in LEGAL and not (kind != "poisson" and param == "n_points")
                out.append((f"{kind}-{param}={value}", {"kind": kind, "lattice": lattice, "params": params},
                            200 if legal else 422))
    for section in ("lattice", "acquisition", None):
        names = list(PLAN_BASE[section]) if section else ["order"]
        for name in names:
            for value in BAD_VALUES:
                body = json.loads(json.dumps(PLAN_BASE))
                (body[section] if section else body)[name] = value
                out.append((f"{section or 'plan'}.{name}={value}", body,
                            200 if (section, name, value) in PLAN_LEGAL else 422))
    return out


#: A reconstruction request's options (``ReconParams``) and the valid value each replaces
#: (``recon_cases`` checks that this names every option the API has).
RECON_PARAMS = {"c": 1500.0, "c_range": [1400.0, 1600.0], "eps": 1e-6, "dtype": "float32", "upsample": 1, "positivity": False, "lam": 1.0,
                "iterations": 10, "n_z": 64, "dz": 1e-5, "interp": "*nearest"}
#: Options whose value among ``BAD_VALUES`` is legal: unset (None: the method's default;
#: dtype has no unset), positivity 0 (false) and λ = 0 (no regularisation).
RECON_LEGAL = {(name, None) for name in RECON_PARAMS if name != "dtype"} | {("positivity", 0), ("lam", 0)}
#: A dataset id no server has: a request that passes validation is answered 404.
NO_DATASET = "0" * 32


def recon_cases() -> list[tuple[str, dict, int]]:
    """Every reconstruction option, the method and the input ids at every bad value (and a
    path trick for the ids): ``(case id, request body, expected status)``: 422, or 404
    (valid, but no such dataset or scan job) for the legal values (an id "x")."""
    from service.api.models import ReconParams

    assert set(RECON_PARAMS) == set(ReconParams.model_fields), "a reconstruction option is missing here"
    out = []
    for name in RECON_PARAMS:
        for value in BAD_VALUES:
            body = {"dataset_id": NO_DATASET, "method": "ner", "params": {name: value}}
            out.append((f"params.{name}={value}", body, 404 if (name, value) in RECON_LEGAL else 422))
    for pair in ([0, 0], [1600.0, 1400.0], [1500.0, 1500.0], [1e300, 1e300], [math.nan, 1500.0], [1500.0]):
        out.append((f"params.c_range={pair}", {"dataset_id": NO_DATASET, "params": {"c_range": pair}}, 422))
    for name in ("method", "dataset_id", "scan_job_id"):
        for value in [*BAD_VALUES, "../../etc/passwd"]:
            body = {"dataset_id": NO_DATASET, "method": "ner", name: value}
            if name == "scan_job_id":
                del body["dataset_id"]
            out.append((f"{name}={value}", body, 404 if name != "method" and value == "x" else 422))
    return out
