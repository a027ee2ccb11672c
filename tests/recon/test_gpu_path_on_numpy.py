"""The GPU path's code on NumPy against the CPU kernels: CI has no GPU, so the
array-namespace steps that run on CuPy there (`fpscan.physics.temporal_xp`,
`fpscan.service.recon.gpu`) run here with ``xp = numpy`` and must give the CPU kernels' results; and
the device rules where there is no GPU."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import scipy.fft

from fpscan.physics import nufft
from fpscan.physics import temporal_xp as txp
from fpscan.physics.fast_lengths import fast_lateral
from fpscan.service.recon import device, gpu
from fpscan.service.recon.operator import PlanarOperator
from fpscan.service.recon.planar import reconstruct_grid
from fpscan.service.recon.tv.preconditioner import apply_weight, apply_weight_on, ner_weight

C = 1500.0


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


@pytest.mark.parametrize("ctype, tol", [(np.complex128, 1e-12), (np.complex64, 2e-6)])
def test_temporal_step_matches_the_compiled_kernels(ctype: type, tol: float) -> None:
    rng = np.random.default_rng(0)
    n_t, dt, n_cols, n_kz = 300, 1e-8, 700, 400  # large enough for the compiled kernels (not the small path)
    grid = nufft.make_grid(n_t, "nufft", 1e-6)
    klat2 = rng.integers(0, 30, n_cols) * 1e7
    kz = np.pi / ((n_kz - 1) * C * dt) * np.arange(n_kz)
    qw = np.full(n_kz, 0.3)
    rdtype = np.float64 if ctype == np.complex128 else np.float32
    a = (rng.standard_normal((n_t, n_cols)) + 1j * rng.standard_normal((n_t, n_cols))).astype(ctype)
    U = nufft.to_fine_grid(a, grid, True)
    U_xp = txp.to_fine_grid(np, np.ascontiguousarray(a.T), grid, True)
    assert _rel(U_xp, U) <= tol
    for inversion in (True, False):
        tp = txp.taps(np, grid, klat2, kz, qw, C, dt, 3e-8, inversion, rdtype)
        E = nufft.evaluate(U, grid, klat2, kz, qw, C, dt, 3e-8, inversion=inversion)
        assert _rel(txp.evaluate(np, U_xp, tp), E) <= tol
    B = (rng.standard_normal((n_cols, n_kz)) + 1j * rng.standard_normal((n_cols, n_kz))).astype(ctype)
    R = nufft.spread(B, grid, klat2, kz, qw, C, dt, 3e-8)
    R_xp = txp.spread(np, B, txp.taps(np, grid, klat2, kz, qw, C, dt, 3e-8, False, rdtype))
    assert _rel(R_xp, R) <= tol
    assert _rel(txp.from_fine_grid(np, R_xp, grid, False), nufft.from_fine_grid(R, grid, False)) <= tol


def test_dct1_is_scipys_type_1() -> None:
    rng = np.random.default_rng(1)
    x = rng.standard_normal((5, 37)) + 1j * rng.standard_normal((5, 37))
    want = scipy.fft.dct(x.real, 1, axis=1) + 1j * scipy.fft.dct(x.imag, 1, axis=1)
    assert np.abs(txp.dct1(np, x, axis=1) - want).max() <= 1e-12 * np.abs(want).max()
    assert np.allclose(txp.dct1(np, x.real.T, axis=0), scipy.fft.dct(x.real.T, 1, axis=0))


@pytest.mark.parametrize("shape", [(60, 20, 24), (50, 30)])
@pytest.mark.parametrize("rdtype, tol", [(np.float64, 1e-12), (np.float32, 2e-6)])
@pytest.mark.parametrize("upsample", [1, 2])
def test_inversion_matches_reconstruct_grid(shape: tuple, rdtype: type, tol: float, upsample: int) -> None:
    rng = np.random.default_rng(2)
    data = rng.standard_normal(shape).astype(rdtype)
    dx, dt, t0 = 1e-4, 5e-8, 1e-7
    cpu = reconstruct_grid(data, dx, dt, C, dtype=rdtype, upsample=upsample, t0=t0, device="cpu")
    n_t, is2d = shape[0], len(shape) == 2
    n_y, n_x = (1, shape[1]) if is2d else shape[1:]
    n_yp, n_xp = fast_lateral(n_y, n_x, square=True)
    A = np.fft.rfft2(data.reshape(n_t, n_y, n_x), s=(n_yp, n_xp), axes=(1, 2))
    keep = (cpu.params["n_z"], 1 if is2d else n_y * upsample, n_x * upsample)
    p = gpu.invert(np, A, n_xp, dx, dx, dt, C, cpu.params["depth_rows"], cpu.params["dz"], t0, 1e-6, rdtype,
                   upsample, keep)
    p = p[:, 0, :] if is2d else p
    assert p.dtype == rdtype and p.shape == cpu.p0.shape
    assert _rel(p, cpu.p0) <= tol


def _lattice(rng: np.random.Generator, n_y: int, n_x: int, dx: float, share: float) -> np.ndarray:
    xs = (np.arange(n_x) - (n_x - 1) / 2) * dx
    ys = (np.arange(n_y) - (n_y - 1) / 2) * dx
    X, Y = np.meshgrid(xs, ys)
    keep = rng.random(X.size) < share
    return np.stack([X.ravel()[keep], Y.ravel()[keep]], 1)


@pytest.mark.parametrize("case", ["2-D grid", "3-D grid", "3-D lattice nodes"])
@pytest.mark.parametrize("band", [None, 4e6])
@pytest.mark.parametrize("rdtype, tol", [(np.float64, 1e-12), (np.float32, 2e-6)])
def test_operator_pair_matches_planar_operator(case: str, band: float | None, rdtype: type, tol: float) -> None:
    rng = np.random.default_rng(3)
    shape = (12, 20) if case == "2-D grid" else (10, 14, 16)
    positions = _lattice(rng, 14, 16, 1e-4, 0.3) if "nodes" in case else None
    op = PlanarOperator(shape, 1e-4, 1e-4, 3e-8, 50, C, positions=positions, band=band, dtype=rdtype, t0=2e-8,
                        device="cpu")
    pair = gpu.OperatorPair(op, np)
    x = rng.standard_normal(op.ishape).astype(rdtype)
    y = rng.standard_normal(op.oshape).astype(rdtype)
    assert _rel(pair.forward(x), op.forward(x)) <= tol
    assert _rel(pair.adjoint(y), op.adjoint(y)) <= tol


def test_operator_pair_refuses_off_lattice_sensors() -> None:
    pos = np.array([[0.13e-4, 0.0], [1.0e-4, 0.5e-4]])
    op = PlanarOperator((10, 14, 16), 1e-4, 1e-4, 3e-8, 50, C, positions=pos, device="cpu")
    with pytest.raises(ValueError, match="off it"):
        gpu.OperatorPair(op, np)


@pytest.mark.parametrize("shape", [(30, 40), (20, 26, 30)])
def test_ner_weight_matches_the_preconditioner(shape: tuple) -> None:
    rng = np.random.default_rng(4)
    P = ner_weight(shape, 1e-4, 6e-5)
    x = rng.standard_normal(shape).astype(np.float32)
    got = apply_weight_on(np, P, x)
    assert got.dtype == np.float32
    assert _rel(got, apply_weight(P, x.copy())) <= 2e-6


def test_without_a_gpu_auto_runs_on_the_cpu_and_cuda_is_refused() -> None:
    data = np.random.default_rng(5).standard_normal((40, 8, 8))
    assert device.cuda_devices() == [] or pytest.skip("a GPU is visible here: tests/gpu covers it")
    assert reconstruct_grid(data, 1e-4, 6e-8, C).params["device"] == "cpu"
    with pytest.raises(ValueError, match="no CUDA GPU is visible"):
        reconstruct_grid(data, 1e-4, 6e-8, C, device="cuda")
    with pytest.raises(ValueError, match="device must be one of auto, cpu, cuda"):
        reconstruct_grid(data, 1e-4, 6e-8, C, device="tpu")
    with pytest.raises(ValueError, match="no CUDA GPU is visible"):
        PlanarOperator((10, 8), 1e-4, 1e-4, 3e-8, 20, C, device="cuda")


_HOLDER = """
import sys, time
from fpscan.service.recon import device
with device.gpu_lock(0) as held:
    print("held", held, flush=True)
    sys.stdin.readline()
"""


def test_the_gpu_lock_admits_one_process_and_nests_in_one() -> None:
    holder = subprocess.Popen([sys.executable, "-c", _HOLDER], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held True"
        with device.gpu_lock(0, wait=False) as held:
            assert held is False  # another process holds it: "auto" goes to the CPU
    finally:
        assert holder.stdin is not None
        holder.stdin.write("\n")
        holder.stdin.flush()
        holder.wait(timeout=60)
    with device.gpu_lock(0, wait=False) as held, device.gpu_lock(0, wait=False) as again:
        assert held and again  # a warm start inside a tv run takes it again


def test_tvs_model_on_the_gpu_branch_gives_the_cpu_branchs_products() -> None:
    """tv's `Model` with its operator pair on ``xp`` (the GPU branch: A, Aᵀ and P there) against
    the compiled CPU branch, on NumPy: the same forward, B = P Aᵀ and residual."""
    from fpscan.physics.forward import forward_points
    from fpscan.service.recon.tv.problem import Model, warm_start, working_record

    rng = np.random.default_rng(6)
    p0 = np.zeros((10, 14, 16))
    p0[4:6, 6:9, 7:10] = 1.0
    positions = _lattice(rng, 14, 16, 1e-4, 0.4)
    axes = ((np.arange(16) - 7.5) * 1e-4, (np.arange(14) - 6.5) * 1e-4)
    al = forward_points(p0, positions=positions, dx=1e-4, dz=1e-4, dt=6e-8, n_t=40, c=C)
    record = working_record(al, 6e-8, C, None, positions, axes, bandwidth=None, dz=1e-4, n_z=10, t0=0.0,
                     whole_record=True)
    warm, centred = warm_start(record, C, None, positions, None, axes, dtype=np.float32, t0=0.0, eps=1e-6,
                                positivity=True, memory_limit=None, progress=None, device="cpu")
    models = [Model(record, warm, C, centred, t0=0.0, eps=1e-6, dtype=np.dtype(np.float32), periodic=False,
                     checkpoint=None, memory_limit=None, device="cpu") for _ in range(2)]
    on_xp = models[1]
    on_xp.op._pair = gpu.OperatorPair(on_xp.op, np)  # the GPU branch, its arrays NumPy's
    x = rng.standard_normal(warm.p0.shape).astype(np.float32)
    r = rng.standard_normal(record.g.shape).astype(np.float32)
    assert _rel(on_xp.forward(x), models[0].forward(x)) <= 2e-6
    assert _rel(on_xp.B(r), models[0].B(r)) <= 2e-6
    Ax = models[0].forward(x)
    assert on_xp.residual(Ax) == pytest.approx(models[0].residual(Ax), rel=1e-6)
