"""The native (C, Python-free) RGBlimp hybrid FMU (fmu_src/rgblimp_hybrid/native.py): the native
FMU contract and the RGBlimp FMUs' interface and step, with the case of the pythonfmu hybrid of the
same model (tests/fmu_src/rgblimp_hybrid/test_pythonfmu.py compares both with the Python free run
over a longer flight)."""
from __future__ import annotations

from dataclasses import replace

import pytest

from fmu_src.rgblimp_hybrid.native import MODEL_SOURCE
from tests.fmu_src.contract import NativeFmuContract
from tests.fmu_src.rgblimp_hybrid.contract import hybrid_case
from tests.fmu_src.rgblimp_rkgp.contract import RGBlimpRkgpContract


@pytest.fixture(scope="module")
def case(native_rgblimp_hybrid_fmu, rgblimp_hybrid_fmu, hybrid_trained, hybrid_reference):
    return replace(hybrid_case(native_rgblimp_hybrid_fmu, hybrid_trained, hybrid_reference),
                   native_of=rgblimp_hybrid_fmu, model_source=MODEL_SOURCE)


class TestNativeRGBlimpHybridFmu(NativeFmuContract, RGBlimpRkgpContract):
    """The native FMU contract and the RGBlimp FMUs' interface and step, on the native hybrid."""
