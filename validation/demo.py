"""``flightgp demo``: the built-in Bo105 case, end to end as far as flightgp goes today.

It runs the paper part of :func:`validation.reproduce_bo105.reproduce_bo105`: record the Bo105
flight-test stand-in's 80 kt 3-2-1-1 (and an unseen one), train the GP-NARX (Higdon kernel,
simulated annealing), free-run it by Monte Carlo and compare it, and the physics reference, with
the flight test. FMU export and co-simulation join the chain with the FMU issue.
"""
from __future__ import annotations

from .reproduce_bo105 import reproduce_bo105


def run_demo(out_dir, *, seed: int = 0, n_runs: int = 1000, progress: bool = True) -> dict:
    """Run the demo into ``out_dir``; returns the results written to ``results.json``."""
    return reproduce_bo105(out_dir, seed=seed, n_runs=n_runs, beyond=False, progress=progress)
