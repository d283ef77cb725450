"""The second FMI host (libcosim via libcosimpy) on a bare pythonfmu FMU."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from validation.core.errors import BadInputError
from validation.cosim.hosts import simulate_in_libcosim

DOUBLER = '''
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real


class flightgp_test_doubler(Fmi2Slave):
    description = "y = gain * u, computed in do_step"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.u, self.gain, self.y = 0.0, 2.0, 0.0
        self.register_variable(Real("u", causality=Fmi2Causality.input,
                                    variability=Fmi2Variability.continuous, start=0.0))
        self.register_variable(Real("gain", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.fixed, start=2.0))
        self.register_variable(Real("y", causality=Fmi2Causality.output,
                                    variability=Fmi2Variability.continuous, initial="exact", start=0.0))

    def do_step(self, current_time, step_size):
        self.y = self.gain * self.u
        return True
'''


@pytest.fixture(scope="module")
def doubler(tmp_path_factory):
    folder = tmp_path_factory.mktemp("doubler")
    script = folder / "flightgp_test_doubler.py"
    script.write_text(DOUBLER)
    pythonfmu = Path(sys.executable).with_name("pythonfmu")
    subprocess.run([str(pythonfmu), "build", "-f", str(script), "-d", str(folder)], check=True,
                   capture_output=True)
    return folder / "flightgp_test_doubler.fmu"


def test_inputs_apply_over_each_step_and_outputs_follow(doubler):
    result = simulate_in_libcosim(doubler, step_size=0.1, n_steps=5, inputs={"u": np.arange(5.0)},
                                  start_values={"gain": 3.0}, outputs=("y",))
    np.testing.assert_allclose(result["y"], 3.0 * np.arange(5.0))
    # Times are k * 100 000 000 ns, converted once: exact decimal multiples of 0.1 s.
    np.testing.assert_allclose(result["time"], [0.1, 0.2, 0.3, 0.4, 0.5], rtol=0, atol=1e-15)


def test_unknown_variable_is_bad_input(doubler):
    with pytest.raises(BadInputError, match="no variable"):
        simulate_in_libcosim(doubler, step_size=0.1, n_steps=1, outputs=("nope",))
