"""Scope: an effect every diagnosed flight shares is told from one that differs per flight (a
random effect), with its spread; only shared ones correct the vehicle's model."""
import numpy as np
import pytest

from validation.diagnose import diagnose
from validation.diagnose.scope import _random_effects
from validation.vehicles.blimp_effects import SENSOR_NOISE_STD, identification_manoeuvre
from validation.vehicles.effect_vehicle import EffectVehicle


@pytest.mark.parametrize("values, kind", [
    ((0.30, 0.30, 0.30), "shared"),  # one value: Q = 0
    ((3.0, -2.0, 1.0), "per_recording"),  # differ, both signs: no shared part beyond the spread
    ((3.0, 3.5, 2.5), "varies"),  # differ around a shared 3, far from the model's 0
])
def test_random_effects_kinds(values, kind):
    values = np.array(values)
    found = _random_effects(values, np.full(3, 1e-6), 0.0)
    assert found["kind"] == kind
    if kind != "shared":  # DerSimonian-Laird: tau^2 -> the sample variance as the Wald variances -> 0
        assert found["spread"] == pytest.approx(np.std(values, ddof=1), rel=1e-3)
        assert found["mean"] == pytest.approx(np.mean(values), rel=1e-3)


def test_one_value_within_the_noise_is_shared_and_its_spread_zero():
    found = _random_effects(np.array([1.0, 1.1, 0.9]), np.full(3, 0.04), 0.0)  # 0.2 sd each
    assert found["kind"] == "shared" and found["spread"] == 0.0 and found["heterogeneity_p"] > 0.5


def _flight(buoyancy_offset, *, variant, seed):
    """A blimp flight with a 0.3 s gondola-fan lag (the vehicle's) and, when not 0, a buoyancy
    imbalance of this flight only, N."""
    effects = [{"effect": "input_lag", "input": "u_gondola", "value": 0.3}]
    if buoyancy_offset:
        effects.append({"effect": "force_offset", "term": "Z_0", "value": buoyancy_offset})
    return EffectVehicle("blimp", effects, noise_sd=SENSOR_NOISE_STD).simulate(
        *identification_manoeuvre(variant=variant, duration=12.0), seed=seed)


@pytest.mark.slow
def test_a_per_flight_buoyancy_difference_is_per_flight_and_a_shared_lag_shared():
    """Three flights with buoyancy imbalances of +3, -2 and +1 mN and one gondola lag: the lag
    is shared and kept; the imbalance is named, said to differ per flight with its values and
    spread, and left out of the corrected model, which then does not spoil the held-out height."""
    flights = [_flight(z, variant=0, seed=s) for z, s in ((0.003, 1), (-0.002, 2), (0.001, 3))]
    diagnosis = diagnose(flights, reference="blimp", holdout=[_flight(0.0, variant=1, seed=4)])
    findings = {f.get("term") or f.get("input"): f for f in diagnosis.findings if f["effect"] != "unexplained"}
    lag, offset = findings["u_gondola"], findings["Z_0"]
    assert lag["scope"]["kind"] == "shared" and lag["in_corrected_model"] and lag["carries_over"]
    assert lag["value"] == pytest.approx(0.3, abs=0.01)
    assert offset["scope"]["kind"] == "per_recording" and not offset["in_corrected_model"]
    np.testing.assert_allclose(offset["scope"]["values"], [0.003, -0.002, 0.001], atol=2e-4)
    assert offset["scope"]["spread"] == pytest.approx(np.std([0.003, -0.002, 0.001], ddof=1), rel=0.2)
    assert "differs per flight" in offset["statement"] and "Every diagnosed flight shares it" in lag["statement"]
    assert [e["effect"] for e in diagnosis.corrected.effects] == ["input_lag"]
    fit = diagnosis.fit
    assert fit["rmse_corrected"]["z"] < 2 * SENSOR_NOISE_STD["z"]
