"""Priors on unconstrained hyperparameter vectors."""
from __future__ import annotations

import numpy as np
from scipy.special import betaln


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

    def __add__(self, other: IndependentPrior) -> IndependentPrior:
        """Concatenation: the prior of ``[theta_self, theta_other]``."""
        return IndependentPrior(self.marginals + other.marginals, self.names + other.names)


class LogitBeta:
    """The distribution of ``z = logit(alpha)`` when ``alpha ~ Beta(a, b)``.

    Density ``p(z) = alpha^a (1 - alpha)^b / B(a, b)`` with ``alpha = expit(z)`` (change of
    variables, ``d alpha / dz = alpha (1 - alpha)``). Offers the two methods
    :class:`IndependentPrior` uses of a frozen ``scipy.stats`` distribution.
    """

    def __init__(self, a: float, b: float) -> None:
        if not (a > 0 and b > 0):
            raise ValueError(f"Beta parameters must be positive, got a={a}, b={b}")
        self.a, self.b = float(a), float(b)
        self._log_norm = float(betaln(a, b))

    def logpdf(self, z):
        z = np.asarray(z, dtype=float)
        # ln alpha = -ln(1 + e^-z), ln(1 - alpha) = -ln(1 + e^z), stable for large |z|.
        return -self.a * np.logaddexp(0.0, -z) - self.b * np.logaddexp(0.0, z) - self._log_norm

    def rvs(self, size, random_state):
        alpha = np.clip(random_state.beta(self.a, self.b, size=size), 1e-12, 1 - 1e-12)
        return np.log(alpha) - np.log1p(-alpha)
