"""What the refinement steps' tests share: a fitter and a step context on a given cloud."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.refinement.context import Context


@pytest.fixture(scope="module")
def pipeline():
    return rs.Pipeline("lms200")


@pytest.fixture
def context(pipeline):
    """``context(cloud, min_size=10, sigma=None)``: the steps' Context for ``cloud`` with the
    lms200 fitter; ``sigma`` defaults to the lms200 sensor's noise at the cloud's ranges."""

    def make(cloud, min_size=10, sigma=None):
        if sigma is None:
            sigma = pipeline.sensor.noise.sigma(np.where(cloud.valid, cloud.range_image(), np.nan))
        return Context(cloud, pipeline.fitter, np.asarray(sigma, float), min_size)

    return make

