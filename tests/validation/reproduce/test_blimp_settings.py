"""Tests of the blimp RKGP settings study (validation/reproduce/blimp_settings.py) and its command."""
import json
import math

import pytest

from validation.cli import main
from validation.reproduce.blimp_settings import CANDIDATES, CHOSEN, VALIDATION_FLIGHT, choose_settings, format_settings


def test_candidates_change_one_setting_of_the_chosen_configuration():
    names = [c.name for c in CANDIDATES]
    assert len(set(names)) == len(names) and CANDIDATES[0] == CHOSEN
    for candidate in CANDIDATES[1:]:
        changed = [field for field in ("smoothing", "command_lags", "process_noise_scale")
                   if getattr(candidate, field) != getattr(CHOSEN, field)]
        assert len(changed) == 1, candidate


@pytest.mark.slow
def test_quick_study_scores_candidates_on_the_validation_flight(tmp_path, capsys):
    """Three candidates (the chosen, recorded states, a process-noise variant) in the quick
    setup: finite scores for RKGP and RK from the same starts, their ratios; the process-noise
    variant reuses the chosen model's fit (only the start filter differs)."""
    results = choose_settings(candidates=(CANDIDATES[0], CANDIDATES[1], CANDIDATES[-1]), quick=True)
    assert list(results["candidates"]) == [CANDIDATES[0].name, CANDIDATES[1].name, CANDIDATES[-1].name]
    for name, entry in results["candidates"].items():
        for model in ("RKGP", "RK"):
            assert all(math.isfinite(v) and v > 0 for v in entry[model].values()), (name, model)
        assert entry["RK_over_RKGP"]["position"] == pytest.approx(
            entry["RK"]["position"] / entry["RKGP"]["position"], rel=1e-12)
    assert results["candidates"][CANDIDATES[-1].name]["fit_seconds"] < 0.01  # reused, not refitted
    assert str(list(VALIDATION_FLIGHT)) in results["setup"]["validation_flight"]
    assert CANDIDATES[1].name in format_settings(results)


def test_cli_settings_study_refuses_seeds(tmp_path, capsys):
    assert main(["reproduce", "blimp-settings", "--out", str(tmp_path / "out"), "--seed", "2"]) == 2
    assert "fixed seeds" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_cli_settings_study_writes_settings_json(tmp_path, capsys, monkeypatch):
    """The command with a two-candidate list (the full list takes minutes)."""
    from validation.reproduce import blimp_settings

    original = blimp_settings.choose_settings
    monkeypatch.setattr(blimp_settings, "choose_settings",
                        lambda **kwargs: original(candidates=CANDIDATES[:2], **kwargs))
    assert main(["reproduce", "blimp-settings", "--out", str(tmp_path), "--quick"]) == 0
    written = json.loads((tmp_path / "settings.json").read_text())
    assert list(written["candidates"]) == [c.name for c in CANDIDATES[:2]]
    assert "settings.json" in capsys.readouterr().out
