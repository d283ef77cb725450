"""validation.campaign and ``flightgp campaign``: on a real Dask cluster of two worker processes
(one thread each), shared by the module: a Monte Carlo of the Bo105 reference FMU with a task the
FMU refuses, resuming, a worker killed mid-campaign, ``diagnose-bench`` over two seeds, a QTG
against two models side by side, bad specs and cluster options; and (slow) a scheduler and two
workers started as separate processes."""
from __future__ import annotations

import csv
import functools
import json
import os
import subprocess
import sys
import time
from contextlib import ExitStack
from pathlib import Path
from xml.etree import ElementTree

import cloudpickle
import numpy as np
import pytest

from validation import qtg
from validation.campaign import parse_spec, read_result, read_spec, run_campaign, task_folder
from validation.campaign.tasks import FileBundle, run_task
from validation.cli.main import main
from validation.vehicles import get_vehicle, read_recording

ROOT = Path(__file__).resolve().parents[3]
#: A short Monte Carlo of the Bo105 reference FMU (4 s at 100 Hz, a 3-2-1-1 of sampled amplitude
#: and step time on longitudinal cyclic, sampled rate-sensor noise) and one task the FMU refuses:
#: a start pitch rate of 50 rad/s, beyond the FMU's plausible 10 rad/s.
MONTE_CARLO = {
    "name": "bo105-mc-test", "seed": 3,
    "studies": [
        {"id": "mc", "kind": "cosim", "fmu": {"reference": "bo105-80kt"}, "duration": 4.0, "samples": 6,
         "inputs": {"theta_1s": {"manoeuvre": "3211", "amplitude_deg": {"uniform": [0.5, 1.5]},
                                 "step_time": {"uniform": [0.3, 0.5]}, "start": 0.5}},
         "outputs": ["p", "q", "r"], "noise": {"q": {"uniform": [0.001, 0.004]}, "p": 0.002},
         "compare_with": "bo105-80kt-flight"},
        {"id": "refused", "kind": "cosim", "fmu": {"reference": "bo105-80kt"}, "duration": 1.0,
         "start_values": {"q": 50.0}},
    ],
}


@pytest.fixture(scope="module")
def cluster():
    """The address of a local cluster of two worker processes, one thread each, started as
    ``flightgp campaign`` starts its own."""
    from validation.campaign.runner import dask_client

    with dask_client(workers=2) as client:
        yield client.scheduler.address


def _write_spec(folder: Path, spec: dict, name: str = "spec.json") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(json.dumps(spec), encoding="utf-8")
    return path


def _rows(out: Path) -> list:
    with open(out / "results.csv", newline="", encoding="utf-8") as stream:
        return list(csv.DictReader(stream))


@pytest.fixture(scope="module")
def monte_carlo(tmp_path_factory, cluster):
    """``flightgp campaign`` on :data:`MONTE_CARLO` (building the reference FMU into DIR/fmus)."""
    folder = tmp_path_factory.mktemp("campaign")
    spec_path = _write_spec(folder, MONTE_CARLO)
    out = folder / "out"
    code = main(["campaign", str(spec_path), "--out", str(out), "--scheduler", cluster,
                 "--no-progress"])
    return spec_path, out, code


def test_a_monte_carlo_of_the_reference_fmu_records_every_task_and_the_failure(monte_carlo):
    spec_path, out, code = monte_carlo
    assert code == 0
    rows = _rows(out)
    assert [row["id"] for row in rows] == [f"mc-{i:03d}" for i in range(6)] + ["refused-000"]
    assert [row["status"] for row in rows] == ["done"] * 6 + ["failed"]
    assert rows[-1]["message"] == "FMICallException: fmi2DoStep failed with status 2 (discard)."
    assert all(row["worker"].startswith("tcp://") and float(row["wall_time_s"]) > 0 for row in rows[:6])
    amplitudes = [float(row["inputs.theta_1s.amplitude_deg"]) for row in rows[:6]]
    assert all(0.5 <= a <= 1.5 for a in amplitudes) and len(set(amplitudes)) == 6  # drawn per task
    summary = json.loads((out / "summary.json").read_text())
    assert (summary["tasks"], summary["done"], summary["failed"], summary["missing"]) == (7, 6, 1, 0)
    assert summary["failures"][0]["id"] == "refused-000"
    statistics = summary["statistics"]["mc"]["rmse_q"]
    values = sorted(float(row["rmse_q"]) for row in rows[:6])
    assert statistics["count"] == 6 and statistics["p50"] == pytest.approx(np.median(values))
    assert values[0] <= statistics["p5"] <= statistics["p95"] <= values[-1]
    assert (out / "fmus" / "bo105_80kt_reference.fmu").is_file()


def test_a_cosim_task_recording_is_the_reference_model_plus_its_seeded_noise(monte_carlo):
    """The FMU, run on a worker with a kept instance, equals the Python reference on the task's
    inputs; the noise is the task's seed's draw (tolerance 1e-9 rad/s: both discretise the same
    model exactly, the FMU in another process, so only rounding differs)."""
    _, out, _ = monte_carlo
    for task_id in ("mc-000", "mc-005"):
        result = json.loads((task_folder(out, task_id) / "result.json").read_text())
        recording = read_recording(task_folder(out, task_id) / "recording.csv")
        reference = get_vehicle("bo105-80kt")
        states = reference.simulate_states(recording.time, recording.inputs)
        truth = states[:, [reference.state_names.index(n) for n in recording.output_names]]
        seed, noise = result["task"]["seed"], result["task"]["settings"]["noise"]
        sd = np.array([noise.get(name, 0.0) for name in recording.output_names])
        draws = np.random.default_rng(seed).standard_normal(truth.shape) * sd
        np.testing.assert_allclose(recording.outputs, truth + draws, rtol=0, atol=1e-9)
        assert result["figures"]["peak_q"] == pytest.approx(np.max(np.abs(recording.output("q"))))


def test_running_again_resumes_only_what_is_missing(monte_carlo, cluster):
    spec_path, out, _ = monte_carlo
    before = (out / "results.csv").read_text()
    spec = read_spec(spec_path)
    again = run_campaign(spec, out, scheduler=cluster, progress=False)
    assert (again.ran, again.resumed, again.workers) == (0, 7, 0)  # no cluster needed
    assert (out / "results.csv").read_text() == before
    (task_folder(out, "mc-002") / "result.json").unlink()
    again = run_campaign(spec, out, scheduler=cluster, progress=False)
    assert (again.ran, again.resumed, again.done) == (1, 6, 6)
    after = _rows(out)
    dropped = ("wall_time_s", "worker")  # the rerun is timed afresh, perhaps on the other worker
    assert [{k: v for k, v in row.items() if k not in dropped} for row in after] == \
           [{k: v for k, v in row.items() if k not in dropped} for row in _rows_of(before)]
    retried = run_campaign(spec, out, scheduler=cluster, progress=False, retry_failed=True)
    assert (retried.ran, retried.failed) == (1, 1)


def _rows_of(text: str) -> list:
    return list(csv.DictReader(text.splitlines()))


def _dies_once(task, bundles, *, marker: str, victim: str):
    """What the workers run in the killed-worker test: the worker running ``victim`` dies the first
    time (``os._exit``; the marker file says it happened), then the task runs as usual."""
    if task.id == victim and not os.path.exists(marker):
        open(marker, "w").close()
        os._exit(1)
    return run_task(task, bundles)


def test_a_worker_killed_mid_campaign_loses_nothing(monte_carlo, cluster, tmp_path):
    _, mc_out, _ = monte_carlo
    fmu = mc_out / "fmus" / "bo105_80kt_reference.fmu"
    spec = parse_spec({"studies": [{"id": "k", "kind": "cosim", "fmu": str(fmu), "duration": 2.0, "samples": 4,
                                    "inputs": {"theta_1s": {"manoeuvre": "doublet", "amplitude": 0.01}}}]},
                      base_dir=tmp_path)
    marker = tmp_path / "killed"
    module = sys.modules[__name__]
    cloudpickle.register_pickle_by_value(module)  # the workers cannot import the tests
    try:
        run = run_campaign(spec, tmp_path / "out", scheduler=cluster, progress=False,
                           execute=functools.partial(_dies_once, marker=str(marker), victim="k-001"))
    finally:
        cloudpickle.unregister_pickle_by_value(module)
    assert marker.exists()
    assert (run.done, run.failed) == (4, 0)
    # The victim is reported; so may be the tasks queued on, or finished but not yet collected
    # from, the worker that died (Dask runs those again too).
    assert ("k-001", 1) in run.interrupted
    assert read_result(tmp_path / "out", spec.tasks[1].as_dict()).workers_lost == 1
    assert {"id": "k-001", "workers_lost": 1} in json.loads((tmp_path / "out" / "summary.json").read_text())[
        "interrupted"]
    rows = _rows(tmp_path / "out")
    assert [row["id"] for row in rows] == ["k-000", "k-001", "k-002", "k-003"]
    assert rows[1]["workers_lost"] == "1" and all(row["status"] == "done" for row in rows)
    # Nothing lost or changed: every task's figures are those of a run in this process.
    bundles = {label: FileBundle.read(label, fmu) for label in spec.files}
    for task, row in zip(spec.tasks, rows):
        figures = run_task(task, bundles).output.figures
        assert {name: float(row[name]) for name in figures} == pytest.approx(figures, rel=1e-12)


def test_diagnose_bench_over_two_seeds_runs_on_the_cluster_and_scores_as_in_process(cluster, tmp_path):
    from validation.diagnose.bench import concealed_cases, run_bench

    out = tmp_path / "bench"
    code = main(["diagnose-bench", "--cases", "none", "delay-theta_1s-60ms", "--duration", "5", "--seed", "0", "1",
                 "--scheduler", cluster, "--out", str(out), "--no-progress"])
    assert code == 0
    scorecard = json.loads((out / "scorecard.json").read_text())
    assert scorecard["summary"]["seeds"] == [0, 1] and scorecard["summary"]["total"] == 4
    assert [row["case"] for row in scorecard["runs"][0]["cases"]] == ["delay-theta_1s-60ms", "none"]
    assert len(list((out / "campaign" / "tasks").iterdir())) == 4
    alone = run_bench([case for case in concealed_cases() if case.name == "none"], seed=1, duration=5.0)
    on_cluster = scorecard["runs"][1]["cases"][1]
    assert {k: v for k, v in on_cluster.items() if k != "seconds"} == \
           {k: v for k, v in alone["cases"][0].items() if k != "seconds"}


#: A QTG of two tests on tests/conftest.py's qtg_flights, which lie outside the spec's folder
#: (``{flights}``: their folder relative to it): a doublet flown on the reference, which it
#: matches, and the stand-in's 3-2-1-1, whose pitch rate it misses.
SIDE_BY_SIDE_QTG = """title = "side by side"
[[test]]
id = "pitch rate, longitudinal cyclic doublet"
recording = "{flights}/ref_theta_1s_doublet.csv"
outputs = ["q"]
[[test]]
id = "pitch rate, longitudinal cyclic 3-2-1-1"
recording = "{flights}/flight_theta_1s_3211.csv"
outputs = {{ q = "2 deg/s" }}
"""


def _side_by_side_qtg(tmp_path: Path, qtg_flights: Path) -> Path:
    """:data:`SIDE_BY_SIDE_QTG` as ``tmp_path/qtg/side.toml``."""
    (tmp_path / "qtg").mkdir(exist_ok=True)
    spec = tmp_path / "qtg" / "side.toml"
    spec.write_text(SIDE_BY_SIDE_QTG.format(flights=os.path.relpath(qtg_flights, spec.parent)), encoding="utf-8")
    return spec


def test_a_qtg_study_qualifies_two_models_side_by_side(cluster, qtg_flights, bo105_reference_fmu, tmp_path):
    """The reference FMU and the registry's reference, one task each on the cluster: the workers
    read the QTG spec and its recordings as the campaign carried them (from a folder of their
    own, the recordings at the paths the spec names them by) and both models give the verdicts
    and excursions of a run in this process."""
    _side_by_side_qtg(tmp_path, qtg_flights)
    spec = _write_spec(tmp_path, {"studies": [
        {"id": "fmu", "kind": "qtg", "spec": "qtg/side.toml", "fmu": str(bo105_reference_fmu)},
        {"id": "ref", "kind": "qtg", "spec": "qtg/side.toml", "reference": "bo105-80kt"}]})
    out = tmp_path / "out"
    assert main(["campaign", str(spec), "--out", str(out), "--scheduler", cluster, "--no-progress"]) == 0
    with ExitStack() as stack:
        alone = qtg.run_qtg(qtg.read_spec(tmp_path / "qtg" / "side.toml"),
                            qtg.open_model(stack, reference="bo105-80kt"), progress=False)
    excursion = alone.tests[1].outputs["q"].excursion
    assert [t.status for t in alone.tests] == ["passed", "failed"] and excursion > 0.05
    rows = _rows(out)
    assert [(row["id"], row["status"]) for row in rows] == [("fmu-000", "done"), ("ref-000", "done")]
    for row in rows:
        counts = {key: float(row[key]) for key in ("passed", "failed", "errors", "not_run", "all_passed")}
        assert counts == {"passed": 1, "failed": 1, "errors": 0, "not_run": 0, "all_passed": 0}
        assert float(row["01.q.excursion"]) == 0
        assert float(row["02.q.excursion"]) == pytest.approx(excursion, rel=1e-9)
        folder = task_folder(out, row["id"])
        report = json.loads((folder / "qtg.json").read_text())
        assert report["spec"] == "qtg/side.toml" and [t["status"] for t in report["tests"]] == ["passed", "failed"]
        suite = ElementTree.parse(folder / "junit.xml").getroot()[0]
        assert (suite.get("tests"), suite.get("failures")) == ("2", "1")
        assert len(list((folder / "plots").glob("*.png"))) == 2 and (folder / "qtg.html").is_file()
        assert {"junit.xml", "qtg.json", "summary.md"} <= set(json.loads((folder / "result.json").read_text())["files"])
    assert json.loads((task_folder(out, "fmu-000") / "qtg.json").read_text())["model"]["kind"] == "fmu"


@pytest.mark.parametrize(("study", "says"), [
    ({"spec": "missing.toml", "reference": "bo105-80kt"}, "studies[0] (\"q\").spec: no such file 'missing.toml'"),
    ({"spec": "qtg/side.toml", "fmu": "model.fmu", "reference": "bo105-80kt"},
     "give the model to qualify as 'fmu' (an FMU file, or {\"reference\": NAME} built by the campaign) or as "
     "'reference'"),
    ({"spec": "qtg/side.toml", "reference": "model.fmu"}, "'model.fmu' is an FMU; give it as 'fmu'"),
    ({"spec": "qtg/side.toml", "reference": "bo105-85kt"}, "task q-000 (study q): reference: no Bo105 model at 85 kt"),
])
def test_a_bad_qtg_study_is_refused_before_anything_runs(qtg_flights, tmp_path, capsys, study, says):
    _side_by_side_qtg(tmp_path, qtg_flights)
    spec = _write_spec(tmp_path, {"studies": [{"id": "q", "kind": "qtg", **study}]})
    assert main(["campaign", str(spec), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    error = capsys.readouterr().err
    assert error.startswith("flightgp campaign: error: ") and error.count("\n") == 1, error
    assert says in error
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("text", "says"), [
    ("{\"studies\": [", "line 1, column 14: not JSON"),
    (json.dumps({"studies": [{"id": "a", "kind": "simulate"}]}), "unknown kind \"simulate\""),
    (json.dumps({"studies": [{"id": "a", "kind": "cosim", "fmu": {"reference": "bo105-80kt"}}]}),
     "missing field 'duration'"),
    (json.dumps({"studies": [{"id": "a", "kind": "cosim", "fmu": {"reference": "bo105-80kt"}, "duration": 1,
                              "parameters": {"M_q": {"uniform": [2, 1]}}}]}), "low < high"),
    (json.dumps({"studies": [{"id": "a", "kind": "cosim", "fmu": {"reference": "bo105-80kt"}, "duration": 1,
                              "noise": {"q": {"gaussian": [0, 1]}}}]}), "must be a finite number"),
    (json.dumps({"studies": [{"id": "a", "kind": "diagnose", "reference": "bo105-80kt",
                              "recordings": ["missing.csv"]}]}), "no such file 'missing.csv'"),
    (json.dumps({"studies": [{"id": "a", "kind": "cosim", "fmu": "bo105.fmu", "duration": 1,
                              "inputs": {"elevator": 0.1}}]}), "the FMU bo105.fmu has no input 'elevator'"),
    ('{"studies": [{"id": "a", "kind": "cosim", "fmu": "bo105.fmu", "duration": NaN}]}', "got NaN"),
    (json.dumps({"studies": [{"id": "a", "kind": "cosim", "fmu": "bo105.fmu", "duration": 1}], "sed": 1}),
     "unknown field 'sed'"),
    (json.dumps({"studies": [{"id": "a", "kind": "cosim", "fmu": "bo105.fmu", "duration": 1, "step": 2}]}),
     "task a-000 (study a): duration, step: sample time must be positive and at most the duration"),
    (json.dumps({"studies": [{"id": "a", "kind": "diagnose-bench", "reference": "bo105-85kt"}]}),
     "studies[0] (\"a\").reference: no Bo105 model at 85 kt"),
])
def test_a_bad_spec_exits_2_with_one_line(monte_carlo, tmp_path, capsys, text, says):
    _, mc_out, _ = monte_carlo
    (tmp_path / "bo105.fmu").write_bytes((mc_out / "fmus" / "bo105_80kt_reference.fmu").read_bytes())
    spec = tmp_path / "bad.json"
    spec.write_text(text, encoding="utf-8")
    assert main(["campaign", str(spec), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    error = capsys.readouterr().err
    assert error.startswith("flightgp campaign: error: ") and error.count("\n") == 1, error
    assert says in error and "Traceback" not in error
    assert not (tmp_path / "out" / "results.csv").exists()


def test_the_cluster_options_are_checked_before_anything_runs(tmp_path, capsys):
    spec = _write_spec(tmp_path, {"studies": [{"id": "a", "kind": "reproduce", "paper": "bo105"}]})
    assert main(["campaign", str(spec), "--out", str(tmp_path / "out"), "--workers", "0"]) == 2
    assert capsys.readouterr().err == "flightgp campaign: error: --workers must be at least 1, got 0\n"
    with pytest.raises(SystemExit) as usage:
        main(["campaign", str(spec), "--out", str(tmp_path / "out"), "--workers", "2", "--scheduler", "tcp://a:1"])
    assert usage.value.code == 2
    assert "error: argument --scheduler: not allowed with argument --workers" in capsys.readouterr().err
    (tmp_path / "not-a-scheduler.json").write_text("[]", encoding="utf-8")
    assert main(["campaign", str(spec), "--out", str(tmp_path / "out"), "--scheduler",
                 str(tmp_path / "not-a-scheduler.json")]) == 2
    assert "not-a-scheduler.json: not a Dask scheduler file" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_independent_runs_map_over_the_cluster_in_order_and_a_runs_error_is_raised(cluster, tmp_path, capsys):
    """What `flightgp reproduce blimp --seeds ... --cluster-workers N` spreads its seeds with
    (map_on_dask): results in the items' order whichever worker finishes first, and a run that
    raises raises its own error, as in this process. The option is refused where it does not
    apply, before anything runs."""
    import math

    from validation.campaign.runner import map_on_dask

    assert map_on_dask(math.factorial, [5, 3, 0, 4, 6], scheduler=cluster, progress=False) == [120, 6, 1, 24, 720]
    with pytest.raises(ValueError, match="math domain error"):
        map_on_dask(math.sqrt, [4.0, -1.0], scheduler=cluster, progress=False)
    assert main(["reproduce", "bo105", "--out", str(tmp_path / "out"), "--cluster-workers", "2"]) == 2
    assert "apply to reproduce blimp only" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_the_example_specs_expand_as_documented():
    montecarlo = read_spec(ROOT / "examples" / "campaigns" / "bo105_montecarlo.json")
    assert len(montecarlo.tasks) == 200 and montecarlo.files["reference:bo105-80kt"].reference == "bo105-80kt"
    assert len({json.dumps(task.settings["inputs"]) for task in montecarlo.tasks}) == 200
    bench = read_spec(ROOT / "examples" / "campaigns" / "diagnose_bench.json")
    assert {task.seed for task in bench.tasks} == {0, 1, 2, 3, 4}
    assert len(bench.tasks) == 5 * len({task.settings["case"] for task in bench.tasks})
    qtgs = read_spec(ROOT / "examples" / "campaigns" / "bo105_qtg.json")
    label = "../qtg/bo105_80kt.toml"
    assert [task.files for task in qtgs.tasks] == [(label, "reference:bo105-80kt"), (label,)]
    bundle = FileBundle.read(label, qtgs.files[label].path, companions=qtgs.files[label].companions)
    names = [name for name, _ in bundle.files]  # the spec, then its 12 recordings with their sidecars
    assert names[:3] == ["bo105_80kt.toml", "flights/theta_1s_3211.csv", "flights/theta_1s_3211.json"]
    assert len(names) == 25


def test_a_tasks_draws_depend_only_on_its_grid_point_and_sample(tmp_path):
    study = {"id": "s", "kind": "cosim", "fmu": {"reference": "bo105-80kt"}, "duration": 1,
             "parameters": {"M_q": {"normal": [-4, 0.2]}, "L_p": {"grid": [-10, -8]}}}
    few = parse_spec({"studies": [{**study, "samples": 2}]}, base_dir=tmp_path).tasks
    many = parse_spec({"studies": [{**study, "samples": 5}]}, base_dir=tmp_path).tasks
    assert [t.settings["parameters"]["L_p"] for t in many] == [-10] * 5 + [-8] * 5
    assert [t.settings for t in few[:2]] == [t.settings for t in many[:2]]
    assert [t.settings for t in few[2:]] == [t.settings for t in many[5:7]]  # renumbered, same draws
    assert [t.seed for t in many] == list(range(10))
    assert len({t.settings["parameters"]["M_q"] for t in many}) == 10  # a fresh draw per sample and grid point


@pytest.mark.slow
def test_an_existing_cluster_of_separate_processes_runs_the_campaign(monte_carlo, tmp_path):
    """``dask scheduler`` and two ``dask worker`` processes on localhost (the multi-machine recipe
    of docs/campaigns.md on one machine), reached through the scheduler file."""
    _, mc_out, _ = monte_carlo
    scheduler_file = tmp_path / "scheduler.json"
    dask = [sys.executable, "-m", "dask"]
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    processes = [subprocess.Popen([*dask, "scheduler", "--port", "0", "--no-dashboard",
                                   "--scheduler-file", str(scheduler_file)], **quiet)]
    try:
        deadline = time.monotonic() + 60
        while not scheduler_file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        processes.append(subprocess.Popen([*dask, "worker", "--scheduler-file", str(scheduler_file), "--nworkers", "2",
                                           "--nthreads", "1", "--no-dashboard", "--local-directory",
                                           str(tmp_path / "workers")], **quiet))
        fmu = mc_out / "fmus" / "bo105_80kt_reference.fmu"
        spec = _write_spec(tmp_path, {"studies": [{"id": "x", "kind": "cosim", "fmu": str(fmu), "duration": 2.0,
                                                   "samples": 4, "noise": {"q": 0.003}}]})
        code = main(["campaign", str(spec), "--out", str(tmp_path / "out"), "--scheduler", str(scheduler_file),
                     "--no-progress"])
        assert code == 0
        rows = _rows(tmp_path / "out")
        assert [row["status"] for row in rows] == ["done"] * 4
    finally:
        from distributed import Client

        try:  # stop the scheduler and its workers the Dask way: quick and clean
            if scheduler_file.exists():
                with Client(scheduler_file=str(scheduler_file), timeout=10) as client:
                    client.shutdown()
        except (OSError, TimeoutError):
            pass  # then the processes are ended below
        for process in reversed(processes):  # the workers (and their worker processes) first
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                process.terminate()
                try:
                    process.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait()
