"""The pythonfmu RGBlimp RKGP FMU (fmu_src/rgblimp_rkgp): the FMU contract and the RGBlimp RKGP's,
on an RKGP fitted on 40 transitions of the excerpt's flights data_117 and data_118 and driven by
data_119's inputs from its first recorded state; then what is particular to the pythonfmu build:
the equations it carries, the model files it refuses, and how ``flightgp build-fmu`` routes
grey-box model files by their physics."""
from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest
from fmpy import read_model_description

from fmu_src import build_model_fmu, build_rgblimp_rkgp_fmu
from fmu_src.fmi.pythonfmu import flat_name, shipped_sources
from fmu_src.fmi.runtime import ModelFormatError
from fmu_src.rgblimp_rkgp.build import rgblimp_rkgp_parts
from fmu_src.rgblimp_rkgp.model import RGBlimpRKGPModel
from gp_model import GreyBoxGP, ModelFileError, save_model
from tests.fmu_src.contract import FmuContract
from tests.fmu_src.rgblimp_rkgp.contract import RGBlimpRkgpContract, rgblimp_rkgp_case
from validation.cli import main
from validation.core.errors import BadInputError
from validation.models import rgblimp_step
from validation.models.blimp_greybox import BlimpStepDescription
from validation.vehicles import rgblimp_equations
from validation.vehicles.blimp import BlimpParameters


@pytest.fixture(scope="module")
def case(rgblimp_rkgp_fmu, rgblimp_trained):
    return rgblimp_rkgp_case(rgblimp_rkgp_fmu, rgblimp_trained)


class TestRGBlimpRkgpFmu(FmuContract, RGBlimpRkgpContract):
    """The FMU contract and the RGBlimp RKGP's, on the pythonfmu RGBlimp RKGP."""


def test_carries_the_rgblimp_equations_and_the_rkgp_step(case):
    """The FMU steps with copies of validation/vehicles/rgblimp_equations.py and
    validation/models/rgblimp_step.py, what the identification and GreyBoxGP's physics step use
    (one home for the equations), only their imports of flightgp modules made relative."""
    with zipfile.ZipFile(case.path) as archive:
        for module in (rgblimp_equations.__name__, rgblimp_step.__name__):
            copies = [name for name in archive.namelist() if name.endswith(f"/{flat_name(module)}.py")]
            assert len(copies) == 1, copies
            # The module's text, its imports of flightgp modules made relative (fmu_src.fmi.pythonfmu).
            expected = shipped_sources([module])[f"{flat_name(module)}.py"]
            assert archive.read(copies[0]).decode() == expected


@pytest.mark.parametrize("problem", ["missing", "a GP", "blimp physics", "unknown physics", "a parameter short",
                                     "not numbers", "other inputs"])
def test_refuses_model_files_it_cannot_carry(problem, rgblimp_trained, rgblimp_model_file, tmp_path):
    """A missing file or another model type: ModelFileError; another physics or an unusable
    description of it, or a grey-box model of other inputs: BadInputError naming the problem.
    Nothing is written."""
    model, physics = rgblimp_trained["model"], rgblimp_trained["description"].as_dict()
    path = tmp_path / "model.npz"
    error, phrase = BadInputError, None
    if problem == "missing":
        error, phrase = ModelFileError, "no such model file"
    elif problem == "a GP":
        save_model(path, model.gp_.gps[0])
        error, phrase = ModelFileError, "not a GreyBoxGP"
    elif problem == "blimp physics":
        save_model(path, model, physics=BlimpStepDescription(BlimpParameters()).as_dict())
        phrase = "needs 'rgblimp_rk4'"
    elif problem == "unknown physics":
        save_model(path, model, physics={"kind": "rgblimp_rk5"})
        phrase = "needs 'rgblimp_rk4'"
    elif problem == "a parameter short":
        del physics["parameters"]["c_l0"]
        save_model(path, model, physics=physics)
        phrase = "c_l0"
    elif problem == "not numbers":
        physics["wind"] = ["calm", 0.0]
        save_model(path, model, physics=physics)
        phrase = "unusable"
    else:
        states, inputs = np.zeros((5, 12)), np.zeros((5, 6))
        states[:, 6] = inputs[:, 0] = np.arange(5)
        other = GreyBoxGP(state_columns=(6,), n_restarts=0).fit(states, inputs, states, None, optimize=False)
        save_model(path, other, physics=physics)
        phrase = "6 inputs"
    with pytest.raises(error, match=phrase):
        build_rgblimp_rkgp_fmu(path, tmp_path / "out")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("change", ["not JSON", "no wind", "a parameter short", "a state column out of range"])
def test_a_corrupt_fmu_model_file_is_refused_at_load(change, rgblimp_model_file, tmp_path):
    """Inside the FMU the model file's physics is read again (validation.models.rgblimp_step): a
    corrupt one is a ModelFormatError, which the FMU logs when it initialises."""
    arrays = dict(rgblimp_rkgp_parts(rgblimp_model_file, tmp_path).arrays)
    physics = json.loads(str(arrays["physics"]))
    if change == "not JSON":
        arrays["physics"] = np.array("{rgblimp")
    elif change == "no wind":
        del physics["wind"]
    elif change == "a parameter short":
        del physics["parameters"]["hull_cg"]
    else:  # a native FMU would read outside its state
        arrays["state_columns"] = np.array([3, 4, 12])
    if change != "not JSON":
        arrays["physics"] = np.array(json.dumps(physics))
    with pytest.raises(ModelFormatError, match={"not JSON": "unusable", "no wind": "wind",
                                                 "a parameter short": "hull_cg",
                                                 "a state column out of range": "distinct columns 0..11"}[change]):
        RGBlimpRKGPModel(arrays)


def test_build_fmu_routes_grey_box_models_by_their_physics(rgblimp_trained, rgblimp_model_file, tmp_path, capsys):
    """``flightgp build-fmu`` (fmu_src.build.build_model_fmu) builds the RGBlimp RKGP FMU of an
    rgblimp_rk4 model file, pythonfmu and --native, and refuses a grey-box model of unknown
    physics (exit 2, one line naming the physics it builds, nothing written)."""
    out = tmp_path / "out"
    for native in ([], ["--native"]):
        name = "rgblimp_native" if native else "rgblimp"
        assert main(["build-fmu", str(rgblimp_model_file), "--out", str(out), "--name", name, *native]) == 0
        description = read_model_description(str(out / f"{name}.fmu"))
        assert description.description.startswith("RGBlimp RKGP")
        assert description.coSimulation.needsExecutionTool is (not native)
        assert [v.name for v in description.modelVariables][:5] == list(rgblimp_equations.INPUT_NAMES)
    assert f"{name}.fmu" in capsys.readouterr().out
    other = save_model(tmp_path / "other.npz", rgblimp_trained["model"], physics={"kind": "glider_rk4"})
    with pytest.raises(BadInputError, match="'glider_rk4'.*'blimp_rk4'.*'rgblimp_rk4'"):
        build_model_fmu(other, tmp_path / "refused")
    assert main(["build-fmu", str(other), "--out", str(tmp_path / "refused")]) == 2
    error = capsys.readouterr().err
    assert error.startswith("flightgp build-fmu: error:") and error.count("\n") == 1 and "rgblimp_rk4" in error
    assert not (tmp_path / "refused").exists()
