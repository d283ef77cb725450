"""Priors on unconstrained hyperparameter vectors."""
from __future__ import annotations

import numpy as np


class IndependentPrior:
    """A product of one-dimensional distributions, one per hyperparameter.

    Parameters
    ----------
    marginals : list of frozen ``scipy.stats`` continuous distributions
        ``marginals[j]`` is the prior of ``theta[j]``.
    names : list of str
        Hyperparameter names, for messages.
    """

    def __init__(self, marginals, names) -> None:
        if len(marginals) != len(names):
            raise ValueError("one name per marginal")
        self.marginals = list(marginals)
        self.names = list(names)

    def __len__(self) -> int:
        return len(self.marginals)

    def log_pdf(self, theta) -> np.ndarray:
        """Log density at ``theta``, shape (..., p) -> (...)."""
        theta = np.asarray(theta, dtype=float)
        return sum(m.logpdf(theta[..., j]) for j, m in enumerate(self.marginals))

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` independent draws, shape (n, p)."""
        return np.column_stack([m.rvs(size=n, random_state=rng) for m in self.marginals])

    def __add__(self, other: "IndependentPrior") -> "IndependentPrior":
        """Concatenation: the prior of ``[theta_self, theta_other]``."""
        return IndependentPrior(self.marginals + other.marginals, self.names + other.names)
