"""A damped cart: the small grey-box system the GP-model tests share (position and velocity
states, a force input, an exact forward-Euler physics step and a term the physics leaves out)."""
import numpy as np

DT = 0.1


def physics(states, inputs):
    """A damped cart: position, velocity; force input. Exact forward-Euler step."""
    x, v = states[:, 0], states[:, 1]
    u = inputs[:, 0]
    return np.column_stack([x + DT * v, v + DT * (u - 0.5 * v)])


def unmodelled(states, inputs):
    """What the 'real' system adds to the velocity step and the physics leaves out."""
    return 0.05 * np.sin(2.0 * states[:, 1]) + 0.02 * inputs[:, 0] ** 2


def trajectory(steps, seed, *, extra=False):
    rng = np.random.default_rng(seed)
    inputs = rng.uniform(-1.0, 1.0, (steps, 1))
    states = np.zeros((steps, 2))
    for k in range(steps - 1):
        states[k + 1] = physics(states[k:k + 1], inputs[k:k + 1])[0]
        if extra:
            states[k + 1, 1] += unmodelled(states[k:k + 1], inputs[k:k + 1])[0]
    return states, inputs


#: What rebuilds :func:`physics` from a model file (a test-only physics kind).
CART_PHYSICS = {"kind": "damped_cart_euler", "dt": DT}
