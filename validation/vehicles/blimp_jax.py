"""The blimp's equations with named effects in ``jax.numpy``, compiled: the replays of
:func:`validation.vehicles.blimp_effects.simulate_batch`, batched over effect lists.

The equations are :func:`validation.vehicles.blimp_equations.blimp_dynamics` plus the term
changes of :mod:`validation.vehicles.blimp_effects` (thrust gains, extra damping and drag,
constant forces, a buoyancy imbalance, search terms), written again for a batch of states (B, 12) with the
changes as arrays, so that JAX can trace and compile one RK4 step per recording interval inside
a ``lax.scan``. The inputs each member sees (dead bands, limits, rate limits, delays and lags)
are shaped beforehand in numpy, exactly as for the numpy step. Everything is in double precision;
a replay here equals the numpy step to rounding (tested to 1e-12 over whole recordings for
every effect kind).

Why compiled: a numpy RK4 step over a batch pays Python's and numpy's overhead per stage, which
dominates diagnose's replays of many hypotheses on the blimp (``flightgp bench blimp``).
"""
from __future__ import annotations

import numpy as np

from validation.vehicles.blimp_equations import STANDARD_GRAVITY, mass_matrix
from validation.vehicles.compiled_runs import jax_modules, padded_rows, padded_steps
from validation.vehicles.polynomial_terms import slot_values

_COMPILED = {}


def _rates(jnp, state, command, p, changes, inverse):
    """State derivatives (B, 12) of the changed blimp ODEs at ``state`` (B, 12) with the held
    ``command`` (B, 3) (the equations of
    :func:`~validation.vehicles.blimp_equations.blimp_dynamics` and
    :meth:`~validation.vehicles.blimp_effects._TermChanges.rates`)."""
    raw_command = command
    command = command * jnp.where(command >= 0, changes["gain_positive"], changes["gain_negative"])
    angles, v, w = state[:, 3:6], state[:, 6:9], state[:, 9:12]
    nu = state[:, 6:12]
    sf, cf = jnp.sin(angles[:, 0]), jnp.cos(angles[:, 0])
    st, ct = jnp.sin(angles[:, 1]), jnp.cos(angles[:, 1])
    sp, cp = jnp.sin(angles[:, 2]), jnp.cos(angles[:, 2])
    tt = jnp.tan(angles[:, 1])
    u_gondola, mu, u_tail = command[:, 0], command[:, 1], command[:, 2]
    gondola = u_gondola * jnp.where(u_gondola >= 0, p["gondola_thrust_forward"], p["gondola_thrust_backward"])
    tail = u_tail * jnp.where(u_tail >= 0, p["tail_thrust_positive"], p["tail_thrust_negative"])
    cos_mu, arm = jnp.cos(mu), p["tail_arm"]
    fin_gain = p["fin_lift"] * jnp.abs(v[:, 0])
    fin_side = -fin_gain * (v[:, 1] - arm * w[:, 2])
    fin_normal = -fin_gain * (v[:, 2] + arm * w[:, 1])
    x_dot = jnp.stack([cp * ct * v[:, 0] + (-sp * cf + cp * st * sf) * v[:, 1] + (sp * sf + cp * cf * st) * v[:, 2],
                       sp * ct * v[:, 0] + (cp * cf + sf * st * sp) * v[:, 1] + (-cp * sf + st * sp * cf) * v[:, 2],
                       -st * v[:, 0] + ct * sf * v[:, 1] + ct * cf * v[:, 2]], axis=-1)
    p_, q, r = w[:, 0], w[:, 1], w[:, 2]
    euler = jnp.stack([p_ + sf * tt * q + cf * tt * r, cf * q - sf * r, (sf * q + cf * r) / ct], axis=-1)
    momentum = nu @ p["matrix"].T
    down = jnp.stack([-st, ct * sf, ct * cf], axis=-1)
    weight_down = p["mass"] * STANDARD_GRAVITY * down
    force = jnp.stack([gondola * cos_mu, -tail + fin_side, -gondola * jnp.sin(mu) + fin_normal], axis=-1)
    moment = jnp.stack([jnp.zeros_like(gondola), p["gondola_arm"] * gondola * cos_mu + arm * fin_normal,
                        arm * tail - arm * fin_side], axis=-1)
    force = force - p["net_lift"] * down - p["linear_drag"] * v - p["quadratic_drag"] * jnp.abs(v) * v
    force = force - jnp.cross(w, momentum[:, :3])
    moment = (moment + jnp.cross(p["cg_position"], weight_down) - p["rotational_damping"] * w
              - jnp.cross(v, momentum[:, :3]) - jnp.cross(w, momentum[:, 3:]))
    extra = changes["constant"] + jnp.concatenate(
        [changes["extra_drag"] * jnp.abs(v) * v + changes["extra_down"][:, None] * down, changes["extra_damping"] * w],
        axis=-1)
    signals = jnp.concatenate([nu, angles[:, :2], raw_command], axis=-1)  # SEARCH_SIGNALS
    extra = extra + slot_values(jnp, signals, changes)
    nu_dot = (jnp.concatenate([force, moment], axis=-1) + extra) @ inverse.T
    return jnp.concatenate([x_dot, euler, nu_dot], axis=-1)


def _replay_function(jax, jnp):
    """The compiled replay: ``(p, changes, inverse, start (B, 12), held (P, B, 3), steps (P,))``
    -> states (P, B, 12) after each step."""

    def replay(p, changes, inverse, start, held, steps):
        def step(state, sample):
            command, dt = sample

            def derivative(x):
                return _rates(jnp, x, command, p, changes, inverse)

            k1 = derivative(state)
            k2 = derivative(state + 0.5 * dt * k1)
            k3 = derivative(state + 0.5 * dt * k2)
            k4 = derivative(state + dt * k3)
            state = state + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            return state, state

        return jax.lax.scan(step, start, (held, steps))[1]

    return jax.jit(replay)


def compiled_replay(params, changes: dict, start: np.ndarray, held: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Replays of B members, compiled (module docstring).

    Parameters
    ----------
    params : BlimpParameters
    changes : dict of str to ndarray
        The term changes per member: ``gain_positive``, ``gain_negative``, ``extra_damping``,
        ``extra_drag`` (B, 3), ``constant`` (B, 6), ``extra_down`` (B,), and the search terms'
        slots (B, SEARCH_SLOTS): ``search_kind``, ``search_first``, ``search_second``,
        ``search_row`` (integers) and ``search_value``.
    start : ndarray, shape (12,)
    held : ndarray, shape (B, n - 1, 3)
        What acts over each interval for each member.
    steps : ndarray, shape (n - 1,)
        The interval lengths, s.

    Returns
    -------
    ndarray, shape (B, n, 12)
        Row 0 the start; a run that diverges holds inf or NaN.
    """
    if "replay" not in _COMPILED:
        jax, jnp = jax_modules()
        _COMPILED["replay"] = (jnp, _replay_function(jax, jnp))
    jnp, replay = _COMPILED["replay"]
    members, n_steps = held.shape[:2]
    rows = padded_rows(members)
    matrix, inverse = mass_matrix(params.mass, params.added_mass, params.inertia, params.added_inertia,
                                  params.cg_position)
    # Steps padded with the last input held over the last interval's length (a replay is causal;
    # the padding is cut), so that recordings of similar lengths share one compiled function.
    length = padded_steps(n_steps)
    held = np.concatenate([held, np.repeat(held[:, -1:], length - n_steps, axis=1)], axis=1)[rows]
    steps = np.concatenate([steps, np.full(length - n_steps, steps[-1])])
    p = {name: jnp.asarray(np.asarray(getattr(params, name), dtype=float)) for name in (
        "gondola_thrust_forward", "gondola_thrust_backward", "tail_thrust_positive", "tail_thrust_negative",
        "tail_arm", "fin_lift", "gondola_arm", "mass", "net_lift", "linear_drag", "quadratic_drag",
        "rotational_damping", "cg_position")}
    p["matrix"] = jnp.asarray(matrix)
    path = replay(p, {name: jnp.asarray(value[rows]) for name, value in changes.items()}, jnp.asarray(inverse),
                  jnp.asarray(np.repeat(start[None], len(rows), axis=0)),
                  jnp.asarray(np.swapaxes(held, 0, 1)), jnp.asarray(steps))
    path = np.swapaxes(np.asarray(path)[:n_steps, :members], 0, 1)
    return np.concatenate([np.repeat(start[None, None], members, axis=0), path], axis=1)
