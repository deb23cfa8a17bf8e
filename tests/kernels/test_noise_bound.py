"""The chi-square bound of a fit's rms under pure noise (kernels.linalg.noise_rms_bound),
shared by the fitter's plane floor and the refinement's noise test."""

import numpy as np
import pytest

from rangeseg_o3d.fitting.robust import CHI_SQUARE_SIGMAS, beyond_noise
from rangeseg_o3d.kernels.linalg import NOISE_CHI2_SIGMAS, noise_rms_bound, plane_tolerance


@pytest.mark.parametrize("dof", [20, 100, 1000])
def test_bound_holds_for_gaussian_noise_at_its_stated_rate(dof):
    rng = np.random.default_rng(dof)
    sigma = 0.003
    rms = np.sqrt((rng.normal(0.0, sigma, (20000, dof)) ** 2).mean(axis=1))
    # 3 deviations up: the chi-square tail beyond it is 0.2-0.7 % for 20-1000 dof
    assert np.mean(rms > noise_rms_bound(sigma, float(dof), 3.0)) < 0.01
    # 1 deviation up: about the normal law's 16 % (the chi-square's skew moves it a little)
    assert 0.10 < np.mean(rms > noise_rms_bound(sigma, float(dof), 1.0)) < 0.20


def test_bound_values_and_degenerate_dof():
    assert noise_rms_bound(0.002, 1000.0, 3.0) == pytest.approx(0.002 * np.sqrt(1 + 3 * np.sqrt(0.002)))
    # no degrees of freedom left: treated as one, never a division by zero
    assert noise_rms_bound(0.002, 0.0, 3.0) == noise_rms_bound(0.002, 1.0, 3.0)
    assert noise_rms_bound(0.002, -5.0, 3.0) == noise_rms_bound(0.002, 1.0, 3.0)


def test_plane_floor_and_refinement_test_use_the_one_bound():
    for n in (10, 57, 4000):
        assert plane_tolerance(0.0, 0.002, n) == pytest.approx(
            noise_rms_bound(0.002, n - 3.0, NOISE_CHI2_SIGMAS), rel=1e-12)
        edge = noise_rms_bound(0.002, float(n), CHI_SQUARE_SIGMAS)
        assert not beyond_noise(edge * (1 - 1e-9), 0.002, n)
        assert beyond_noise(edge * (1 + 1e-9), 0.002, n)
