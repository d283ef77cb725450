"""FMU references (validation/vehicles/fmu_reference.py) on flightgp's Bo105 reference FMU: a
replay through the FMU is the built-in reference's, each effect acts as documented (a search term
as an extra input), a refused replay ends only its candidate, diagnose names what it names
through the built-in reference, the residual search through the FMU finds a term on no list, and
bad FMUs exit 2 with one line."""
import copy

import numpy as np
import pytest

from fmu_src import build_bo105_reference_fmu
from validation.cli import main
from validation.core.errors import BadInputError
from validation.diagnose import diagnose
from validation.vehicles.bo105 import Bo105Reference
from validation.vehicles.bo105_effects import identification_manoeuvre
from validation.vehicles.bo105_flight import SENSOR_NOISE_STD
from validation.vehicles.effect_vehicle import EffectVehicle, effect_model

#: 6 s of the Bo105 manoeuvre at 50 Hz (its longitudinal 3-2-1-1 and lateral one): short
#: replays through a Python FMU.
DURATION, STEP = 6.0, 0.02
#: The sample interval of the diagnoses through the FMU, s (33 Hz: two thirds of the replayed
#: steps of 50 Hz; the 60 ms delay is two whole samples, and each effect is still named with its
#: truth inside an interval of under 2 %).
DIAGNOSE_STEP = 0.03


@pytest.fixture(scope="module")
def fmu(tmp_path_factory):
    return str(build_bo105_reference_fmu(80, tmp_path_factory.mktemp("fmu_reference")))


@pytest.fixture(scope="module")
def manoeuvre():
    return identification_manoeuvre(duration=DURATION, sample_time=STEP)


def test_replays_through_the_fmu_are_the_built_in_references_with_each_effect(fmu, manoeuvre):
    """Delays of whole steps, gains, parameters, biases and scales: as the built-in Bo105 with the
    same physics (the FMU runs the same discretisation; 1e-9)."""
    time, inputs = manoeuvre
    through_fmu, built_in = effect_model(fmu, purpose="test"), Bo105Reference(80)
    assert through_fmu.input_names == built_in.input_names and through_fmu.state_names == built_in.state_names
    assert len(through_fmu.terms["fmu_parameter"]) == 72 and through_fmu.term_description("M_q").startswith("pitch")
    gain = 0.8
    lists = [[], [{"effect": "time_delay", "input": "theta_1s", "value": 2 * STEP}],
             [{"effect": "input_gain", "input": "theta_1c", "value": gain}],
             [{"effect": "fmu_parameter", "term": "M_q", "value": -3.0},
              {"effect": "sensor_bias", "output": "q", "value": 0.01},
              {"effect": "output_scale", "output": "p", "value": 1.1}]]
    replays = through_fmu.simulate_many(lists, time, inputs)
    delayed = np.vstack([np.zeros((2, 4)), inputs[:-2]])
    delayed[:, [0, 2, 3]] = inputs[:, [0, 2, 3]]
    scaled = inputs.copy()
    scaled[:, 2] *= gain
    corrected = built_in.with_derivatives({"M_q": -3.0}).simulate_states(time, inputs)
    corrected[:, 2] += 0.01
    corrected[:, 5] *= 1.1
    expected = [built_in.simulate_states(time, inputs), built_in.simulate_states(time, delayed),
                built_in.simulate_states(time, scaled), corrected]
    for replay, states in zip(replays, expected):
        np.testing.assert_allclose(replay, states, rtol=0, atol=1e-9)


def test_a_refused_replay_ends_only_its_candidate(fmu, manoeuvre, caplog):
    time, inputs = manoeuvre
    model = effect_model(fmu, purpose="test")
    blown_up, fine = model.simulate_many([[{"effect": "fmu_parameter", "term": "M_q", "value": 1e300}], []],
                                         time, inputs)
    assert np.isnan(blown_up).all() and np.isfinite(fine).all()
    np.testing.assert_allclose(fine, Bo105Reference(80).simulate_states(time, inputs), rtol=0, atol=1e-9)
    assert any("refused a replay" in record.message for record in caplog.records)


@pytest.mark.slow
def test_diagnose_through_the_fmu_names_what_the_built_in_reference_names(fmu):
    truth = [{"effect": "time_delay", "input": "theta_1s", "value": 0.06},
             {"effect": "stability_derivative", "term": "M_q", "value": -3.0}]
    aircraft = EffectVehicle("bo105-80kt", truth, noise_sd=SENSOR_NOISE_STD)
    fit = aircraft.simulate(*identification_manoeuvre(duration=DURATION, sample_time=DIAGNOSE_STEP, variant=0), seed=1)
    held = aircraft.simulate(*identification_manoeuvre(duration=DURATION, sample_time=DIAGNOSE_STEP, variant=1), seed=2)
    built_in = diagnose([fit], reference="bo105-80kt", holdout=[held]).as_dict()["findings"]
    through_fmu = diagnose([fit], reference=fmu, holdout=[held], workers=1).as_dict()["findings"]
    assert [f.get("input") or f.get("term") for f in through_fmu] == [f.get("input") or f.get("term") for f in built_in]
    assert [f["effect"] for f in through_fmu] == ["fmu_parameter", "time_delay"]
    for ours, theirs in zip(through_fmu, built_in):
        assert ours["interval"][0] <= theirs["value"] <= ours["interval"][1]
    assert "The parameter M_q (pitch damping, the derivative M_q) is -3" in through_fmu[0]["statement"]


def test_search_terms_through_the_fmu_enter_its_inputs(fmu, manoeuvre):
    """A search term through an FMU is an extra input: ``theta0_theta_1s`` (theta_0 receives c
    theta_1s) is the built-in reference flown on those inputs, and ``theta1s_q`` (theta_1s
    receives c times the pitch rate at each step's start) is the reference's discrete model
    closed through that feedback, both to 1e-9; the unit and words name the input, and the
    input's own linear term (the named input gain) is refused."""
    time, inputs = manoeuvre
    model, built_in = effect_model(fmu, purpose="test"), Bo105Reference(80)
    assert "search_term" not in model.kinds  # asked for only
    model.take_input_terms()
    linear, fed = model.simulate_many([[{"effect": "search_term", "term": "theta0_theta_1s", "value": 0.3}],
                                       [{"effect": "search_term", "term": "theta1s_q", "value": -0.2}]], time, inputs)
    shifted = inputs.copy()
    shifted[:, 0] += 0.3 * inputs[:, 1]
    np.testing.assert_allclose(linear, built_in.simulate_states(time, shifted), rtol=0, atol=1e-9)
    transition, forcing = built_in.discretisation(STEP)
    state, expected = np.zeros(len(built_in.state_names)), []
    for row in inputs:
        expected.append(state)
        state = transition @ state + forcing @ (row + np.array([0.0, -0.2 * state[2], 0.0, 0.0]))  # q is state 2
    np.testing.assert_allclose(fed, np.array(expected), rtol=0, atol=1e-9)
    assert np.abs(fed - linear).max() > 1e-3
    assert model.term_unit("theta1s_q|q|") == "rad/(rad/s)^2" and model.term_unit("theta0_u*q") == "rad/(m/s rad/s)"
    assert model.term_description("theta1s_q|q|") == "extra theta_1s input proportional to q|q|"
    from validation.vehicles.effects import check_effects

    with pytest.raises(BadInputError, match="not one of"):
        check_effects([{"effect": "search_term", "term": "theta1s_theta_1s", "value": 0.1}], model)


def test_input_terms_are_refused_for_inputs_that_collide_without_underscores(fmu):
    """A search term names its input without underscores (``theta1s``); an FMU whose inputs
    ``theta_0`` and ``theta0`` would share a row is refused input terms with one line, and its
    effects stay as they were (the real FMU, its inputs renamed as such an FMU's would be)."""
    from validation.vehicles.fmu_reference import FMUEffects

    reference = copy.copy(effect_model(fmu, purpose="test").reference)
    reference.input_names = ("theta_0", "theta0", "theta_1c", "theta_0T")
    model = FMUEffects(reference)
    with pytest.raises(BadInputError, match="do not stay distinct"):
        model.take_input_terms()
    assert "search_term" not in model.kinds and "search_term" not in model.terms


@pytest.mark.slow
def test_the_residual_search_through_the_fmu_finds_a_term_on_no_list(fmu):
    """The FMU flown with a pitch damping quadratic in the pitch rate, seen through the
    longitudinal cyclic (``theta1s_q|q|``): asked for input terms, the search through the FMU
    finds that term first, with the truth inside its interval, and it carries over; input terms
    on a reference that is not an FMU are refused with one line."""
    truth = [{"effect": "search_term", "term": "theta1s_q|q|", "value": -0.5}]
    model = effect_model(fmu, purpose="test")
    model.take_input_terms()
    noise = {name: SENSOR_NOISE_STD[name] for name in model.state_names}
    fit, held = [EffectVehicle(model, truth, noise_sd=noise).simulate(
        *identification_manoeuvre(duration=DURATION, sample_time=DIAGNOSE_STEP, variant=v), seed=v + 1) for v in (0, 1)]
    result = diagnose([fit], reference=fmu, holdout=[held], workers=1, input_terms=True).as_dict()
    found = result["findings"][0]
    assert (found["effect"], found["term"], found["found_by"]) == ("search_term", "theta1s_q|q|", "search")
    assert found["interval"][0] <= -0.5 <= found["interval"][1] and found["carries_over"]
    assert result["search"]["residual_search"]["ran"] and result["search"]["residual_search"]["library_terms"] > 100
    with pytest.raises(BadInputError, match="input terms are for an FMU reference"):
        diagnose([fit], reference="bo105-80kt", input_terms=True)


def test_bad_fmus_exit_2_with_one_line(tmp_path, capsys):
    recording = tmp_path / "run.csv"
    recording.write_text("time,theta_0,theta_1s,theta_1c,theta_0T,q\n0,0,0,0,0,0\n0.01,0,0,0,0,0\n")
    (tmp_path / "text.fmu").write_text("not a zip")
    for reference, message in ((tmp_path / "text.fmu", "not an FMU"), (tmp_path / "none.fmu", "no such FMU")):
        code = main(["diagnose", str(recording), "--reference", str(reference), "--out", str(tmp_path / "out")])
        err = capsys.readouterr().err
        assert code == 2 and message in err and err.count("\n") == 1, err
    with pytest.raises(BadInputError, match="no such FMU"):
        effect_model(str(tmp_path / "none.fmu"), purpose="test")


def description_only_fmu(path, *, version: str, kind: str) -> str:
    """A zip holding only a model description of FMI ``version`` and ``kind`` (CoSimulation or
    ModelExchange) with one Real input and output: enough for diagnose to read and refuse."""
    import zipfile

    variables = ('<ScalarVariable name="u" valueReference="0" causality="input"><Real start="0"/></ScalarVariable>'
                 '<ScalarVariable name="q" valueReference="1" causality="output"><Real/></ScalarVariable>')
    xml = (f'<?xml version="1.0" encoding="UTF-8"?><fmiModelDescription fmiVersion="{version}" modelName="m" '
           f'guid="{{00000000-0000-0000-0000-000000000000}}" numberOfEventIndicators="0">'
           f'<{kind} modelIdentifier="m"/><ModelVariables>{variables}</ModelVariables>'
           '<ModelStructure><Outputs><Unknown index="2"/></Outputs></ModelStructure></fmiModelDescription>')
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("modelDescription.xml", xml)
    return str(path)


def test_fmus_of_another_kind_or_version_and_unmatched_columns_exit_2_with_one_line(fmu, tmp_path, capsys):
    recording = tmp_path / "run.csv"
    recording.write_text("time,theta_0,theta_1s,theta_1c,theta_0T,q\n0,0,0,0,0,0\n0.01,0,0,0,0,0\n")
    other = tmp_path / "other.csv"
    other.write_text("time,elevator,pitch_rate\n0,0,0\n0.01,0,0\n")
    cases = ((description_only_fmu(tmp_path / "me.fmu", version="2.0", kind="ModelExchange"), recording,
              "a model-exchange FMU"),
             (description_only_fmu(tmp_path / "v1.fmu", version="1.0", kind="CoSimulation"), recording,
              "an FMI 1.0 FMU"),
             (fmu, other, "--map renames columns"))
    for reference, data, message in cases:
        code = main(["diagnose", str(data), "--reference", str(reference), "--out", str(tmp_path / "out")])
        err = capsys.readouterr().err
        assert code == 2 and message in err and err.count("\n") == 1, err
    assert not (tmp_path / "out").exists()


def test_an_fmu_without_a_binary_for_this_platform_exits_2_and_never_gives_a_verdict(fmu, tmp_path, capsys):
    """An FMU whose binaries are for other platforms (the linux64 folder dropped from a copy),
    or that has none, is refused in one line before anything is written; so is a reference whose
    own replay is not finite, instead of a verdict on NaN."""
    import zipfile

    from fmpy import platform

    foreign = tmp_path / "foreign.fmu"
    with zipfile.ZipFile(fmu) as source, zipfile.ZipFile(foreign, "w") as target:
        for item in source.infolist():
            if not item.filename.startswith(f"binaries/{platform}/"):
                target.writestr(item, source.read(item))
    recording = tmp_path / "run.csv"
    recording.write_text("time,theta_0,theta_1s,theta_1c,theta_0T,q\n0,0,0,0,0,0\n0.01,0,0,0,0,0\n")
    bare = description_only_fmu(tmp_path / "bare.fmu", version="2.0", kind="CoSimulation")
    for reference, message in ((foreign, "binaries for win64"), (bare, "this FMU has no binaries")):
        code = main(["diagnose", str(recording), "--reference", str(reference), "--out", str(tmp_path / "out")])
        err = capsys.readouterr().err
        assert code == 2 and message in err and f"this machine needs {platform}" in err and err.count("\n") == 1, err
    assert not (tmp_path / "out").exists()


def test_a_column_map_renames_recording_columns_to_the_fmus_names(fmu, manoeuvre, tmp_path, capsys):
    """A recording whose columns carry other names is diagnosed through the map exactly as the
    same recording under the FMU's names; maps that name unknown variables or columns no
    recording has, or are not JSON objects of names, exit 2 with one line."""
    from validation.core.recordings import write_recording
    from validation.diagnose.data import prepare, read_column_map

    time, inputs = manoeuvre
    flown = Bo105Reference(80).simulate(time, inputs)
    flown = type(flown)(flown.time, flown.inputs, flown.input_names, flown.outputs[:, :-1], flown.output_names[:-1],
                        {})  # without r
    renames = {"theta_1s": "long_cyclic", "q": "pitch_rate"}
    renamed = type(flown)(flown.time, flown.inputs, tuple(renames.get(n, n) for n in flown.input_names),
                          flown.outputs, tuple(renames.get(n, n) for n in flown.output_names), {})
    path = tmp_path / "renamed.csv"
    write_recording(path, renamed)
    column_map = tmp_path / "map.json"
    column_map.write_text('{"long_cyclic": "theta_1s", "pitch_rate": "q"}')
    model = effect_model(fmu, purpose="test")
    mapped = prepare([path], model, column_map=read_column_map(column_map))
    direct = prepare([flown], model)
    assert mapped.output_names == direct.output_names
    np.testing.assert_array_equal(mapped.measured[0], direct.measured[0])
    np.testing.assert_array_equal(mapped.inputs[0], direct.inputs[0])
    for text, message in (('{"long_cyclic": "theta_9", "pitch_rate": "q"}', "none of"),
                          ('{"long_cyclic": "theta_1s", "pitch_rate": "q", "yaw_gyro": "r"}',
                           "which no recording has"),
                          ('{"long_cyclic": "theta_1s", "pitch_rate": "q", "stick": "theta_1c"}',
                           "--map renames columns"),
                          ('["long_cyclic"]', "a JSON object of names"),
                          ('{"long_cyclic": "q", "pitch_rate": "q"}', "more than one column")):
        column_map.write_text(text)
        code = main(["diagnose", str(path), "--reference", fmu, "--map", str(column_map),
                     "--out", str(tmp_path / "out")])
        err = capsys.readouterr().err
        assert code == 2 and message in err and err.count("\n") == 1, err


def test_dead_band_and_delay_act_about_the_inputs_first_value(fmu, manoeuvre):
    """A dead band passes nothing within its half-width of the recording's first input value and
    the rest short by it; a delay holds the first value before the recording (an input that
    does not start at zero is not delayed from zero): both as the built-in reference with those
    inputs (1e-9)."""
    time, inputs = manoeuvre
    offset, width = np.radians(0.5), np.radians(0.4)
    shifted = inputs + np.array([0.0, offset, 0.0, 0.0])
    shifted[-50:, 1] += np.radians(0.2)  # a last second inside the dead band
    through_fmu, built_in = effect_model(fmu, purpose="test"), Bo105Reference(80)
    replays = through_fmu.simulate_many([[{"effect": "dead_band", "input": "theta_1s", "value": width}],
                                         [{"effect": "time_delay", "input": "theta_1s", "value": 3 * STEP}]],
                                        time, shifted)
    deviation = shifted[:, 1] - offset
    banded = shifted.copy()
    banded[:, 1] = offset + np.sign(deviation) * np.maximum(np.abs(deviation) - width, 0.0)
    delayed = shifted.copy()
    delayed[:, 1] = np.concatenate([np.full(3, offset), shifted[:-3, 1]])
    assert np.any(np.abs(deviation) > width) and np.any((np.abs(deviation) < width) & (deviation != 0))
    for replay, flown in zip(replays, (banded, delayed)):
        np.testing.assert_allclose(replay, built_in.simulate_states(time, flown), rtol=0, atol=1e-9)


def test_parallel_and_resumed_replays_equal_fresh_ones(fmu, manoeuvre):
    """Replays on two worker processes, and replays that resume from a kept replay's saved FMU
    state, are bit for bit the replays of a fresh instance, one at a time (a replay with a
    search term's feedback too, which resumes from none without it)."""
    from validation.vehicles.fmu_reference import FMUReference

    time, inputs = manoeuvre
    later = inputs.copy()
    later[len(time) // 2:, 2] *= 1.5  # differs from the first replay only in its second half
    fed_back = ((1, 3, 2, 2, -0.2),)  # theta_1s receives -0.2 q (a linear term, kind 3, of signal 2)
    requests = [(time, inputs, {}, {}, ()), (time, later, {}, {}, ()), (time, inputs, {"M_q": -3.0}, {}, ()),
                (time, later, {"M_q": -3.0}, {"q": 0.01}, ()), (time, later, {}, {}, fed_back)]
    fresh = [FMUReference(fmu, workers=1).replay(t, u, parameters=p, start=s, feedback=f)
             for t, u, p, s, f in requests]
    kept = FMUReference(fmu, workers=1)
    serial = kept.replay_many(requests)
    assert kept.steps_resumed >= len(time) // 2 - 1  # the second replay resumed halfway
    parallel = FMUReference(fmu, workers=2).replay_many(requests)
    for expected, one, other in zip(fresh, serial, parallel):
        np.testing.assert_array_equal(one, expected)
        np.testing.assert_array_equal(other, expected)


_CRASHING_SLAVE = '''
import os
import signal

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real


class Crashing(Fmi2Slave):
    """A first-order lag whose process dies at its second step when the parameter crash is 1."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.u, self.y, self.crash = 0.0, 0.0, 0.0
        self.register_variable(Real("u", causality=Fmi2Causality.input))
        self.register_variable(Real("y", causality=Fmi2Causality.output))
        self.register_variable(Real("crash", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.fixed))

    def do_step(self, current_time, step_size):
        if self.crash > 0.5 and current_time > 0.5 * step_size:
            os.kill(os.getpid(), signal.SIGKILL)
        self.y += step_size * (self.u - self.y)
        return True
'''


@pytest.mark.slow
def test_an_fmu_whose_process_dies_ends_only_that_candidate(tmp_path, caplog):
    """Replays run in worker processes, so an FMU that kills its process (a crash inside it)
    ends the candidate that made it crash, with a message; the other candidates of the batch
    are replayed, and the next batch runs on fresh workers."""
    from pythonfmu.builder import FmuBuilder

    script = tmp_path / "crashing.py"
    script.write_text(_CRASHING_SLAVE)
    path = str(FmuBuilder.build_FMU(script, dest=tmp_path))
    model = effect_model(path, purpose="test")
    model.workers = 2
    time = np.arange(20) * 0.1
    inputs = np.ones((20, 1))
    crash, fine, also_fine = model.simulate_many(
        [[{"effect": "fmu_parameter", "term": "crash", "value": 1.0}], [], [{"effect": "input_gain", "input": "u",
                                                                          "value": 2.0}]], time, inputs)
    assert np.isnan(crash).all() and np.isfinite(fine).all()
    np.testing.assert_allclose(also_fine, 2 * fine, rtol=1e-12)
    assert any("process died" in record.message for record in caplog.records)
    again = model.simulate_many([[], []], time, inputs)
    np.testing.assert_array_equal(again[0], fine)


def test_a_sensor_bias_from_the_first_sample_is_not_a_start_state(fmu, manoeuvre):
    """A roll-attitude sensor that reads 0.01 rad high starts the recording at phi = 0.01: the
    replay without effects starts there (a tilted aircraft), and the replay with that bias
    starts at the trim the sensor hides and reads the recording exactly (1e-9)."""
    from validation.core.recordings import Recording

    time, inputs = manoeuvre
    flown = Bo105Reference(80).simulate(time, inputs)
    phi, bias = flown.output_names.index("phi"), 0.01
    outputs = flown.outputs.copy()
    outputs[:, phi] += bias
    recording = Recording(time, inputs, flown.input_names, outputs, flown.output_names, {})
    model = effect_model(fmu, purpose="test")
    start = model.start_state(recording)
    assert start[model.state_names.index("phi")] == pytest.approx(bias)
    tilted, biased = model.simulate_many([[], [{"effect": "sensor_bias", "output": "phi", "value": bias}]],
                                         time, inputs, start=start)
    np.testing.assert_allclose(biased, outputs, rtol=0, atol=1e-9)
    assert tilted[0, phi] == pytest.approx(bias) and np.abs(tilted - outputs).max() > 2 * bias  # 4x in 6 s


@pytest.mark.slow
def test_a_dead_band_is_named_when_the_manoeuvre_has_two_amplitudes(fmu):
    """A 0.3 deg dead band on longitudinal cyclic, flown through the FMU with 3-2-1-1s of 1 deg
    and then 2.5 deg (at one amplitude a dead band is a lower gain, exactly, on a 3-2-1-1), each
    in 4.5 s (the 3-2-1-1 ends at 3.8 s): named first, the true half-width inside its interval
    (measured 0.00523 rad, -0.5 % to +0.3 %)."""
    width = np.radians(0.3)
    time, small = identification_manoeuvre(duration=4.5, sample_time=DIAGNOSE_STEP)
    inputs = np.vstack([small, 2.5 * small[1:]])
    time = np.arange(len(inputs)) * DIAGNOSE_STEP
    aircraft = EffectVehicle(effect_model(fmu, purpose="test"), [{"effect": "dead_band", "input": "theta_1s",
                                                                 "value": width}], noise_sd=SENSOR_NOISE_STD)
    fit, held = aircraft.simulate(time, inputs, seed=1), aircraft.simulate(time, -inputs, seed=2)
    findings = diagnose([fit], reference=fmu, holdout=[held], workers=1).as_dict()["findings"]
    first = findings[0]
    assert (first["effect"], first["input"]) == ("dead_band", "theta_1s"), findings
    assert first["interval"][0] <= width <= first["interval"][1]
    assert "dead band on theta_1s" in first["statement"]
