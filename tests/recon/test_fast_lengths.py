"""Fast lengths everywhere: every FFT/DCT length a reconstruction or the
model-based operator chooses has no prime factor above 7, for a range of sizes. The
lengths come from the functions the methods themselves call (`transform_lengths`), and
a small reconstruction checks that what runs is what they report. k-Wave's modes keep
k-Wave's own lengths (their documented exception)."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.fft

from fpscan.physics import nufft
from fpscan.physics.fast_lengths import fast_dct1_rows, fast_length, largest_prime_factor
from fpscan.service.recon import kwave, planar
from fpscan.service.recon.operator import PlanarOperator

C, DT, DX = 1500.0, 25e-9, 60e-6
N_T = range(50, 1101)
LATERAL = range(30, 261)


def lpf_by_trial_division(n: int) -> int:
    """Independent oracle: the largest prime p dividing n, by scanning candidates down."""
    for p in range(n, 1, -1):
        if n % p == 0 and all(p % q for q in range(2, int(p**0.5) + 1)):
            return p
    return 1


def is_fast(n: int) -> bool:
    return largest_prime_factor(n) <= 7


def test_largest_prime_factor_and_fast_length_against_independent_oracles():
    for n in range(1, 600):
        assert largest_prime_factor(n) == lpf_by_trial_division(n)
    for n in range(1, 3000):
        real = fast_length(n, real=True)
        assert real == scipy.fft.next_fast_len(n, real=True)
        m = fast_length(n)
        assert m >= n and largest_prime_factor(m) <= 7
        assert all(largest_prime_factor(k) > 7 for k in range(n, m))  # the smallest one
        e = fast_length(n, even=True)
        assert e % 2 == 0 and largest_prime_factor(e) <= 7
        assert all(k % 2 or largest_prime_factor(k) > 7 for k in range(n, e))
        k = fast_dct1_rows(n)
        assert k >= max(n, 2) and largest_prime_factor(2 * (k - 1)) <= 5
    with pytest.raises(ValueError, match="n must be"):
        fast_length(0)


@pytest.mark.parametrize("method", planar.GRID_METHODS)
def test_planar_temporal_and_depth_lengths_are_fast_for_every_n_t(method):
    for n_t in N_T:
        lengths = planar.transform_lengths((n_t, 64), DT, C, method=method)
        assert is_fast(lengths["temporal"][0]), (n_t, lengths)
        assert is_fast(lengths["depth"][0]), (n_t, lengths)
        assert lengths["temporal"][0] >= (2 * n_t if method == "ner" else 2 * n_t - 1)
        assert lengths["depth"][0] >= 2 * (n_t - 1)


def test_planar_depth_lengths_are_fast_for_other_depth_grids():
    for n_t in range(50, 1101, 7):
        for dz, n_z in ((0.5 * C * DT, None), (2.0 * C * DT, None), (C * DT, 3 * n_t + 1), (1.3 * C * DT, 17)):
            assert is_fast(planar.transform_lengths((n_t, 40), DT, C, dz=dz, n_z=n_z)["depth"][0]), (n_t, dz, n_z)


@pytest.mark.parametrize("upsample", range(1, 9))
def test_planar_lateral_lengths_are_fast_2d_and_3d(upsample):
    for n in LATERAL:
        two = planar.transform_lengths((64, n), DT, C, upsample=upsample)
        assert two["lateral"][0] >= n
        assert all(is_fast(m) for m in two["lateral"] + two["output"]), (n, two)
        for n_y in (n, n + 1, max(2, n // 2), 31):
            for square in (True, False):
                three = planar.transform_lengths((64, n_y, n), DT, C, upsample=upsample, square=square)
                assert three["lateral"][0] >= n_y and three["lateral"][1] >= n
                assert all(is_fast(m) for m in three["lateral"] + three["output"]), (n_y, n, square, three)


@pytest.mark.parametrize("shape", [(37, 29), (53, 31, 26)])
@pytest.mark.parametrize("method", ["ner", "linear", "cubic"])
def test_reconstructions_run_the_lengths_reported(shape, method):
    """params of a real run (grid and lattice points) against `transform_lengths`."""
    rng = np.random.default_rng(5)
    data = rng.standard_normal(shape)
    lengths = planar.transform_lengths(shape, DT, C, method=method)
    rec = planar.reconstruct_grid(data, DX, DT, C, method=method, dz=C * DT)
    assert 2 * (rec.params["depth_rows"] - 1) == lengths["depth"][0]
    lateral = tuple(rec.params["lateral_transform"])
    assert lateral[-len(lengths["lateral"]):] == lengths["lateral"]
    if method != "cubic":  # the grid the temporal step plans
        assert nufft.make_grid(shape[0], planar._KIND[method], 1e-6).L == lengths["temporal"][0]
    else:
        assert lengths["temporal"][0] == fast_length(2 * shape[0] - 1)
    # NEDNER on the lattice of the same grid: the same lengths
    if len(shape) == 2:
        pos = ((np.arange(shape[1]) - (shape[1] - 1) / 2) * DX)[:, None]
    else:
        yy, xx = np.meshgrid(np.arange(shape[1]) * DX, np.arange(shape[2]) * DX, indexing="ij")
        pos = np.column_stack([xx.ravel(), yy.ravel()])
    alines = data.reshape(shape[0], -1).T
    pts = planar.reconstruct_points(alines, pos, DT, C, method=method, dz=C * DT)
    assert pts.params["depth_rows"] == rec.params["depth_rows"]
    assert tuple(pts.params["lateral_transform"])[-len(lengths["lateral"]):] == lengths["lateral"]


def test_model_based_operator_padding_is_fast():
    for n_t in range(50, 1101, 9):
        for n_x in (30, 64, 113, 226, 257):
            op = PlanarOperator((n_t, n_x), DX, C * DT, DT, n_t, C)
            lengths = op.transform_lengths()
            assert all(is_fast(m) for m in lengths["lateral"] + lengths["depth"] + lengths["temporal"]), \
                (n_t, n_x, lengths)
            n_z2, _, n_x2 = op.padded_shape
            assert n_z2 >= n_t and n_x2 >= n_x and (n_x2 - n_x) % 2 == 0
    for n_y, n_x in ((30, 30), (64, 57), (113, 226), (259, 260)):
        for positions in (None, np.array([[0.0, 0.0], [40 * DX, -3 * DX]])):
            op = PlanarOperator((263, n_y, n_x), DX, C * DT, DT, 263, C, positions=positions)
            lengths = op.transform_lengths()
            assert all(is_fast(m) for m in lengths["lateral"] + lengths["depth"] + lengths["temporal"]), \
                (n_y, n_x, lengths)
            assert (op.padded_shape[1] - n_y) % 2 == 0 and (op.padded_shape[2] - n_x) % 2 == 0
    # depth 263, 519, 1031 -> DCT lengths of 524, 1036, 2060 before
    for n_z in (263, 519, 1031):
        op = PlanarOperator((n_z, 40), DX, C * DT, DT, n_z, C)
        assert is_fast(op.transform_lengths()["depth"][0])


def test_kwave_modes_keep_kwaves_mirrored_length():
    """The documented exception: k-Wave's grids are its definition (its reference data
    are matched to 5e-8 by tests/recon/test_recon_kwave.py)."""
    for n_t in (50, 256, 1024, 3519):
        assert kwave.transform_lengths((n_t, 64)) == {"lateral": (64,), "temporal": (2 * n_t - 1,),
                                                       "depth": (2 * n_t - 1,)}
    assert kwave.transform_lengths((20, 30, 31))["lateral"] == (30, 31)
    with pytest.raises(ValueError, match="data_shape"):
        kwave.transform_lengths((1, 30))


def test_model_based_preconditioner_lengths_are_fast():
    """tv's preconditioner P (its DCT-II on every axis of the image, each iteration) runs on
    the image zero-padded to fast real lengths: at the paper's 1024 × 226² its transforms took
    2.08 s on axes of 226 = 2·113, against 0.57 s at 1024 × 240²."""
    from fpscan.service.recon.tv import preconditioner

    for n in LATERAL:
        for shape in ((n, n), (3, 2, n), (2, n, 3)):
            P = preconditioner.ner_weight(shape, DX, C * DT)
            assert all(is_fast(m) and m >= k for m, k in zip(P.shape, shape)), (shape, P.shape)
    for n_z in range(50, 1101, 9):
        assert is_fast(preconditioner.ner_weight((n_z, 4), DX, C * DT).shape[0]), n_z
