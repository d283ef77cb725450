"""What the compiled free runs of the vehicles share (:mod:`validation.vehicles.rgblimp_jax`,
:mod:`validation.vehicles.blimp_jax`): JAX in double precision, imported on first use, and the
padding of batches and run lengths to a few sizes, so that runs of similar sizes share one
compiled function (a compile takes seconds, a run milliseconds).
"""
from __future__ import annotations

import numpy as np

#: Batches of runs are padded to a power of two (at least this), and their steps to the smallest
#: power of two (at least the second) or multiple of the third that holds them, so that replays of
#: similar sizes share one compiled function and short ones waste little.
_MIN_RUNS, _MIN_STEPS, _SAMPLE_BATCH = 8, 32, 600


def jax_modules():
    """``jax`` and ``jax.numpy`` in double precision (imported on first use: only the compiled
    runs need them)."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    return jax, jnp


def padded_rows(runs: int) -> np.ndarray:
    """Row indices that pad a batch of ``runs`` runs to the next power of two (at least 8) with
    copies of the first, so that batches of similar sizes share one compiled function; cut the
    result back to ``runs`` rows."""
    padded = max(_MIN_RUNS, 1 << (runs - 1).bit_length())
    return np.concatenate([np.arange(runs), np.zeros(padded - runs, dtype=int)])


def padded_steps(steps: int) -> int:
    """The step count a compiled run of ``steps`` steps is padded to: the smaller of the next
    power of two (at least 32) and the next multiple of 600, so that runs of similar lengths share
    one compiled function and short ones waste little."""
    return min(max(_MIN_STEPS, 1 << (steps - 1).bit_length()), steps + (-steps % _SAMPLE_BATCH))
