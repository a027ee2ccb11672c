"""The one centred-axis convention (fpscan.physics.axes): x_i = (i - (n - 1)/2)·d, its
lattice-index form and its inverse, against the formula written out by hand."""
from __future__ import annotations

import numpy as np
import pytest

from fpscan.physics.axes import centred_axis, centred_index, centred_positions


@pytest.mark.parametrize("n", [1, 2, 5, 6, 226])
def test_axis_positions_and_index_agree(n):
    d = 6e-5
    x = centred_axis(n, d)
    by_hand = np.array([(i - (n - 1) / 2) * d for i in range(n)])
    np.testing.assert_allclose(x, by_hand, rtol=0, atol=1e-18)
    np.testing.assert_allclose(x, -x[::-1], rtol=0, atol=1e-18)  # symmetric about the optical axis
    idx = np.random.default_rng(n).integers(0, n, size=(4, 3))
    np.testing.assert_array_equal(centred_positions(idx, n, d), x[idx])
    np.testing.assert_allclose(centred_index(x, n, d), np.arange(n), rtol=0, atol=1e-9)
    # half a pitch off a lattice point is half an index off
    np.testing.assert_allclose(centred_index(x + d / 2, n, d), np.arange(n) + 0.5, rtol=0, atol=1e-9)
