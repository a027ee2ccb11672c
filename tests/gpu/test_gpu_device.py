"""The GPU path against the CPU kernels on the same data: NER, NEDNER, the operator
pair and tv, float32 on both, plus the device rules (fallback, lock, params). Runs only where
CuPy sees a CUDA device (tests/gpu/conftest.py)."""
from __future__ import annotations

import numpy as np
import pytest

from fpscan.physics.forward import forward_points
from fpscan.service.recon import device
from fpscan.service.recon.operator import PlanarOperator
from fpscan.service.recon.planar import reconstruct_grid, reconstruct_points
from fpscan.service.recon.tv import reconstruct_tv

C, DT, DX = 1500.0, 2e-8, 6e-5


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


def _cc(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(a.ravel(), b.ravel())[0, 1])


@pytest.fixture(scope="module")
def scene() -> dict:
    """A 3-D scene: three balls' A-lines on a 48² lattice (every node), 160 samples."""
    rng = np.random.default_rng(3)
    shape = (40, 48, 48)
    p0 = np.zeros(shape)
    for z, y, x, r in ((12, 20, 24, 3), (25, 30, 18, 4), (30, 14, 33, 2)):
        zz, yy, xx = np.ogrid[: shape[0], : shape[1], : shape[2]]
        p0[(zz - z) ** 2 + (yy - y) ** 2 + (xx - x) ** 2 <= r * r] = 1.0
    axis = (np.arange(48) - 23.5) * DX
    X, Y = np.meshgrid(axis, axis)
    pos = np.stack([X.ravel(), Y.ravel()], 1)
    al = forward_points(p0, positions=pos, dx=DX, dz=DX, dt=DT, n_t=160, c=C)
    al = al + 0.01 * np.abs(al).max() * rng.standard_normal(al.shape)
    grid_data = np.ascontiguousarray(al.T.reshape(160, 48, 48))
    return dict(p0=p0, pos=pos, al=al, grid=grid_data, axis=axis)


def test_ner_gpu_matches_cpu(scene: dict) -> None:
    for ups in (1, 2):
        cpu = reconstruct_grid(scene["grid"], DX, DT, C, dtype=np.float32, upsample=ups, device="cpu")
        gpu = reconstruct_grid(scene["grid"], DX, DT, C, dtype=np.float32, upsample=ups, device="cuda")
        assert gpu.params["device"] == "cuda" and cpu.params["device"] == "cpu"
        assert gpu.p0.dtype == np.float32 and gpu.p0.shape == cpu.p0.shape
        assert _rel(gpu.p0, cpu.p0) <= 1e-4


def test_nedner_gpu_matches_cpu(scene: dict) -> None:
    rng = np.random.default_rng(4)
    keep = rng.random(len(scene["pos"])) < 0.3
    for pos in (scene["pos"][keep], scene["pos"][keep] + rng.uniform(-0.3, 0.3, (keep.sum(), 2)) * DX):
        kw = dict(dtype=np.float32, grid=(scene["axis"], scene["axis"]), n_z=40)
        cpu = reconstruct_points(scene["al"][keep], pos, DT, C, device="cpu", **kw)
        gpu = reconstruct_points(scene["al"][keep], pos, DT, C, device="cuda", **kw)
        assert gpu.params["device"] == "cuda"
        assert _rel(gpu.p0, cpu.p0) <= 1e-4


def test_operator_pair_gpu_matches_cpu(scene: dict) -> None:
    rng = np.random.default_rng(5)
    keep = rng.random(len(scene["pos"])) < 0.2
    for positions, band in ((None, None), (scene["pos"][keep], None), (scene["pos"][keep], 8e6)):
        kw = dict(positions=positions, band=band, dtype=np.float32)
        cpu = PlanarOperator((40, 48, 48), DX, DX, DT, 160, C, device="cpu", **kw)
        gpu = PlanarOperator((40, 48, 48), DX, DX, DT, 160, C, device="cuda", **kw)
        assert gpu.device == "cuda"
        x = rng.standard_normal(cpu.ishape).astype(np.float32)
        y = rng.standard_normal(cpu.oshape).astype(np.float32)
        assert _rel(gpu.forward(x), cpu.forward(x)) <= 1e-4
        assert _rel(gpu.adjoint(y), cpu.adjoint(y)) <= 1e-4
        lhs, rhs = np.vdot(gpu.forward(x), y), np.vdot(x, gpu.adjoint(y))
        assert abs(lhs - rhs) <= 1e-4 * abs(rhs)


def test_tv_gpu_matches_cpu_at_the_same_lambda_and_iterations(scene: dict) -> None:
    rng = np.random.default_rng(6)
    keep = rng.random(len(scene["pos"])) < 0.15
    kw = dict(positions=scene["pos"][keep], grid=(scene["axis"], scene["axis"]), dtype=np.float32, lam=None,
              max_iter=40, tol=0.0)
    cpu = reconstruct_tv(scene["al"][keep], DT, C, device="cpu", **kw)
    gpu = reconstruct_tv(scene["al"][keep], DT, C, device="cuda", lam=cpu.params["lam"],
                         **{k: v for k, v in kw.items() if k != "lam"})
    assert gpu.params["device"] == "cuda" and gpu.params["iterations"] == cpu.params["iterations"]
    assert _cc(gpu.p0, cpu.p0) >= 0.9999


def test_auto_picks_the_gpu_and_records_it(scene: dict) -> None:
    r = reconstruct_grid(scene["grid"], DX, DT, C, dtype=np.float32)
    assert r.params["device"] == "cuda" and r.params["device_name"]


def test_a_gpu_out_of_memory_falls_back_or_fails_with_the_reason(scene: dict) -> None:
    import cupy

    pool = cupy.get_default_memory_pool()
    device.release()
    pool.set_limit(size=4 << 20)  # 4 MiB: the inversion's first large array fails
    try:
        r = reconstruct_grid(scene["grid"], DX, DT, C, dtype=np.float32, device="auto")
        assert r.params["device"] == "cpu" and "OutOfMemory" in r.params["device_fallback"]
        with pytest.raises(device.GpuError, match="OutOfMemory"):
            reconstruct_grid(scene["grid"], DX, DT, C, dtype=np.float32, device="cuda")
    finally:
        pool.set_limit(size=0)
    assert reconstruct_grid(scene["grid"], DX, DT, C, dtype=np.float32, device="cuda").params["device"] == "cuda"


def test_a_job_too_large_for_the_gpu_is_refused_or_sent_to_the_cpu() -> None:
    free = device.cuda_devices()[0]["memory_free"]
    with pytest.raises(ValueError, match="GiB of GPU memory"):
        device.choose("cuda", 2 * free)
    assert device.choose("auto", 2 * free) == "cpu"
    assert device.choose("auto", 1 << 20) == "cuda"
