"""The RGBlimp's equations in ``jax.numpy``, compiled: free runs batched over parameter sets and
recordings, and the functions the rollout-trained hybrid differentiates
(:mod:`validation.models.rgblimp_rollout`).

The equations are those of :mod:`validation.vehicles.rgblimp_equations`, written again for one
state (12,) and inputs (5,) with the parameters as a dict of arrays (:func:`parameter_arrays`),
so that JAX can trace, batch (``vmap``), differentiate and compile them. Everything is in double
precision; a free run here equals :func:`~validation.vehicles.rgblimp_equations.free_run` to
rounding (tested to 1e-12 over whole flights, batched as diagnose replays them, and to 6e-14 over
the 3801 samples of ``data_1.csv``).

Why compiled: a numpy RK4 step over a batch pays Python's and numpy's overhead per stage (about
0.6 ms for 100 parameter sets), so a replay of many hypotheses over many flights is dominated by
it; a compiled ``lax.scan`` over the samples is not (``flightgp bench rgblimp``).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from validation.vehicles.compiled_runs import jax_modules, padded_rows, padded_steps
from validation.vehicles.rgblimp_equations import (
    SAMPLE_TIME,
    ZERO_SPEED_GUARD,
    RGBlimpParameters,
    search_accelerations,
)

_COMPILED = {}


def parameter_arrays(params: RGBlimpParameters, *, thrust_gain: float = 1.0, wind=(0.0, 0.0)) -> dict:
    """``params`` as a dict of float64 arrays (every field of :class:`RGBlimpParameters`), plus
    ``thrust_gain`` and ``wind`` (2,)."""
    values = {f.name: np.asarray(getattr(params, f.name), dtype=float) for f in dataclasses.fields(RGBlimpParameters)}
    values["thrust_gain"] = np.asarray(thrust_gain, dtype=float)
    values["wind"] = np.asarray(wind, dtype=float)
    return values


def _skew(jnp, a):
    return jnp.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def inverse_mass_matrix(jnp, inputs, p):
    """The inverse of the 6x6 mass matrix and the first mass moment ``l`` and inertia ``J``
    (:func:`validation.vehicles.rgblimp_equations.mass_properties`)."""
    gondola = inputs[2:5]
    mass_moment = p["hull_mass"] * p["hull_cg"] + p["gondola_mass"] * gondola
    gondola_skew = _skew(jnp, gondola)
    inertia = jnp.diag(p["inertia"]) - p["gondola_mass"] * gondola_skew @ gondola_skew
    eye = jnp.eye(3)
    translational = (p["hull_mass"] + p["gondola_mass"]) * eye + jnp.diag(p["added_mass"])
    moment_skew = _skew(jnp, mass_moment)
    matrix = jnp.block([[translational, -moment_skew], [moment_skew, inertia + jnp.diag(p["added_inertia"])]])
    return jnp.linalg.inv(matrix), mass_moment, inertia


def accelerations(jnp, state, inputs, p, masses, body_to_earth):
    """Body accelerations of the equations
    (:func:`validation.vehicles.rgblimp_equations.body_accelerations`); ``body_to_earth`` the
    state's rotation (3, 3) (:func:`kinematics` has it)."""
    inverse, mass_moment, inertia = masses
    phi, theta = state[3], state[4]
    velocity, rates = state[6:9], state[9:12]
    gondola_z = inputs[4]
    down = jnp.array([-jnp.sin(theta), jnp.cos(theta) * jnp.sin(phi), jnp.cos(theta) * jnp.cos(phi)])
    draught = state[0] * p["draught_gradient_x"] + state[1] * p["draught_gradient_y"]
    air_velocity = velocity - body_to_earth.T @ draught
    speed_squared = jnp.sum(air_velocity**2)
    speed = jnp.sqrt(speed_squared)
    alpha = jnp.arctan2(air_velocity[2], air_velocity[0] + ZERO_SPEED_GUARD)
    beta = jnp.arcsin(air_velocity[1] / (speed + ZERO_SPEED_GUARD))
    alpha_cross, beta_cross = alpha * jnp.abs(alpha), beta * jnp.abs(beta)
    qbar_area = 0.5 * p["air_density"] * speed_squared * p["reference_area"]
    drag = qbar_area * (p["c_d0"] + p["c_d_alpha2"] * alpha**2 + p["c_d_beta2"] * beta**2)
    side = qbar_area * (p["c_s0"] + p["c_s_alpha2"] * alpha**2 + p["c_s_beta"] * beta
                        + p["c_s_beta_abs"] * beta_cross)
    lift = qbar_area * (p["c_l0"] + p["c_l_alpha"] * alpha + p["c_l_beta2"] * beta**2
                        + p["c_l_alpha_abs"] * alpha_cross)
    aero_moment = qbar_area * jnp.array([
        p["c_mx0"] + p["c_mx_alpha"] * alpha + p["c_mx_beta"] * beta,
        p["c_my0"] + p["c_my_alpha"] * alpha + p["c_my_beta4"] * beta**4 + p["c_my_alpha_abs"] * alpha_cross,
        p["c_mz0"] + p["c_mz_alpha"] * alpha + p["c_mz_beta"] * beta + p["c_mz_beta_abs"] * beta_cross])
    aero_moment = aero_moment + p["rate_damping"] * rates
    ca, sa, cb, sb = jnp.cos(alpha), jnp.sin(alpha), jnp.cos(beta), jnp.sin(beta)
    rotation = jnp.array([[ca * cb, -ca * sb, -sa], [sb, cb, 0.0], [sa * cb, -sa * sb, ca]])
    total_mass = p["hull_mass"] + p["gondola_mass"]
    thrust_factor = 1.0 - p["thrust_speed_loss"] * air_velocity[0]
    thrust_left, thrust_right = inputs[0] * thrust_factor, inputs[1] * thrust_factor
    thrust = thrust_left + thrust_right
    velocity_cross_rates = jnp.cross(velocity, rates)
    added_momentum = p["added_mass"] * velocity
    force = (total_mass * velocity_cross_rates + jnp.cross(added_momentum, rates)
             + jnp.cross(jnp.cross(rates, mass_moment), rates)
             + (total_mass - p["buoyancy_mass"]) * p["gravity"] * down
             + rotation @ jnp.array([-drag, side, -lift]) + jnp.array([thrust, 0.0, 0.0]))
    moment = (jnp.cross(inertia @ rates, rates) + jnp.cross(added_momentum, velocity)
              + jnp.cross(p["added_inertia"] * rates, rates) + jnp.cross(mass_moment, velocity_cross_rates)
              + jnp.cross(mass_moment, p["gravity"] * down) + rotation @ aero_moment
              + jnp.array([0.0, thrust * gondola_z,
                           (thrust_left - thrust_right) * p["propeller_arm"] - p["thrust_line_y"] * thrust]))
    return inverse @ jnp.concatenate([force, moment])


def kinematics(jnp, state):
    """Earth position rates and Euler angle rates (ZYX; Fossen 2011, sec. 2.2.1)."""
    phi, theta, psi = state[3], state[4], state[5]
    sf, cf, st, ct, sp, cp = jnp.sin(phi), jnp.cos(phi), jnp.sin(theta), jnp.cos(theta), jnp.sin(psi), jnp.cos(psi)
    rotation = jnp.array([[cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st],
                          [sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf],
                          [-st, ct * sf, ct * cf]])
    p, q, r = state[9], state[10], state[11]
    tt = st / ct
    angle_rates = jnp.array([p + sf * tt * q + cf * tt * r, cf * q - sf * r, (sf * q + cf * r) / ct])
    return rotation @ state[6:9], angle_rates, rotation


def rollout_function(jax, jnp, correction_of=None, *, checkpoint_steps: bool = True):
    """``rollout(p, theta, start, inputs, disturbance) -> states (L, 12)``: the free run from
    ``start`` (12,) through ``inputs`` (L, 5), states at samples 1 .. L, in the earth frame (the
    wind handled as in :func:`validation.vehicles.rgblimp_equations.free_run`, yaw carried
    continuously), ``p`` the parameters (:func:`parameter_arrays`; with the search terms' slots,
    :data:`~validation.vehicles.polynomial_terms.SLOT_KEYS`, their accelerations
    :func:`~validation.vehicles.rgblimp_equations.search_accelerations` are added in every
    stage). ``correction_of(theta)``,
    when given and ``theta`` is not None, returns a function ``a(state, commands)`` (6,) added to
    the body accelerations in every stage (a learned correction,
    :mod:`validation.models.rgblimp_rollout`); ``disturbance`` (L, 6), or None, is added over
    each step. ``checkpoint_steps``: a reverse pass through the run recomputes each step from
    its carried state instead of storing every stage's intermediates (gradients 1.6x faster on
    32 segments of 20 s, docs/rgblimp.md, "Exact gradients: why JAX"; False stores them, the
    peer of ``flightgp bench rgblimp``); a free run without gradient is the same either way."""
    h = SAMPLE_TIME

    def rollout(p, theta, start, inputs, disturbance=None):
        wind = jnp.concatenate([p["wind"], jnp.zeros(1)])
        extra_acceleration = None if theta is None or correction_of is None else correction_of(theta)

        def to_air(state, sign):
            _, _, rotation = kinematics(jnp, state)
            return state.at[6:9].add(sign * rotation.T @ wind)

        def derivative(state, commands, masses, extra):
            position_rate, angle_rates, body_to_earth = kinematics(jnp, state)
            body = accelerations(jnp, state, commands, p, masses, body_to_earth)
            if extra_acceleration is not None:
                body = body + extra_acceleration(state, commands)
            if "search_value" in p:  # search terms in slots (diagnose's residual search)
                body = body + search_accelerations(jnp, state, p)
            if extra is not None:
                body = body + extra
            return jnp.concatenate([position_rate, angle_rates, body])

        def step(state, sample):
            commands, extra = sample if disturbance is not None else (sample, None)
            commands = commands.at[:2].multiply(p["thrust_gain"])
            masses = inverse_mass_matrix(jnp, commands, p)
            k1 = derivative(state, commands, masses, extra)
            k2 = derivative(state + 0.5 * h * k1, commands, masses, extra)
            k3 = derivative(state + 0.5 * h * k2, commands, masses, extra)
            k4 = derivative(state + h * k3, commands, masses, extra)
            moved = state + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            return moved, moved

        samples = inputs if disturbance is None else (inputs, disturbance)
        _, path = jax.lax.scan(jax.checkpoint(step) if checkpoint_steps else step, to_air(start, -1.0), samples)
        drift = h * jnp.arange(1, inputs.shape[0] + 1)[:, None] * wind
        path = path.at[:, :3].add(drift)
        return jax.vmap(lambda s: to_air(s, 1.0))(path)

    return rollout


def _float_unless_integer(value) -> np.ndarray:
    """``value`` as an array of float64, or as it is if it holds integers (slot indices)."""
    array = np.asarray(value)
    return array if array.dtype.kind in "iu" else array.astype(float)


def held_inputs(inputs: np.ndarray) -> np.ndarray:
    """The inputs (..., L, 5) of a free run of L - 1 steps, the step count padded (to the smaller
    of the next power of two, at least 32, and the next multiple of 600) by holding the last
    input used: a free run is causal, so the first L - 1 states of the padded run are those of
    the run, and runs of different lengths share a compiled function. Shape (..., P, 5)."""
    steps = max(inputs.shape[-2] - 1, 1)
    used = inputs[..., :steps, :]
    padded = padded_steps(steps)
    return np.concatenate([used, np.repeat(used[..., -1:, :], padded - steps, axis=-2)], axis=-2)


def batched_free_runs(parameters: dict, starts, inputs) -> np.ndarray:
    """Free runs of B parameter sets over S recordings, compiled (module docstring).

    Parameters
    ----------
    parameters : dict
        :func:`parameter_arrays` of each set stacked on a first axis of length B (``wind`` (B,
        2), ``thrust_gain`` (B,), triples (B, 3), the other fields (B,)); optionally search
        terms' slots (B, K) (:func:`rollout_function`; integer arrays stay integers).
    starts : ndarray, shape (B, S, 12)
    inputs : ndarray, shape (B, S, L, 5)
        ``inputs[..., k, :]`` held from sample k to k + 1 (the thrusts times ``thrust_gain``).

    Returns
    -------
    ndarray, shape (B, S, L, 12)
        Row 0 the start, yaw carried continuously; a run that diverges holds inf or NaN.
    """
    if "batched" not in _COMPILED:
        jax, jnp = jax_modules()
        rollout = rollout_function(jax, jnp)
        _COMPILED["batched"] = (jnp, jax.jit(jax.vmap(lambda p, start, u: rollout(p, None, start, u))))
    jnp, batched = _COMPILED["batched"]
    starts, inputs = np.asarray(starts, dtype=float), np.asarray(inputs, dtype=float)
    members, recordings, length = inputs.shape[:3]
    # One run per member and recording, their count padded to a power of two with copies of the
    # first and their samples with the last input held (a free run is causal); the padding is cut.
    runs = members * recordings
    rows = padded_rows(runs)
    member_of_run = rows // recordings
    steps = length - 1
    held = held_inputs(inputs.reshape(runs, length, 5)[rows])
    by_run = {name: jnp.asarray(_float_unless_integer(value)[member_of_run]) for name, value in parameters.items()}
    path = batched(by_run, jnp.asarray(starts.reshape(runs, 12)[rows]), jnp.asarray(held))
    path = np.asarray(path)[:runs, :steps].reshape(members, recordings, steps, 12)
    return np.concatenate([starts[:, :, None, :], path], axis=2)
