"""The RGBlimp hybrid FMUs' case for the FMU contract (tests/fmu_src/contract.py): data_119's
inputs from its state at CASE_START, against the hybrid's Python free run."""
from __future__ import annotations

import functools
import math

import numpy as np

from tests.fmu_src.contract import FmuCase
from tests.fmu_src.rgblimp_hybrid.conftest import CASE_START
from tests.fmu_src.rgblimp_rkgp.contract import NO_LIBCOSIM, start_values
from validation.vehicles.rgblimp_equations import INPUT_NAMES, SAMPLE_TIME

#: Steps of the contract's standard run (1 s).
CASE_STEPS = 60


def hybrid_case(path, trained: dict, reference: np.ndarray) -> FmuCase:
    """The hybrid FMU at ``path`` driven by data_119's inputs from its state at CASE_START; the
    reference is the first CASE_STEPS + 1 rows of the Python free run (a free run is causal)."""
    inputs = trained["inputs"][CASE_START:]
    return FmuCase(path=path, step=SAMPLE_TIME, n_steps=CASE_STEPS, inputs=lambda k: dict(zip(INPUT_NAMES, inputs[k])),
                   reference=functools.cache(lambda: (reference[:CASE_STEPS + 1], 0)),
                   parameters=start_values(trained["states"][CASE_START]),
                   # The correction saw one configuration: any other thrust or gondola position is outside.
                   far_inputs={"thrust_left": 0.05, "gondola_x": 0.09}, bands=[], spreads=[],
                   bad_inputs=[("thrust_left", math.nan), ("gondola_x", math.inf), ("thrust_right", -math.inf)],
                   no_libcosim_reason=NO_LIBCOSIM)
