"""Fixtures the GP-model tests share."""
import numpy as np
import pytest

from gp_model import HigdonKernel, SquaredExponentialARD


@pytest.fixture(params=["se_ard", "higdon"])
def make_kernel(request):
    """A factory ``make_kernel(d)`` of each kernel family with distinct length scales per input."""
    if request.param == "se_ard":
        return lambda d: SquaredExponentialARD(1.3, np.linspace(0.7, 1.5, d))
    return lambda d: HigdonKernel(1.3, np.linspace(0.3, 0.7, d))
