"""The pythonfmu blimp RKGP FMU (fmu_src/blimp_rkgp): the FMU contract and the blimp RKGP's, on a
shared-GP RKGP trained on 10 s of blimp-flight; the blimp RKGP's lagged contract, on a model with
one GP per state whose GPs see the lagged fan commands; then what is particular to the pythonfmu
build."""
from __future__ import annotations

import zipfile
from pathlib import Path

import pytest

from tests.fmu_src.blimp_rkgp.contract import BlimpRkgpContract, BlimpRkgpLaggedContract, blimp_rkgp_case
from tests.fmu_src.contract import FmuContract
from validation.vehicles import blimp_equations


@pytest.fixture(scope="module")
def case(blimp_rkgp_fmu, blimp_trained):
    return blimp_rkgp_case(blimp_rkgp_fmu, blimp_trained)


@pytest.fixture(scope="module")
def lagged_case(blimp_lagged_fmu, blimp_lagged):
    return blimp_rkgp_case(blimp_lagged_fmu, blimp_lagged, n_steps=40)


class TestBlimpRkgpFmu(FmuContract, BlimpRkgpContract):
    """The FMU contract and the blimp RKGP's, on the pythonfmu blimp RKGP."""


class TestLaggedBlimpRkgpFmu(BlimpRkgpLaggedContract):
    """The blimp RKGP's lagged contract, on the pythonfmu blimp RKGP."""


def test_carries_the_blimp_equations_of_the_vehicle(case):
    """The FMU steps with a copy of validation/vehicles/blimp_equations.py, the equations the
    blimp reference, identification and GreyBoxGP's physics use: one home for the equations."""
    with zipfile.ZipFile(case.path) as archive:
        copies = [name for name in archive.namelist() if name.endswith("/validation_vehicles_blimp_equations.py")]
        assert len(copies) == 1, copies
        carried = archive.read(copies[0]).decode()
    assert carried == Path(blimp_equations.__file__).read_text(encoding="utf-8")
