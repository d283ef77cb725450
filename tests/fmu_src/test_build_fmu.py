"""``flightgp build-fmu`` (validation/cli/build_fmu.py on fmu_src's public API): every FMU it
builds, with exit code 0 and the FMU validated; bad input exits 2, one line, no traceback, and
writes nothing."""
from __future__ import annotations

import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from fmu_src.blimp_rkgp.native import MODEL_SOURCE as BLIMP_MODEL_SOURCE
from fmu_src.fmi.native import compiled_sources
from gp_model import save_model
from validation.cli import main
from validation.core.files import WRITTEN_LIST
from validation.models.blimp_greybox import BlimpStepDescription
from validation.models.narx import NarxConfig, save_trained, train_narx


# -- pythonfmu FMUs ----------------------------------------------------------------------------------
def test_build_fmu_command_writes_the_fmu(bo105_model_file, tmp_path, capsys):
    assert main(["build-fmu", str(bo105_model_file), "--out", str(tmp_path / "out"), "--name", "rates"]) == 0
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [WRITTEN_LIST, "rates.fmu"]
    assert validate_fmu(str(tmp_path / "out" / "rates.fmu")) == []
    assert "rates.fmu" in capsys.readouterr().out


@pytest.mark.parametrize("problem", ["missing", "not a model", "bad name", "out is a file", "input lag 0"])
def test_build_fmu_bad_input_exits_2_and_writes_nothing(bo105_model_file, bo105_flights, tmp_path, capsys,
                                                        problem):
    model, out, name = str(bo105_model_file), tmp_path / "out", []
    if problem == "missing":
        model = str(tmp_path / "nope.npz")
    elif problem == "not a model":
        (tmp_path / "junk.npz").write_text("not a zip")
        model = str(tmp_path / "junk.npz")
    elif problem == "bad name":
        name = ["--name", "2 fast"]
    elif problem == "out is a file":
        out.write_text("keep me")
    else:
        config = NarxConfig(input_lags=(0, 1), hyperparameters="maximum_likelihood", stride=25)
        trained = train_narx([bo105_flights["training"]], config, seed=0, n_restarts=0)
        model = str(save_trained(tmp_path / "lag0.npz", trained))
    assert main(["build-fmu", model, "--out", str(out), *name]) == 2
    err = capsys.readouterr().err
    assert err.startswith("flightgp build-fmu: error:") and "Traceback" not in err
    assert not out.is_dir() or not any(out.iterdir())


@pytest.mark.parametrize("reference, file_name", [("bo105-80kt", "bo105_80kt_reference.fmu"),
                                                  ("blimp", "blimp_reference.fmu"),
                                                  ("jsbsim:c172x", "jsbsim_c172x.fmu")])
def test_build_fmu_command_builds_reference_fmus(reference, file_name, tmp_path, capsys):
    assert main(["build-fmu", "--reference", reference, "--out", str(tmp_path / "out")]) == 0
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [WRITTEN_LIST, file_name]
    assert validate_fmu(str(tmp_path / "out" / file_name)) == []
    assert file_name in capsys.readouterr().out


@pytest.mark.parametrize("arguments", [["--reference", "bo105-85kt"], ["--reference", "bo105-80kt-flight"],
                                       ["--reference", "blimp-flight"], ["--reference", "jsbsim:"],
                                       ["--reference", "jsbsim:nope"], ["--reference", "jsbsim:ZLT-NT"],
                                       [], ["model.npz", "--reference", "bo105-80kt"]])
def test_build_fmu_bad_reference_exits_2_naming_the_valid_ones(arguments, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["build-fmu", *arguments, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("flightgp build-fmu: error:") and err.count("\n") == 1 and "Traceback" not in err
    assert "jsbsim:c172x" in err or "jsbsim:<aircraft>" in err
    if not any(a.startswith("jsbsim:") for a in arguments):
        assert "bo105-<V>kt" in err or "bo105-80kt, bo105-100kt" in err
    assert not out.exists()


def test_build_fmu_command_builds_the_blimp_rkgp_from_a_greybox_model(blimp_model_file, tmp_path, capsys):
    assert main(["build-fmu", str(blimp_model_file), "--out", str(tmp_path / "out"), "--name", "blimp"]) == 0
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [WRITTEN_LIST, "blimp.fmu"]
    assert validate_fmu(str(tmp_path / "out" / "blimp.fmu")) == []
    names = [v.name for v in read_model_description(str(tmp_path / "out" / "blimp.fmu")).modelVariables]
    assert "u_gondola" in names and "R_sd" in names
    assert "blimp.fmu" in capsys.readouterr().out


def test_build_fmu_refuses_a_greybox_model_of_other_physics(blimp_trained, tmp_path, capsys):
    model = save_model(tmp_path / "cart.npz", blimp_trained["model"], physics={"kind": "damped_cart"})
    assert main(["build-fmu", str(model), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("flightgp build-fmu: error:") and "blimp_rk4" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


# -- native FMUs -------------------------------------------------------------------------------------
def test_build_fmu_command_native(bo105_flights, tmp_path, capsys):
    # A GP-NARX model of one hyperparameter sample: the command is what is checked here, and its
    # build spends 0.1 s besides gcc instead of the paper model's 1.1 s (400 samples: the check of
    # the fast path, a 10 MB model.bin).
    trained = train_narx([bo105_flights["training"]], NarxConfig(hyperparameters="maximum_likelihood"), seed=0,
                         n_restarts=0)
    model = save_trained(tmp_path / "single.npz", trained)
    out = tmp_path / "out"
    assert main(["build-fmu", str(model), "--native", "--out", str(out), "--name", "rates"]) == 0
    assert sorted(p.name for p in out.iterdir()) == [WRITTEN_LIST, "rates.fmu"]
    assert "rates.fmu" in capsys.readouterr().out
    assert read_model_description(str(out / "rates.fmu")).coSimulation.needsExecutionTool is False


@pytest.mark.parametrize("arguments", [["--reference", "bo105-80kt"], ["missing.npz"]])
def test_build_fmu_native_bad_input_exits_2(arguments, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["build-fmu", *arguments, "--native", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("flightgp build-fmu: error:") and "Traceback" not in err
    assert not out.exists() or not any(out.iterdir())


def test_build_fmu_command_native_builds_the_blimp_rkgp(blimp_model_file, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["build-fmu", str(blimp_model_file), "--native", "--out", str(out), "--name", "blimp"]) == 0
    assert sorted(p.name for p in out.iterdir()) == [WRITTEN_LIST, "blimp.fmu"]
    assert "blimp.fmu" in capsys.readouterr().out
    assert validate_fmu(str(out / "blimp.fmu")) == []
    description = read_model_description(str(out / "blimp.fmu"))
    assert description.coSimulation.needsExecutionTool is False
    assert description.buildConfigurations[0].sourceFileSets[0].sourceFiles == [
        path.name for path in compiled_sources(BLIMP_MODEL_SOURCE)]


def test_build_fmu_native_refuses_a_greybox_model_of_other_physics(blimp_trained, tmp_path, capsys):
    model = save_model(tmp_path / "cart.npz", blimp_trained["model"], physics={"kind": "damped_cart"})
    assert main(["build-fmu", str(model), "--native", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("flightgp build-fmu: error:") and "blimp_rk4" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


@pytest.mark.parametrize("native", [False, True], ids=["pythonfmu", "native"])
@pytest.mark.parametrize("problem", ["negative lag", "lag not a number", "lags not the model's"])
def test_build_fmu_refuses_a_blimp_model_whose_command_lags_are_unusable(blimp_lagged, tmp_path, capsys, problem,
                                                                        native):
    """The command lags of the physics description (validation.models.blimp_greybox) must be
    positive times and the ones the model's GP inputs were made with; otherwise exit 2, one line
    naming the problem, nothing written."""
    physics = BlimpStepDescription(blimp_lagged["params"], command_lags=blimp_lagged["command_lags"]).as_dict()
    if problem == "negative lag":
        physics["command_lags"] = [-0.15, 0.3, 0.6]
        phrase = "command lags must be positive times in s"
    elif problem == "lag not a number":
        physics["command_lags"] = ["fast", 0.3, 0.6]
        phrase = "physics description is unusable"
    else:  # a description without lags for a model whose GPs see three
        physics = BlimpStepDescription(blimp_lagged["params"]).as_dict()
        phrase = "names 12 states and 4 inputs"
    model = save_model(tmp_path / "lagged.npz", blimp_lagged["model"], physics=physics)
    out = tmp_path / "out"
    assert main(["build-fmu", str(model), "--out", str(out), *(["--native"] if native else [])]) == 2
    err = capsys.readouterr().err
    assert err.startswith("flightgp build-fmu: error:") and phrase in err, err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists() or not any(out.iterdir())
