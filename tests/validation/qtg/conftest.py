"""Short Bo105 flights for the QTG tests: 5 s at 100 Hz from trim, 1 deg manoeuvres from 0.5 s."""
import numpy as np
import pytest

from validation.core.manoeuvres import manoeuvre, time_grid
from validation.core.recordings import write_recording
from validation.vehicles import get_vehicle

#: The flights, name -> (vehicle, manoeuvre, input): doublets flown on the unchanged reference,
#: and a 3-2-1-1 flown on the flight-test stand-in, which the reference misses in pitch rate by
#: about four times the 2 deg/s band (docs/qtg.md, "The Bo105 example").
FLIGHTS = {
    "ref_theta_1s_doublet": ("bo105-80kt", "doublet", "theta_1s"),
    "ref_theta_1c_doublet": ("bo105-80kt", "doublet", "theta_1c"),
    "ref_theta_0T_doublet": ("bo105-80kt", "doublet", "theta_0T"),
    "flight_theta_1s_3211": ("bo105-80kt-flight", "3211", "theta_1s"),
}


@pytest.fixture(scope="session")
def qtg_flights(tmp_path_factory):
    """A folder holding the :data:`FLIGHTS` as ``<name>.csv`` recordings (with sidecars)."""
    folder = tmp_path_factory.mktemp("qtg")
    for name, (vehicle_name, kind, input_name) in FLIGHTS.items():
        vehicle = get_vehicle(vehicle_name)
        time = time_grid(duration=5.0, sample_time=0.01)
        inputs = np.zeros((len(time), len(vehicle.input_names)))
        inputs[:, vehicle.input_names.index(input_name)] = manoeuvre(
            kind, time, amplitude=np.radians(1.0), step_time=0.4 if kind == "3211" else 0.5, start=0.5)
        recording = vehicle.simulate(time, inputs, seed=0)
        recording.metadata["vehicle"] = vehicle_name
        write_recording(folder / f"{name}.csv", recording)
    return folder


def write_spec(folder, text: str, *, name: str = "qtg.toml"):
    """``text`` as the spec ``folder/name``; returns its path."""
    path = folder / name
    path.write_text(text, encoding="utf-8")
    return path
