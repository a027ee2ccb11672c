"""The temporal NUFFT's kernel taps by Horner's rule match the ES kernel formula."""
import numpy as np
import pytest

from driver.physics.nufft import kernel_params, kernel_polynomials


@pytest.mark.parametrize("eps", [1e-2, 1e-4, 1e-6, 1e-9, 1e-12, 1e-14])
def test_tap_polynomials_match_the_kernel_to_a_fraction_of_eps(eps):
    w, beta = kernel_params(eps)
    coef = kernel_polynomials(w, beta)
    assert coef.shape[0] == w
    x = np.linspace(0.0, 1.0, 2001, endpoint=False)  # offset of the first tap in [0, 1)
    for k in range(w):
        u = (x + k - 0.5 * w) * (2.0 / w)
        phi = np.exp(beta * (np.sqrt(1.0 - u * u) - 1.0))  # the ES kernel itself
        approx = np.polyval(coef[k], 2.0 * x - 1.0)
        assert np.max(np.abs(approx - phi)) <= max(eps / 10, 1e-14), (k, np.max(np.abs(approx - phi)))
