"""The planar operator pair: the adjoint is the true adjoint of the forward model (dot
test, every variant), and the forward model is `forward_grid` / `forward_points`."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pylops
import pytest

from fpscan.physics.forward import forward_grid, forward_points
from fpscan.service.recon.operator import PlanarOperator

pytestmark = pytest.mark.long(50)

C, DT = 1500.0, 20e-9
DZ = C * DT
DX = 40e-6
rng = np.random.default_rng(11)


def assert_adjoint(op: PlanarOperator, tol: float = 1e-10) -> None:
    """⟨A x, y⟩ = ⟨x, Aᴴ y⟩ for random x, y, to ``tol`` relative."""
    x = rng.standard_normal(op.ishape)
    y = rng.standard_normal(op.oshape)
    lhs, rhs = np.vdot(op.forward(x), y), np.vdot(x, op.adjoint(y))
    assert abs(lhs - rhs) <= tol * abs(lhs), (lhs, rhs)


def _positions(shape, n=7):
    """Sensors off the grid, some beyond its lateral extent."""
    extent = np.array(shape[1:][::-1], dtype=float) * DX
    return rng.uniform(-0.6, 0.6, (n, len(shape) - 1)) * extent


@pytest.mark.parametrize("periodic", [False, True])
@pytest.mark.parametrize("sensors", ["grid", "points"])
@pytest.mark.parametrize("shape", [(16, 9), (12, 10), (10, 5, 6), (9, 6, 7)], ids=["2d-odd", "2d-even", "3d-even-odd", "3d-odd-even"])
def test_dot_test(shape, sensors, periodic):
    pos = None if sensors == "grid" else _positions(shape)
    for t0 in (0.0, 3e-8):
        op = PlanarOperator(shape, DX, DZ, DT, 14, C, positions=pos, t0=t0, eps=1e-12, periodic=periodic)
        assert_adjoint(op)


def assert_close(a, ref, rtol):
    """Agreement to ``rtol`` of the reference's largest magnitude."""
    assert np.abs(a - ref).max() <= rtol * np.abs(ref).max(), np.abs(a - ref).max() / np.abs(ref).max()


@pytest.mark.parametrize("shape", [(14, 9), (10, 6, 7), (12, 8, 8)])
def test_forward_is_the_forward_model(shape):
    """The operator's own transforms (pruned lateral FFTs, half spectrum, plans made once)
    compute the model of `forward_grid` / `forward_points` (full-size transforms) to the
    NUFFT tolerance."""
    p0 = rng.standard_normal(shape)
    op = PlanarOperator(shape, DX, DZ, DT, 18, C, eps=1e-9)
    assert_close(op.forward(p0), forward_grid(p0, DX, DZ, DT, 18, C, eps=1e-9), 1e-9)
    pos = _positions(shape, 5)
    op = PlanarOperator(shape, DX, DZ, DT, 18, C, positions=pos, t0=2e-8, eps=1e-9)
    assert_close(op.forward(p0), forward_points(p0, DX, DZ, pos, DT, 18, C, t0=2e-8, eps=1e-9), 1e-8)


def test_pylops_operator_matches_and_solves():
    """As a pylops LinearOperator: matvec/rmatvec are forward/adjoint on flat vectors,
    pylops' own dottest passes and a pylops solver (CGLS) reduces the residual."""
    shape = (8, 7)
    op = PlanarOperator(shape, DX, DZ, DT, 10, C, eps=1e-12, periodic=True)
    assert op.shape == (10 * 7, 8 * 7) and op.ishape == shape and op.oshape == (10, 7)
    x = rng.standard_normal(shape)
    np.testing.assert_array_equal(op @ x.ravel(), op.forward(x).ravel())
    assert pylops.utils.dottest(op, *op.shape, rtol=1e-10)
    y = op.forward(x)
    sol = pylops.optimization.basic.cgls(op, y.ravel(), niter=15, tol=0)[0]
    assert np.linalg.norm(op.forward(np.reshape(sol, shape)) - y) <= 1e-2 * np.linalg.norm(y)


def test_float32_and_bad_input():
    op = PlanarOperator((8, 5, 6), DX, DZ, DT, 9, C, dtype=np.float32)
    assert op.forward(np.ones((8, 5, 6))).dtype == np.float32
    assert op.adjoint(np.ones((9, 5, 6))).dtype == np.float32
    with pytest.raises(ValueError, match="p0 must have shape"):
        op.forward(np.ones((8, 6, 5)))
    with pytest.raises(ValueError, match="data contains NaN"):
        op.adjoint(np.full((9, 5, 6), np.nan))
    with pytest.raises(ValueError, match="positions must have shape"):
        PlanarOperator((8, 5), DX, DZ, DT, 9, C, positions=np.zeros((3, 2)))
    with pytest.raises(ValueError, match="dt must be"):
        PlanarOperator((8, 5), DX, DZ, -1.0, 9, C)
    with pytest.raises(ValueError, match="dtype"):
        PlanarOperator((8, 5), DX, DZ, DT, 9, C, dtype=np.complex64)


# -- free space at the image's edge: the padded model against the analytic field ------------
SIGMA = 1.5 * DX  # Gaussian source: its band limit at the grid's Nyquist is exp(-(1.5π)²/2) ~ 1e-5


def gaussian_p0(shape, centre):
    """p0 = exp(-|r - centre|² / 2σ²) sampled on the operator's grid (rows z = j DZ, lateral
    coordinates centred), and the centre's coordinates (x, y, z) in m."""
    n_z, lat = shape[0], shape[1:]
    axes = [(np.arange(n) - (n - 1) / 2) * DX for n in lat]  # (y,) x
    z = np.arange(n_z) * DZ
    cz, *clat = centre
    pos = [a[i] for a, i in zip(axes, clat)]
    r2 = (z[:, None] - z[cz]) ** 2 if len(lat) == 1 else (z[:, None, None] - z[cz]) ** 2
    if len(lat) == 1:
        r2 = r2 + (axes[0][None, :] - pos[0]) ** 2
    else:
        r2 = r2 + (axes[0][None, :, None] - pos[0]) ** 2 + (axes[1][None, None, :] - pos[1]) ** 2
    return np.exp(-r2 / (2 * SIGMA**2)), pos[::-1] + [z[cz]]


def field_3d(r, t):
    """Free-space pressure at distance r (m) and time t (s) of p0 = exp(-r²/2σ²), p_t = 0 in 3-D:
    r p(r, t) = ½ [(r - ct) f(r - ct) + (r + ct) f(r + ct)] (d'Alembert for r p, f even)."""
    f = lambda s: np.exp(-s**2 / (2 * SIGMA**2))
    return ((r - C * t) * f(r - C * t) + (r + C * t) * f(r + C * t)) / (2 * r)


def field_2d(r, t):
    """The same in 2-D by its Hankel representation p(r, t) = σ² ∫ k e^{-k²σ²/2} J0(k r) cos(c k t) dk."""
    from scipy.special import j0

    k = np.linspace(0, 9 / SIGMA, 6001)
    integrand = k * np.exp(-((k * SIGMA) ** 2) / 2) * j0(np.multiply.outer(r, k)) * np.cos(C * np.multiply.outer(t, k))
    return SIGMA**2 * np.trapezoid(integrand, k, axis=-1)


def oracle(sensors, source, n_t, t0):
    """Analytic A-lines (n_sensors, n_t) at sensor coordinates (n, 1|2) on z = 0."""
    t = t0 + DT * np.arange(n_t)
    d = sensors.shape[1]
    lat = np.asarray(source[:d])
    r = np.sqrt(((sensors - lat) ** 2).sum(1) + source[-1] ** 2)
    fn = field_2d if d == 1 else field_3d
    return fn(np.repeat(r[:, None], n_t, 1), np.broadcast_to(t, (len(r), n_t)))


def test_analytic_field_oracles_start_from_p0():
    """The oracles themselves: at t = 0 both give p0(r) (the 2-D quadrature to 1e-6)."""
    r = np.linspace(0.2, 3, 9) * 1e-3
    np.testing.assert_allclose(field_2d(r, np.zeros_like(r)), np.exp(-r**2 / (2 * SIGMA**2)), atol=1e-6)
    np.testing.assert_allclose(field_3d(r, np.zeros_like(r)), np.exp(-r**2 / (2 * SIGMA**2)), atol=1e-12)


@pytest.mark.parametrize("t0", [0.0, 1e-8])
@pytest.mark.parametrize("sensors", ["grid", "points"])
@pytest.mark.parametrize("shape", [(22, 24), (22, 20, 20)], ids=["2d", "3d"])
def test_edge_source_matches_free_space(shape, sensors, t0):
    """A smooth source touching the image's lateral edge (and, in 3-D, its corner) and its
    deepest row: the zero-padded model gives the analytic free-space A-lines at every
    sensor to 1e-3 of their peak, over a record long enough for the source's periodic
    images to reach the far sensors if the padding were short (periodic: far off)."""
    n_t = 56
    edge = int(np.ceil(4.5 * SIGMA / DX))  # the source's 4.5σ support touches the edges
    centre = (shape[0] - 1 - int(np.ceil(4.5 * SIGMA / DZ)),) + tuple(n - 1 - edge for n in shape[1:])
    p0, source = gaussian_p0(shape, centre)
    lat = [(np.arange(n) - (n - 1) / 2) * DX for n in shape[1:]]  # (y,) x
    if sensors == "grid":
        mesh = np.meshgrid(*lat[::-1], indexing="xy") if len(lat) == 2 else [lat[0]]
        pos = np.column_stack([m.ravel() for m in mesh])  # (x[, y]) in the grid's C order
        posarg = None
    else:  # the far edge, the far corner and inside; two beyond the image
        ext = np.array([n * DX / 2 for n in shape[1:][::-1]])
        pos = np.array([-ext, 0.9 * ext, [-ext[0], 0.5 * ext[-1]][: len(ext)], -1.3 * ext, 0.2 * ext])
        posarg = pos
    expect = oracle(pos, source, n_t, t0)
    peak = np.abs(expect).max()
    for periodic, bound in ((False, 1e-3), (True, None)):
        op = PlanarOperator(shape, DX, DZ, DT, n_t, C, positions=posarg, t0=t0, eps=1e-9, periodic=periodic)
        got = op.forward(p0)
        got = got.reshape(n_t, -1).T if posarg is None else got
        err = np.abs(got - expect).max() / peak
        if bound is not None:
            assert err <= bound, err
        else:  # the test can fail: without padding the wrap-around is plain
            assert err > 30 * 1e-3, err


@pytest.mark.parametrize("sensors", ["grid", "points"])
@pytest.mark.parametrize("shape", [(16, 9), (10, 6, 7), (12, 8, 8)], ids=["2d", "3d", "3d-square"])
def test_dot_test_float32(shape, sensors):
    """In float32 the transforms run in complex64 (and the lateral NUFFTs in single
    precision): still each other's adjoint, to rounding (1e-4)."""
    pos = None if sensors == "grid" else _positions(shape)
    op = PlanarOperator(shape, DX, DZ, DT, 14, C, positions=pos, t0=2e-8, dtype=np.float32)
    x = rng.standard_normal(op.ishape).astype(np.float32)
    y = rng.standard_normal(op.oshape).astype(np.float32)
    ax, aty = op.forward(x), op.adjoint(y)
    assert ax.dtype == aty.dtype == np.float32
    lhs, rhs = np.vdot(ax.astype(np.float64), y), np.vdot(x.astype(np.float64), aty)
    assert abs(lhs - rhs) <= 1e-4 * abs(lhs), (lhs, rhs)
    # and float32 computes the float64 model to single precision
    op64 = PlanarOperator(shape, DX, DZ, DT, 14, C, positions=pos, t0=2e-8)
    assert_close(ax, op64.forward(x), 1e-4)
    assert_close(aty, op64.adjoint(y), 1e-4)


def test_padding_reaches_exactly_as_far_as_the_record():
    """The working grid's gap between the image and its periodic copy covers the record's
    reach c·t_last (the exactness rule), and no smaller fast length would: the padding
    is the smallest fast grid the rule allows (fast: largest prime factor <= 7, the DCT's
    2 (N_z - 1) and x's real FFT <= 5)."""
    from fpscan.physics.fast_lengths import largest_prime_factor

    for n_t, lat, dx in ((64, (40,), DX), (200, (33, 33), 60e-6), (150, (20, 31), 25e-6), (90, (48, 48), 100e-6)):
        shape = (n_t,) + lat
        op = PlanarOperator(shape, dx, DZ, DT, n_t, C)
        n_z2, n_y2, n_x2 = op.padded_shape
        reach = C * (n_t - 1) * DT
        square = len(lat) == 2 and n_y2 == n_x2
        for n, n2, p in zip((1,) * (2 - len(lat)) + lat, (n_y2, n_x2), (5 if square else 7, 5)):
            if n == 1:
                assert n2 == 1
                continue
            assert (n2 - n) * dx >= reach, (shape, op.padded_shape)
            assert (n2 - n) % 2 == 0 and largest_prime_factor(n2) <= p
            # no smaller admissible length (a square grid may pad its shorter need up to the longer)
            need = (n - 1) * dx + C * (n_t - 0.5) * DT + 2 * max(dx, DZ)  # half a sample, two pitches: the margin
            smaller = [m for m in range(n, n2) if (m - n) % 2 == 0 and largest_prime_factor(m) <= p
                       and (m - 1) * dx >= need]
            assert smaller == [] or square, (shape, n2, smaller)
        assert 2 * (n_z2 - 1) * DZ >= reach + (n_t - 1) * DZ and largest_prime_factor(2 * (n_z2 - 1)) <= 5
        need_z = C * (n_t - 0.5) * DT + DZ + (n_t - 1) * DZ  # depth: half a sample and a pitch of margin
        assert not [k for k in range(n_t, n_z2) if largest_prime_factor(2 * (k - 1)) <= 5
                    and 2 * (k - 1) * DZ >= need_z], (shape, n_z2)


@pytest.mark.parametrize("sensors", ["grid", "points", "lattice"])
@pytest.mark.parametrize("shape", [(12, 8, 9), (52, 8, 9)], ids=["n_z<n_t", "n_z>n_t"])
def test_chunked_and_batched_steps_give_the_same_pair(sensors, shape):
    """The depth and temporal steps run on chunks of k-space columns and the point NUFFTs on
    batches of time samples (16; here 40 samples: two whole batches and a remainder): any
    chunking computes the same forward and adjoint, which stay each other's adjoint. A step's
    input and output k-space share one array (rows of the image and of the data, fewer
    either way), so a chunk that wrote over columns another still reads would show here."""
    n_t = 40
    if sensors == "lattice":  # on the image's nodes: the exact lateral DFTs
        ix, iy = rng.choice(shape[2], 9), rng.choice(shape[1], 9)
        pos = np.unique(np.column_stack([(ix - (shape[2] - 1) / 2) * DX, (iy - (shape[1] - 1) / 2) * DX]), axis=0)
    else:
        pos = None if sensors == "grid" else _positions(shape, 9)
    whole = PlanarOperator(shape, DX, DZ, DT, n_t, C, positions=pos, eps=1e-12)
    calls = []
    chunked = PlanarOperator(shape, DX, DZ, DT, n_t, C, positions=pos, eps=1e-12, chunk_elements=2000,
                             checkpoint=lambda: calls.append(1))
    assert len(whole._chunks) == 1 and len(chunked._chunks) > 5
    assert (chunked._nodes is not None) == (sensors == "lattice")
    p0, g = rng.standard_normal(shape), rng.standard_normal(whole.oshape)
    assert_close(chunked.forward(p0), whole.forward(p0), 1e-12)
    n_forward = len(calls)
    assert_close(chunked.adjoint(g), whole.adjoint(g), 1e-12)
    assert_adjoint(chunked)
    # a checkpoint after every chunk (and every batch of point NUFFTs): a cancel is heard
    # within one chunk's work, however long the whole application takes
    batches = 3 if sensors != "grid" else 0
    assert n_forward >= len(chunked._chunks) + batches
    assert len(calls) - n_forward >= len(chunked._chunks) + batches
    with pytest.raises(ValueError, match="chunk_elements"):
        PlanarOperator(shape, DX, DZ, DT, n_t, C, chunk_elements=0)


def test_a_checkpoint_that_raises_abandons_the_application():
    """The checkpoint may raise (a cancelled job): the exception leaves `forward` at once,
    before the remaining chunks run."""
    shape = (12, 8, 9)
    seen = []

    class Stop(Exception):
        pass

    def checkpoint():
        seen.append(1)
        if len(seen) == 3:
            raise Stop

    op = PlanarOperator(shape, DX, DZ, DT, 40, C, eps=1e-9, chunk_elements=2000, checkpoint=checkpoint)
    with pytest.raises(Stop):
        op.forward(rng.standard_normal(shape))
    assert len(seen) == 3 < len(op._chunks)


def _lattice_positions(shape, n=9, beyond=1):
    """n sensors on the image's lateral grid nodes (the scanner's lattice), one of them
    ``beyond`` pitches outside the image (the working grid still holds it)."""
    lat = [(np.arange(m) - (m - 1) / 2) * DX for m in shape[1:][::-1]]  # x[, y]
    pick = np.random.default_rng(5)
    pos = np.column_stack([a[pick.integers(0, len(a), n)] for a in lat])
    pos[0, 0] = lat[0][-1] + beyond * DX
    return np.unique(pos, axis=0)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("periodic", [False, True])
@pytest.mark.parametrize("shape", [(16, 9), (12, 10), (10, 5, 6), (9, 6, 7), (12, 8, 8)])
def test_sensors_on_the_lattice_take_exact_lateral_transforms(shape, periodic, dtype):
    """Sensors on grid nodes skip the lateral NUFFTs (exact DFTs on the rows that hold
    sensors): the pair is still each other's adjoint, and the forward is the model of
    `forward_points` (finufft's type-2 NUFFT, an independent path; free space) and of the
    grid operator read at those nodes (periodic: the same working grid; in free space the two
    pad differently, and a random p0's sharp-edged tails differ by a few per cent late in
    the record)."""
    pos = _lattice_positions(shape, beyond=0 if periodic else 1)
    op = PlanarOperator(shape, DX, DZ, DT, 14, C, positions=pos, t0=2e-8, eps=1e-12, periodic=periodic,
                        dtype=dtype)
    assert op._nodes is not None and not op._plans  # the exact path, no NUFFT plans
    assert_adjoint(op, 1e-10 if dtype == np.float64 else 2e-5)
    p0 = rng.standard_normal(shape)
    got = op.forward(p0)
    assert got.shape == (len(pos), 14) and got.dtype == dtype
    tol = 1e-9 if dtype == np.float64 else 2e-5
    if not periodic:
        assert_close(got, forward_points(p0, DX, DZ, pos, DT, 14, C, t0=2e-8, eps=1e-12), tol)
        return
    inside = np.all(np.abs(pos) <= (np.array(shape[1:][::-1]) - 1) / 2 * DX + 1e-12, axis=1)
    grid = PlanarOperator(shape, DX, DZ, DT, 14, C, t0=2e-8, eps=1e-12, periodic=periodic, dtype=dtype)
    on_grid = grid.forward(p0).reshape(14, -1)  # (n_t, n_y n_x), C order
    ix = np.rint(pos[:, 0] / DX + (shape[-1] - 1) / 2).astype(int)
    iy = np.rint(pos[:, 1] / DX + (shape[1] - 1) / 2).astype(int) if len(shape) == 3 else 0 * ix
    assert_close(got[inside], on_grid[:, (iy * shape[-1] + ix)[inside]].T, tol)


def test_sensors_off_the_lattice_keep_the_nufft():
    pos = _lattice_positions((10, 5, 6))
    pos[1, 1] += 0.3 * DX
    op = PlanarOperator((10, 5, 6), DX, DZ, DT, 14, C, positions=pos)
    assert op._nodes is None and op._plans


ADJOINT_PEAK_SCRIPT = r"""
import json
import numpy as np
from fpscan.service.recon.operator import PlanarOperator

def rss():
    with open("/proc/self/status") as fh:
        return {l.split(":")[0]: int(l.split()[1]) * 1024 for l in fh if l.startswith(("VmRSS", "VmHWM"))}

n_z, n = 1024, 128
op = PlanarOperator((n_z, n, n), 1e-4, 1e-4, 1e-4 / 1500, n_z, periodic=True, dtype=np.float32,
                    chunk_elements=1 << 14)
data = np.random.default_rng(0).standard_normal(op.oshape).astype(np.float32)
want = op.adjoint(data)  # compiles and plans; its image is kept to compare (its k-space stays busy)
with open("/proc/self/clear_refs", "w") as fh:
    fh.write("5")
before = rss()["VmRSS"]
got = op.adjoint(data)
peak = rss()["VmHWM"] - before
print(json.dumps({"peak": peak, "image": got.nbytes, "kspace": n_z * n * (n // 2 + 1) * 8,
                  "same": bool(np.array_equal(got, want)), "apart": not np.shares_memory(got, want)}))
"""


@pytest.mark.skipif(not os.path.exists("/proc/self/clear_refs"), reason="needs Linux's /proc")
def test_the_adjoint_writes_its_image_over_its_k_space():
    """The adjoint's peak is its k-space, not the k-space and the image beside it: the image
    is written over the k-space's first rows. A periodic operator in float32 (k-space about as
    large as the image), tiny chunks: peak RSS above the RSS before, in a fresh interpreter
    (/proc/self/clear_refs resets the peak), while the first application's image is still held
    (its k-space is not lent again: the second image lies apart from it)."""
    r = subprocess.run([sys.executable, "-c", ADJOINT_PEAK_SCRIPT], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    m = json.loads(r.stdout.strip().splitlines()[-1])
    assert m["same"] and m["apart"], m
    # the lateral blocks' transforms add ~12 MB beside the 68 MB k-space; an image beside it 64 MB more
    assert m["peak"] < m["kspace"] + 0.5 * m["image"], m
