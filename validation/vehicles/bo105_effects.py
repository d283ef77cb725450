"""Named effects on the linear Bo105 reference (:mod:`validation.vehicles.bo105`): its
:class:`~validation.vehicles.effects.EffectModel`, :class:`Bo105Effects` (the linear references'
:class:`~validation.vehicles.linear_effects.LinearEffects` with the Bo105's family, sensor noise
and manoeuvre), and the multi-axis identification manoeuvre that excites them.

A Bo105 takes what every linear reference takes (:mod:`validation.vehicles.linear_effects` says
how each effect enters ``x_dot = A x + B u``): delays, lags and sensor biases, and its
derivatives ``<row>_<column>`` with the row letters ``X, Z, M, Y, L, N`` of
:data:`validation.vehicles.bo105.ROW_LETTERS` (``M_q``, ``L_theta_1c`` ...).
"""
from __future__ import annotations

import math

import numpy as np

from validation.core.manoeuvres import doublet, three_two_one_one, time_grid
from validation.vehicles.bo105 import INPUT_NAMES, Bo105Reference
from validation.vehicles.bo105_flight import SENSOR_NOISE_STD
from validation.vehicles.linear_effects import LinearEffects


def identification_manoeuvre(*, duration: float = 20.0, sample_time: float = 0.01,
                             variant: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A multi-axis Bo105 identification input: a 3-2-1-1 on each cyclic, then doublets on
    pedals and collective, one after the other, so that every control derivative and delay is
    identifiable (Tischler & Remple, *Aircraft and Rotorcraft System Identification*, 2012,
    ch. 5: one axis at a time, multisteps for broad-band excitation).

    Parameters
    ----------
    duration, sample_time : float
        s; manoeuvres that do not fit in ``duration`` are cut off.
    variant : int
        0: 1 deg, 0.4/0.3 s steps (for fitting); 1: 1.5 deg, 0.3/0.5 s steps, signs reversed,
        pedal before lateral cyclic (a different manoeuvre, for held-out data); 2: variant 0 with
        the longitudinal-cyclic 3-2-1-1 flown again at twice the amplitude from 16.5 s, so that
        an amplitude-dependent response (a dead band) is told from a linear one (a lower control
        derivative), which one amplitude cannot.

    Returns
    -------
    time : ndarray, shape (n,)
    inputs : ndarray, shape (n, 4)
        ``theta_0, theta_1s, theta_1c, theta_0T``, rad.
    """
    time = time_grid(duration=duration, sample_time=sample_time)
    inputs = np.zeros((len(time), len(INPUT_NAMES)))
    degree = math.radians(1.0)
    column = {name: INPUT_NAMES.index(name) for name in INPUT_NAMES}
    if variant in (0, 2):
        inputs[:, column["theta_1s"]] = three_two_one_one(time, amplitude=degree, step_time=0.4, start=1.0)
        if variant == 2:
            inputs[:, column["theta_1s"]] += three_two_one_one(time, amplitude=2 * degree, step_time=0.4, start=16.5)
        inputs[:, column["theta_1c"]] = three_two_one_one(time, amplitude=degree, step_time=0.3, start=6.0)
        inputs[:, column["theta_0T"]] = doublet(time, amplitude=degree, step_time=0.5, start=10.0)
        inputs[:, column["theta_0"]] = doublet(time, amplitude=degree, step_time=0.5, start=14.0)
    else:
        amplitude = -1.5 * degree
        inputs[:, column["theta_1s"]] = three_two_one_one(time, amplitude=amplitude, step_time=0.3, start=1.0)
        inputs[:, column["theta_0T"]] = doublet(time, amplitude=amplitude, step_time=0.4, start=5.0)
        inputs[:, column["theta_1c"]] = three_two_one_one(time, amplitude=amplitude / 1.5, step_time=0.5, start=8.0)
        inputs[:, column["theta_0"]] = doublet(time, amplitude=amplitude, step_time=0.6, start=14.0)
    return time, inputs


class Bo105Effects(LinearEffects):
    """The :class:`~validation.vehicles.effects.EffectModel` of a ``bo105-<V>kt`` reference
    (module docstring): :class:`~validation.vehicles.linear_effects.LinearEffects` of the
    Bo105, whose recordings the flight-test stand-in's sensor noise
    (:data:`validation.vehicles.bo105_flight.SENSOR_NOISE_STD`) and the Bo105 manoeuvre of
    :func:`identification_manoeuvre` make.

    Parameters
    ----------
    reference : Bo105Reference
    """

    family = "bo105"

    def __init__(self, reference: Bo105Reference):
        super().__init__(reference)
        self.sensor_noise_sd = dict(SENSOR_NOISE_STD)

    identification_manoeuvre = staticmethod(identification_manoeuvre)
