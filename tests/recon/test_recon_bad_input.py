"""Bad input gets a ValueError naming the problem."""
from __future__ import annotations

import numpy as np
import pytest

from fpscan.service.recon import (
    estimate_peak_memory,
    forward_grid,
    kspace_line_recon,
    kspace_plane_recon,
    reconstruct_grid,
    reconstruct_points,
)

DT, DX, C = 20e-9, 50e-6, 1500.0
GOOD = np.random.default_rng(0).standard_normal((32, 8))


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(data=np.full((32, 8), np.nan)), "NaN or inf"),
        (dict(data=np.r_[GOOD[:-1], [[np.inf] * 8]]), "NaN or inf"),
        (dict(data=np.zeros(32)), "dimensions"),
        (dict(data=np.zeros((32, 4, 4, 2))), "dimensions"),
        (dict(data=np.zeros((1, 8))), "at least 2 time samples"),
        (dict(data=np.zeros((32, 0))), "empty"),
        (dict(data=np.array([["a"]])), "numeric"),
        (dict(dx=0.0), "dx"),
        (dict(dx=-1e-4), "dx"),
        (dict(dt=0.0), "dt"),
        (dict(dt=float("nan")), "dt"),
        (dict(c=-1500.0), "c must"),
        (dict(method="spline"), "method"),
        (dict(eps=1e-15), "eps"),
        (dict(eps=0.5), "eps"),
        (dict(dtype=np.int32), "dtype"),
        (dict(upsample=0), "upsample"),
        (dict(n_z=1), "n_z"),
        (dict(dz=0.0), "dz"),
        (dict(dz=5e-324), "dz must be in"),  # the depth rows overflowed int() (OverflowError): the rule's range
        (dict(t0=-1e-9), "t0"),
        (dict(memory_limit=1000), "GiB"),
    ],
)
def test_reconstruct_grid_rejects(kwargs, match):
    args = dict(data=GOOD, dx=DX, dt=DT, c=C)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        reconstruct_grid(args.pop("data"), args.pop("dx"), args.pop("dt"), args.pop("c"), **args)


POS = np.column_stack([np.arange(6) * DX, np.zeros(6)])
AL = np.random.default_rng(1).standard_normal((6, 20))


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(positions=np.r_[POS[:-1], [[np.nan, 0]]]), "NaN or inf"),
        (dict(positions=np.r_[POS[:-1], POS[:1]]), "duplicates"),
        (dict(positions=POS[:5]), "rows"),
        (dict(positions=np.zeros((6, 3))), "shape"),
        (dict(weights=-np.ones(6)), ">= 0"),
        (dict(weights=np.ones(5)), "shape"),
        (dict(weights=np.r_[np.ones(5), np.nan]), "NaN or inf"),
        (dict(alines=np.zeros((6, 20, 2))), "dimensions"),
        (dict(grid=(np.arange(4) * DX, np.arange(3) * DX)), "outside"),
        (dict(grid=(np.array([0, 1, 3.0]) * DX, np.arange(3) * DX)), "regular"),
        (dict(grid=(np.arange(4) * DX,)), "coordinate vector"),
        (dict(eps=1.0), "eps"),
        (dict(dt=-1.0), "dt"),
    ],
)
def test_reconstruct_points_rejects(kwargs, match):
    args = dict(alines=AL, positions=POS, dt=DT, c=C)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        reconstruct_points(args.pop("alines"), args.pop("positions"), args.pop("dt"), args.pop("c"), **args)


@pytest.mark.parametrize("n_points", [40, 512, 513, 900])  # every pair up to 512 points, a k-d tree above
def test_duplicate_positions_are_found_at_any_count(n_points):
    """A duplicate (within 1e-9 of the mask's extent) is refused whichever search finds it; a
    point 1e-6 of the extent away from another is not a duplicate."""
    side = int(np.ceil(np.sqrt(n_points)))
    grid = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:n_points] * DX
    alines = np.random.default_rng(2).standard_normal((n_points, 20))
    dup = grid.copy()
    dup[-1] = dup[n_points // 2] + 1e-12 * DX * side
    with pytest.raises(ValueError, match="duplicates"):
        reconstruct_points(alines, dup, DT, C, weights=np.ones(n_points))
    near = grid.copy()
    near[-1] = near[n_points // 2] + 1e-6 * DX * side
    rec = reconstruct_points(alines, near, DT, C, weights=np.ones(n_points), n_z=4,
                             grid=(np.arange(side) * DX, np.arange(side) * DX))
    assert rec.p0.shape == (4, side, side)


def test_kwave_dropins_reject_bad_options():
    with pytest.raises(ValueError, match="Interp"):
        kspace_line_recon(GOOD, DX, DT, C, interp="spline")
    with pytest.raises(ValueError, match="data_order"):
        kspace_line_recon(GOOD, DX, DT, C, data_order="tz")
    with pytest.raises(ValueError, match="dimensions"):
        kspace_plane_recon(GOOD, DX, DX, DT, C)
    with pytest.raises(ValueError, match="dz"):
        kspace_plane_recon(np.zeros((8, 4, 4)), DX, 0, DT, C)


def test_forward_model_rejects_bad_input():
    with pytest.raises(ValueError, match="NaN"):
        forward_grid(np.full((8, 8), np.nan), DX, DX, DT, 10)
    with pytest.raises(ValueError, match="n_t"):
        forward_grid(np.zeros((8, 8)), DX, DX, DT, 0)
    with pytest.raises(ValueError, match="eps"):
        forward_grid(np.zeros((8, 8)), DX, DX, DT, 10, eps=0)


def test_memory_estimate_grows_with_size_and_halves_with_float32():
    small = estimate_peak_memory(256, 64, 64)
    big = estimate_peak_memory(1024, 226, 226)
    assert big > 40 * small
    f32 = estimate_peak_memory(1024, 226, 226, dtype=np.float32)
    assert 0.4 < f32 / big < 0.6
    # the 226 x 226 x 1024 volume itself is 418 MB in float64: the peak is several times it
    assert 4 * 1024 * 226 * 226 * 8 < big < 20 * 1024 * 226 * 226 * 8


@pytest.mark.parametrize("shape", [(40, 5, 6), (300, 20, 20)])
@pytest.mark.parametrize("dtype", [np.float16, np.float32, np.float64])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("where", [0, 777, -1])
def test_a_single_nan_or_inf_anywhere_is_found_in_every_precision(shape, dtype, bad, where):
    """`checks.finite_array` sums a small array in its own precision and checks a large one's
    exponent bits on every core (120 000 elements: above `fpscan.physics.fft_engine.SMALL_ELEMENTS`):
    one NaN or ±inf anywhere, in float16, float32 or float64, is refused; finite values whose sum
    overflows that precision (float16's 65504, float32's 3.4e38) pass; integers pass unsummed."""
    from fpscan.service.recon.checks import finite_array

    data = np.random.default_rng(1).standard_normal(shape).astype(dtype)
    data.reshape(-1)[where] = bad
    with pytest.raises(ValueError, match="NaN or inf"):
        finite_array("data", data, (3,))
    big = np.full(shape, np.finfo(dtype).max / 2, dtype=dtype)  # finite, its sum is not
    assert finite_array("data", big, (3,)) is big
    tiny = np.full(shape, np.finfo(dtype).smallest_subnormal, dtype=dtype)  # finite, the exponent bits all clear
    assert finite_array("data", tiny, (3,)) is tiny
    ints = np.full(shape, np.iinfo(np.int64).max, dtype=np.int64)
    assert finite_array("data", ints, (3,)) is ints
