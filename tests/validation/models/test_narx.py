"""GP-NARX on recordings: configuration, training, prediction, model files, CLI, and the Bo105
paper reproduction's headline results."""
import json

import numpy as np
import pytest

from gp_model import ModelFileError, save_model
from validation.cli import main
from validation.core.errors import BadInputError
from validation.core.files import WRITTEN_LIST
from validation.core.recordings import Recording, write_recording
from validation.models.narx import (
    NarxConfig,
    free_run,
    load_trained,
    one_step,
    save_trained,
    train_narx,
    unseen_inputs,
)


@pytest.fixture(scope="module")
def recordings(bo105_flights):
    """The Bo105 stand-in 3-2-1-1s of tests/conftest.py: training and unseen."""
    return bo105_flights["training"], bo105_flights["unseen"]


FAST = NarxConfig(hyperparameters="maximum_likelihood", kernel="squared_exponential_ard", stride=10)


@pytest.fixture(scope="module")
def trained(recordings):
    return train_narx([recordings[0]], FAST, seed=0, n_restarts=1)


def test_training_uses_every_stride_th_sample_on_every_phase(trained, recordings):
    # 8 s at 100 Hz = samples 0..800; a target needs 2 lags of 10 samples, so targets are
    # samples 20..800; every 10th of them: 20, 30, ..., 800 -> 79 training points.
    assert len(trained.model.model.gps[0].X_train_) == 79
    assert trained.step == pytest.approx(0.1)
    np.testing.assert_allclose(trained.training_time[:3], [0.2, 0.3, 0.4])
    # The paper's every 25th sample takes targets from two phases of the 0.1 s grid (25, 50, ...).
    paper = train_narx([recordings[0]], NarxConfig(hyperparameters="maximum_likelihood",
                                                   kernel="squared_exponential_ard", stride=25),
                       n_restarts=0)
    np.testing.assert_allclose(paper.training_time[:3], [0.25, 0.5, 0.75])
    assert len(paper.model.model.gps[0].X_train_) == 32  # samples 25, 50, ..., 800


def test_one_step_matches_the_model(trained, recordings):
    prediction = one_step(trained, recordings[1])
    u = recordings[1].input("theta_1s")[::10, None]
    y = np.column_stack([recordings[1].output(a) for a in "pqr"])[::10]
    mean, _ = trained.model.one_step(u, y)
    np.testing.assert_array_equal(prediction.mean[2:], mean)
    np.testing.assert_array_equal(prediction.measured, y)


def test_free_run_is_reproducible_and_bounded(trained, recordings):
    a = free_run(trained, recordings[1], n_runs=200, seed=4)
    b = free_run(trained, recordings[1], n_runs=200, seed=4)
    np.testing.assert_array_equal(a.mean, b.mean)
    assert np.all(np.isfinite(a.mean)) and np.all(a.var[2:] > 0)
    assert np.all(a.coverage() > 0.5) and np.all(a.rmse() < 0.1)


def test_trained_model_file_round_trip(tmp_path, trained, recordings):
    path = save_trained(tmp_path / "m.npz", trained)
    loaded = load_trained(path)
    assert loaded.config == trained.config and loaded.recording_sample_time == trained.recording_sample_time
    # The condition it was trained at travels with it (an FMU of it states it).
    assert trained.condition == loaded.condition == {"vehicle": "bo105-80kt-flight", "speed_kt": 80}
    np.testing.assert_array_equal(one_step(loaded, recordings[1]).mean, one_step(trained, recordings[1]).mean)


def test_the_training_condition_is_what_every_recording_says(recordings):
    from dataclasses import replace

    from validation.models.narx import training_condition

    other = replace(recordings[1], metadata={**recordings[1].metadata, "speed_kt": 60})
    assert training_condition(recordings) == {"vehicle": "bo105-80kt-flight", "speed_kt": 80}
    assert training_condition([recordings[0], other]) == {"vehicle": "bo105-80kt-flight"}
    assert training_condition([replace(other, metadata={})]) == {}
    # A hand-written sidecar's speed as text says no speed (the FMU's description formats it).
    typed = replace(recordings[0], metadata={**recordings[0].metadata, "speed_kt": "80"})
    assert training_condition([typed]) == {"vehicle": "bo105-80kt-flight"}


def test_plain_gp_file_is_not_a_narx_model(tmp_path, trained):
    path = save_model(tmp_path / "gp.npz", trained.model.model.gps[0])
    with pytest.raises(ModelFileError, match="not a GP-NARX model"):
        load_trained(path)


@pytest.mark.parametrize("kwargs, message", [
    ({"decimation": 0}, "decimation and stride must be >= 1"),
    ({"kernel": "matern"}, "unknown kernel 'matern'"),
    ({"hyperparameters": "guess"}, "unknown hyperparameter method"),
    ({"output_lags": (0,)}, "output lags >= 1"),
])
def test_bad_configuration(kwargs, message):
    with pytest.raises(BadInputError, match=message):
        NarxConfig(**kwargs)


def test_recording_without_the_model_columns(trained, recordings):
    with pytest.raises(BadInputError, match="missing column"):
        train_narx([recordings[0]], NarxConfig(outputs=("p", "nope")))


def test_recording_at_another_rate_is_refused(trained, recordings):
    from validation.core.recordings import Recording

    slow = recordings[1]
    halved = Recording(slow.time[::2], slow.inputs[::2], slow.input_names, slow.outputs[::2],
                       slow.output_names, dict(slow.metadata))
    with pytest.raises(BadInputError, match="trained on 0.01 s data"):
        free_run(trained, halved)


def test_cli_train_and_predict(tmp_path, recordings, capsys):
    write_recording(tmp_path / "train.csv", recordings[0])
    write_recording(tmp_path / "test.csv", recordings[1])
    model = tmp_path / "m.npz"
    assert main(["train", str(tmp_path / "train.csv"), "--out", str(model),
                 "--hyperparameters", "maximum_likelihood"]) == 0
    printed = capsys.readouterr()
    assert "ARD relevance" in printed.out
    # Progress to a stream that is not a terminal (a log, a pipe): plain lines with their totals.
    assert "\r" not in printed.err
    assert [line.rsplit(", ", 1)[0] for line in printed.err.splitlines()] == [
        f"training (maximum likelihood): {i}/3 GPs" for i in (1, 2, 3)]
    assert load_trained(model).condition == {"vehicle": "bo105-80kt-flight", "speed_kt": 80}
    out = tmp_path / "pred.csv"
    assert main(["predict", str(model), str(tmp_path / "test.csv"), "--out", str(out),
                 "--runs", "100", "--plot"]) == 0
    printed = capsys.readouterr()
    assert "\r" not in printed.err and printed.err.splitlines()[-1].startswith("free run (monte carlo): 79/79 steps, ")
    header = out.read_text().splitlines()[0].split(",")
    assert header[:5] == ["time", "p_measured", "p_mean", "p_lower", "p_upper"]
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    # 8 s on the 0.1 s NARX grid: 81 rows; time, then measured, mean, lower, upper per axis.
    assert table.shape == (81, 13) and np.all(table[:, 3] <= table[:, 4])
    assert out.with_suffix(".png").stat().st_size > 10_000
    assert "coverage" in printed.out
    # The unseen 3-2-1-1 is larger than the training one (1.3 deg against 1 deg).
    assert "warning: theta_1s spans -0.02269 .. 0.02269 rad, but the model was trained on" in printed.err


def test_predict_names_what_the_model_never_saw_move(trained, recordings):
    """An input the model does not take, moved, and a model input beyond its training range
    each give a phrase; the training flight itself none."""
    assert unseen_inputs(trained, recordings[0], margin=0.1) == []
    wider = recordings[0].inputs.copy()
    wider[:, recordings[0].input_names.index("theta_1c")] = 0.01 * np.sign(np.sin(recordings[0].time))
    wider[:, recordings[0].input_names.index("theta_1s")] *= 1.5
    flown = Recording(recordings[0].time, wider, recordings[0].input_names, recordings[0].outputs,
                      recordings[0].output_names)
    phrases = unseen_inputs(trained, flown, margin=0.1)
    assert len(phrases) == 2
    assert phrases[0].startswith("theta_1c moves, but the model does not take it as an input (its inputs: theta_1s)")
    assert phrases[1].startswith("theta_1s spans") and "the GP extrapolates there" in phrases[1]
    # Within the margin (10 % of the range on each side) is still inside.
    assert unseen_inputs(trained, Recording(recordings[0].time, recordings[0].inputs * 1.05, recordings[0].input_names,
                                            recordings[0].outputs, recordings[0].output_names), margin=0.1) == []


def test_cli_bad_inputs_exit_2_and_write_nothing(tmp_path, recordings, trained, capsys):
    write_recording(tmp_path / "rec.csv", recordings[0])
    trained_file = save_trained(tmp_path / "trained.npz", trained)
    (tmp_path / "blimp.csv").write_text("time,u_gondola,mu,u_tail,U\n"
                                        + "".join(f"{k / 20},0,0,0,0\n" for k in range(40)))
    short = recordings[0]
    write_recording(tmp_path / "short.csv", Recording(short.time[:51], short.inputs[:51], short.input_names,
                                                      short.outputs[:51], short.output_names, dict(short.metadata)))
    cases = [
        ["train", str(tmp_path / "rec.csv"), "--out", str(tmp_path / "m.txt")],
        ["train", str(tmp_path / "rec.csv"), "--out", str(tmp_path / "m.npz"), "--outputs", "p", "zz"],
        ["train", str(tmp_path / "rec.csv"), "--out", str(tmp_path / "m.npz"), "--sparse", "0"],
        ["predict", str(tmp_path / "rec.csv"), str(tmp_path / "rec.csv"), "--out", str(tmp_path / "p.csv")],
        ["predict", str(tmp_path / "none.npz"), str(tmp_path / "rec.csv"), "--out", str(tmp_path / "p.csv")],
        # A recording of another vehicle (no theta_1s): refused, not a traceback.
        ["predict", str(trained_file), str(tmp_path / "blimp.csv"), "--out", str(tmp_path / "p.csv")],
        # Half a second: 2 training points for the paper's 5 regressors.
        ["train", str(tmp_path / "short.csv"), "--out", str(tmp_path / "m.npz")],
    ]
    for argv in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err and "internal error" not in err, err
    assert "the recordings give 2 training point(s) (every 25th NARX target) for 5 regressors; a GP needs at " \
           "least 14" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == [WRITTEN_LIST, "blimp.csv", "rec.csv", "rec.json",
                                                          "short.csv", "short.json", "trained.npz"]


@pytest.mark.slow
def test_reproduce_bo105_headline_results(tmp_path, capsys):
    """The paper's finding on our stand-ins: the GP free run beats the physics reference on
    pitch, roll and yaw rate, and its 95 % band covers at least 90 % of the samples on-axis."""
    assert main(["reproduce", "bo105", "--out", str(tmp_path), "--paper-only", "--runs", "500"]) == 0
    results = json.loads((tmp_path / "results.json").read_text())
    for axis in "pqr":
        assert results["fmp"]["gp"][axis] < results["fmp"]["reference"][axis], axis
    assert results["config"]["training_points"] == 32  # every 25th sample of 8 s, as the paper
    assert results["coverage95"]["q"] >= 0.9
    assert set(results["unseen"]["fmp"]["gp"]) == {"p", "q", "r"}
    assert {"osap.png", "fmp.png", "fmp_unseen.png"} <= {p.name for p in tmp_path.iterdir()}
    assert "FMP   physics reference" in capsys.readouterr().out
