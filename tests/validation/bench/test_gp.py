"""validation.bench.gp: GP fitting and prediction against scikit-learn's GaussianProcessRegressor."""
import math

from validation.bench import gp


def test_reaches_at_least_sklearns_optimum_and_reports_every_size():
    report = gp.run(sizes=(30, 60), n_restarts=0, progress=False)
    assert [row["n"] for row in report["rows"]] == [30, 60]
    assert (report["n_restarts"], report["peer"]) == (0, "scikit-learn GaussianProcessRegressor")
    for row in report["rows"]:
        for key in ("fit_s", "fit_s_sklearn", "lml", "lml_sklearn", "predict_s", "predict_s_sklearn"):
            assert math.isfinite(row[key]), key
        assert row["fit_s"] > 0 and row["fit_s_sklearn"] > 0
        assert row["fit_speedup"] == row["fit_s_sklearn"] / row["fit_s"]
        assert row["predict_speedup"] == row["predict_s_sklearn"] / row["predict_s"]
        # Both optimisers start from the same hyperparameters on the same function; flightgp's
        # optimum must be at least as good (1e-3 covers L-BFGS-B stopping tolerances).
        assert row["lml"] >= row["lml_sklearn"] - 1e-3
    # The summary: one headline row per size, the fit speedup against the >= 6x goal.
    summary = gp.summary_rows(report)
    assert [row.id for row in summary] == ["gp.fit.speedup.n30", "gp.fit.speedup.n60"]
    for headline, row in zip(summary, report["rows"]):
        assert headline.goal == 6.0 and headline.unit == "x" and headline.met == (row["fit_speedup"] >= 6.0)
    table = gp.format_table(report).splitlines()
    assert "speedup" in table[0] and len(table) == 2 + len(report["rows"])
