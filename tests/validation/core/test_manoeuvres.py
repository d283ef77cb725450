"""Manoeuvres on the integer step grid."""
import numpy as np
import pytest

from validation.core.errors import BadInputError
from validation.core.manoeuvres import doublet, frequency_sweep, manoeuvre, step, three_two_one_one, time_grid


def test_time_grid_is_an_integer_step_counter():
    time = time_grid(duration=8.0, sample_time=0.01, start_time=2.0)
    assert len(time) == 801
    # t = t0 + k h exactly, never accumulated: sample 700 is 2 + 700 * 0.01 to the last bit.
    assert time[700] == 2.0 + 700 * 0.01
    assert np.all(np.diff(time) > 0)


def test_3211_widths_and_signs():
    h = 0.01
    time = time_grid(duration=6.0, sample_time=h)
    signal = three_two_one_one(time, amplitude=0.5, step_time=0.4, start=1.0)
    # Run-length encode the non-zero part: 3, 2, 1, 1 steps of 0.4 s = 120, 80, 40, 40 samples.
    change = np.flatnonzero(np.diff(signal)) + 1
    runs = np.diff(np.concatenate(([0], change, [len(signal)])))
    values = signal[np.concatenate(([0], change))]
    np.testing.assert_array_equal(values, [0, 0.5, -0.5, 0.5, -0.5, 0])
    np.testing.assert_array_equal(runs[1:5], [120, 80, 40, 40])
    assert time[change[0]] == pytest.approx(1.0)
    assert time[change[-1]] == pytest.approx(1.0 + 7 * 0.4)


def test_doublet_and_step():
    time = time_grid(duration=3.0, sample_time=0.1)
    d = doublet(time, amplitude=2.0, step_time=0.5, start=1.0)
    assert d[(time > 1.0) & (time < 1.5)].tolist() == [2.0] * 4
    assert d[(time > 1.5) & (time < 2.0)].tolist() == [-2.0] * 4
    assert np.all(d[time >= 2.0] == 0) and np.all(d[time < 1.0] == 0)
    s = step(time, amplitude=-1.0, start=0.5)
    assert np.all(s[time >= 0.5] == -1.0) and np.all(s[time < 0.5] == 0)


def test_sweep_frequency_rises_from_f_min_to_f_max():
    h = 0.001
    time = time_grid(duration=20.0, sample_time=h)
    signal = frequency_sweep(time, amplitude=1.0, start=0.0, duration=20.0, f_min=0.2, f_max=2.0)
    crossings = time[np.flatnonzero(np.diff(np.signbit(signal).astype(int)) != 0)]
    frequency = 0.5 / np.diff(crossings)  # half a period between zero crossings
    midpoint = 0.5 * (crossings[1:] + crossings[:-1])
    expected = 0.2 * 10.0 ** (midpoint / 20.0)  # f_min (f_max/f_min)^(t/T)
    # A half period averages an exponentially rising frequency: at most ~1.5 % off its midpoint
    # value here; the 1 ms grid adds < 0.5 %.
    np.testing.assert_allclose(frequency, expected, rtol=0.03)
    assert expected[0] < 0.3 and expected[-1] > 1.8  # the sweep covers the range
    assert np.abs(signal).max() <= 1.0


def test_manoeuvre_by_name_and_unknown_name():
    time = time_grid(duration=5.0, sample_time=0.05)
    np.testing.assert_array_equal(manoeuvre("3211", time, amplitude=1.0, step_time=0.3, start=1.0),
                                  three_two_one_one(time, amplitude=1.0, step_time=0.3, start=1.0))
    with pytest.raises(BadInputError, match="unknown manoeuvre 'loop'"):
        manoeuvre("loop", time, amplitude=1.0, step_time=0.3, start=1.0)


@pytest.mark.parametrize("kwargs, message", [
    ({"duration": 0.0, "sample_time": 0.01}, "duration must be a positive"),
    ({"duration": 1.0, "sample_time": 0.0}, "sample time must be positive"),
    ({"duration": float("nan"), "sample_time": 0.01}, "duration"),
    ({"duration": 1.0, "sample_time": 2.0}, "at most the duration"),
])
def test_bad_grid_is_bad_input(kwargs, message):
    with pytest.raises(BadInputError, match=message):
        time_grid(**kwargs)


def test_bad_step_time_is_bad_input():
    with pytest.raises(BadInputError, match="step time must be a positive"):
        three_two_one_one(time_grid(duration=1.0, sample_time=0.1), amplitude=1.0, step_time=-0.1, start=0.0)
