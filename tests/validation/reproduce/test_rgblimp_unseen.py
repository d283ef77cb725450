"""Tests of the study of configurations never flown (validation/reproduce/rgblimp_unseen.py): the
folds, a short study on the first two seconds of the shipped excerpt's flights whose fits never see
the held-out configuration, and the command's one-line errors. The measured numbers are in docs/rgblimp.md."""
import contextlib
import io
import json
import math
from dataclasses import replace

import numpy as np
import pytest

from validation.cli import main
from validation.core.errors import BadInputError
from validation.reproduce import rgblimp_unseen
from validation.reproduce.rgblimp_unseen import UNSEEN_MODELS, fold_of, study_unseen

from .test_rgblimp import QUICK, _folder, _short_excerpt


def test_folds_deal_the_configurations_in_turn():
    assert fold_of([0, 3, 17, 29, 30], 2) == {0: 0, 3: 1, 17: 0, 29: 1, 30: 0}
    assert set(fold_of(range(35), 35).values()) == set(range(35))  # leave-one-configuration-out


@pytest.mark.slow
def test_a_short_study_never_fits_on_the_held_out_configuration(tmp_path, monkeypatch):
    """Configurations 29 and 30 of the excerpt in two folds: each fold's vehicle identification
    and hybrid see only the other configuration's fitting flights; each held-out test flight is
    scored by the three models; results.json and report.md agree with the entries."""
    data = _short_excerpt(tmp_path / "data")
    seen = []
    fit_global, fit_rollout_global = rgblimp_unseen.fit_global, rgblimp_unseen.fit_rollout_global

    def spy_global(fitting, *args, **kwargs):
        seen.append(("physics", sorted(f.number for f in fitting)))
        return fit_global(fitting, *args, **kwargs)

    def spy_hybrid(groups, **kwargs):
        assert kwargs["shared_physics"]
        seen.append(("hybrid", sorted(f.number for flights, _ in groups for f in flights)))
        return fit_rollout_global(groups, **kwargs)

    monkeypatch.setattr(rgblimp_unseen, "fit_global", spy_global)
    monkeypatch.setattr(rgblimp_unseen, "fit_rollout_global", spy_hybrid)
    out = tmp_path / "out"
    out.mkdir()
    # The quick setup with 3 identification iterations: the folds' bookkeeping, not the numbers.
    results = study_unseen(data, out, folds=2, setup=replace(QUICK, max_iterations=3), progress=False)
    # Fold 0 holds configuration 29 (fitted on 121, 122 only), fold 1 configuration 30.
    assert seen == [("physics", [121, 122]), ("hybrid", [121, 122]), ("physics", [117, 118]), ("hybrid", [117, 118])]
    written = json.loads((out / "results.json").read_text())
    assert [(e["index"], e["fold"], e["test"]) for e in written["configurations"]] == [
        (29, 0, "data_119.csv"), (30, 1, "data_123.csv")]
    for entry in written["configurations"]:
        assert set(entry["score"]) == set(UNSEEN_MODELS) == set(entry["position_rmse_m"])
        assert all(math.isfinite(v) and v > 0 for v in entry["score"].values())
        assert 0 <= entry["coverage95_position"] <= 1
    summary = written["summary"]
    for name in UNSEEN_MODELS:
        assert math.isclose(summary["mean_score"][name], np.mean([e["score"][name] for e in results["configurations"]]))
    beats = sum(e["score"]["vehicle_hybrid"] < e["score"]["identified"] for e in written["configurations"])
    assert summary["goal_beats_identified"]["measured"] == f"{beats} of 2"
    assert "vehicle_hybrid" in (out / "report.md").read_text()


@pytest.mark.parametrize("args, message", [
    (["rgblimp-unseen", "--folds", "1"], "--folds must be between 2"),
    (["rgblimp", "--folds", "3"], "--folds applies to reproduce rgblimp-unseen only"),
])
def test_bad_folds_exit_2_with_one_line(args, message, tmp_path):
    data = _folder(tmp_path / "data", [117, 118, 119, 121, 122, 123])
    with contextlib.redirect_stderr(io.StringIO()) as stderr:
        code = main(["reproduce", *args, "--data", str(data), "--out", str(tmp_path / "out")])
    assert code == 2 and stderr.getvalue().count("\n") == 1 and message in stderr.getvalue()
    with pytest.raises(BadInputError):
        study_unseen(data, tmp_path / "out2", folds=3, progress=False)
