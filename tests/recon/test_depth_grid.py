"""One default depth grid for every method (`fpscan.service.recon.depth`; docs/methods.md "The depth
grid"): ``dz`` the lateral pitch (c·dt where that is finer), ``n_z`` as deep as the record reaches
(c·t_last), one given alone keeping the other's default; ``kwave`` keeps k-Wave's own grid (n_t rows
of c·dt); the server sizes a job on the grid the method makes.

Oracles: the rule's own arithmetic written out here (rows = ⌊c (n_t − 1) dt / dz⌋ + 1), the volumes
the one dispatch (``fpscan.reconstruct``) returns, and the true p0 of the k-Wave reference files
(real k-Wave output, ``shared/data``) for the images' quality on the old and the new grid."""
from __future__ import annotations

import math

import h5py
import numpy as np
import pytest

import fpscan
from fpscan.physics.forward import forward_grid

C, DT, PITCH, N_T = 1500.0, 8e-9, 60e-6, 100
#: the rows down to c·t_last at the pitch: 1.188 mm / 60 µm = 19.8 -> rows 0..19
REACH_ROWS = math.floor(C * (N_T - 1) * DT / PITCH) + 1
PLANAR = ("ner", "nedner", "linear", "nearest", "cubic")


def _data(pitch: float = PITCH, plane: bool = False) -> fpscan.GridDataset:
    """A small blob 0.6 mm deep seen by a line of 16 (or a plane of 8 x 8) sensors at ``pitch``."""
    n = 8 if plane else 16
    shape = (12, n, n) if plane else (12, n)
    p0 = np.zeros(shape)
    p0[(10, *(s // 2 for s in shape[1:]))] = 1.0
    g = forward_grid(p0, pitch, 60e-6, DT, N_T, C)
    return fpscan.GridDataset(g, dx=pitch, dt=DT, sound_speed=C)


def _depth(rec) -> tuple[float, int]:
    z = np.asarray(rec.z)
    return float(z[1] - z[0]), len(z)


@pytest.mark.parametrize("plane", [False, True])
def test_every_method_makes_the_one_default_grid(plane):
    ds = _data(plane=plane)
    for method in PLANAR:
        rec = fpscan.reconstruct(ds, method, quiet=True)
        dz, rows = _depth(rec)
        assert dz == pytest.approx(PITCH, rel=1e-12) and rows == REACH_ROWS == rec.p0.shape[0], (method, dz, rows)
        assert rec.params["dz"] == pytest.approx(PITCH) and rec.params["n_z"] == REACH_ROWS
    # tv: the same grid where its image is the whole record's (by default it ends at the last echo)
    tv = fpscan.reconstruct(ds, "tv", max_iter=2, whole_record=True, quiet=True)
    assert _depth(tv) == (pytest.approx(PITCH, rel=1e-9), REACH_ROWS)
    ended = fpscan.reconstruct(ds, "tv", max_iter=2, quiet=True)  # at the pitch, no deeper than the record
    assert _depth(ended)[0] == pytest.approx(PITCH, rel=1e-9) and 2 <= _depth(ended)[1] <= REACH_ROWS
    # kwave: k-Wave's kspaceLineRecon / kspacePlaneRecon grid, the record's n_t rows of c·dt
    kw = fpscan.reconstruct(ds, "kwave", quiet=True)
    assert _depth(kw) == (pytest.approx(C * DT, rel=1e-12), N_T)


def test_a_pitch_finer_than_c_dt_gives_c_dt():
    ds = _data(pitch=5e-6)  # c·dt = 12 µm: the record resolves no finer depth
    for method in ("ner", "nedner"):
        dz, rows = _depth(fpscan.reconstruct(ds, method, quiet=True))
        assert dz == pytest.approx(C * DT, rel=1e-12) and rows == N_T, method


def test_n_z_alone_is_rows_of_the_default_spacing_and_dz_alone_reaches_the_record():
    ds = _data()
    for method in PLANAR:
        assert _depth(fpscan.reconstruct(ds, method, n_z=8, quiet=True)) == (pytest.approx(PITCH, rel=1e-12), 8)
        # 30 µm down to c·t_last = 1.188 mm: rows 0..39 (until 2026-11-28: n_t = 100 rows, 3 mm deep)
        assert _depth(fpscan.reconstruct(ds, method, dz=30e-6, quiet=True)) == (pytest.approx(30e-6), 40)
    tv = fpscan.reconstruct(ds, "tv", n_z=8, max_iter=2, quiet=True)
    assert _depth(tv) == (pytest.approx(PITCH, rel=1e-9), 8)
    tv = fpscan.reconstruct(ds, "tv", dz=30e-6, max_iter=2, whole_record=True, quiet=True)
    assert _depth(tv) == (pytest.approx(30e-6), 40)


def test_the_server_sizes_a_job_on_the_grid_the_method_makes():
    """The admission's output rows and result bytes are the volume's (``fpscan.service.jobs.admission``)."""
    from fpscan.service.jobs.admission import (
        estimate_result_bytes,
        input_shape,
        output_depth_rows,
        working_depth_rows,
    )

    for plane in (False, True):
        ds = _data(plane=plane)
        shape = input_shape(ds)
        for params in ({}, {"n_z": 8}, {"dz": 30e-6}, {"n_z": 12, "dz": 100e-6}):
            rec = fpscan.reconstruct(ds, "ner", quiet=True, **params)
            assert output_depth_rows(shape, params) == rec.p0.shape[0], params
            assert estimate_result_bytes(shape, {"method": "ner", **params}) == int(rec.p0.size * 4 * 1.02 + (1 << 20))
            assert working_depth_rows(shape, params) <= rec.params["depth_rows"], params


def _cc_on_truth(rec, p0: np.ndarray, p0_dz: float) -> float:
    """Pearson's CC of ``rec`` (linear in depth onto p0's rows) with the true ``p0``."""
    z = np.asarray(rec.z)
    zt = np.arange(p0.shape[0]) * p0_dz
    assert z[-1] >= zt[-1] - 1e-12, f"the image ends at {z[-1] * 1e3:.3g} mm, above the phantom's {zt[-1] * 1e3:.3g} mm"
    j = np.clip(np.searchsorted(z, zt, side="right") - 1, 0, len(z) - 2)
    w = ((zt - z[j]) / (z[j + 1] - z[j])).reshape((-1,) + (1,) * (p0.ndim - 1))
    img = rec.p0[j] * (1 - w) + rec.p0[j + 1] * w
    return float(np.corrcoef(img.ravel(), p0.ravel())[0, 1])


@pytest.mark.parametrize("name", ["kwave3d_vessel_tree.h5", "kwave3d_balls_yarn.h5", "kwave2d_points.h5"])
def test_the_default_grid_keeps_the_images_quality(shared_data, name):
    """NER's CC with k-Wave's true p0 on the default grid (the pitch) is the c·dt grid's (the default
    until 2026-11-28): the same band-limited image, sampled less densely (docs/methods.md)."""
    path = shared_data / name
    with h5py.File(path, "r") as f:
        p0 = np.asarray(f["p0"][...], dtype=np.float64)
        p0_dz = float(f.attrs["dx_m"])  # k-Wave's x is the depth (shared/data/README.md)
    ds = fpscan.load_dataset(path)
    pitch = _depth(fpscan.reconstruct(ds, "ner", quiet=True))
    fine = fpscan.reconstruct(ds, "ner", dz=ds.sound_speed * ds.dt, n_z=ds.data.shape[0], quiet=True)
    new = fpscan.reconstruct(ds, "ner", quiet=True)
    assert pitch[0] == pytest.approx(ds.dx)
    cc_new, cc_fine = _cc_on_truth(new, p0, p0_dz), _cc_on_truth(fine, p0, p0_dz)
    assert cc_new >= cc_fine - 0.002 and cc_new > 0.7, (cc_new, cc_fine)


def test_recon_help_states_the_default_grid():
    """``fpscan recon --help`` says the default grid (its spacing and depth) and kwave's own."""
    import argparse

    from fpscan.clients.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    text = " ".join(sub["recon"].format_help().split())
    start = text.index("--n-z N_Z nedner")  # the option's help, after the usage line
    n_z = text[start:text.index("--dz DZ ", start)]
    dz = text[text.index("--dz DZ ", start):text.index("--device ", start)]
    assert "default down to c·t_last" in n_z and "given alone: rows of the default dz" in n_z, n_z
    assert "tv: down to the record's last echo above the noise" in n_z, n_z
    assert "default the lateral pitch, c·dt where that is finer" in dz, dz
    assert "kwave: k-Wave compatible (kspaceLineRecon / kspacePlaneRecon; their own depth grid, n_t rows of c·dt)" \
        in text
