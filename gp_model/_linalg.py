"""Cholesky factorisation with a bounded, logged jitter escalation."""
from __future__ import annotations

import logging

import numpy as np
from scipy.linalg import lapack

from ._errors import GPNumericalError

logger = logging.getLogger(__name__)

#: Jitter tried in turn, relative to the mean diagonal of the matrix (Rasmussen & Williams 2006,
#: sec. 3.4.3, add a small multiple of the identity when K is numerically singular).
RELATIVE_JITTERS = (0.0, 1e-10, 1e-8, 1e-6, 1e-4)


def robust_cholesky(K: np.ndarray, *, quiet: bool = False) -> tuple[np.ndarray, float]:
    """Lower Cholesky factor of ``K + jitter I``, escalating the jitter until it succeeds.

    Parameters
    ----------
    K : ndarray, shape (n, n)
        Symmetric, in theory positive definite.
    quiet : bool
        Do not log the escalation (used inside optimisers that probe bad hyperparameters).

    Returns
    -------
    L : ndarray, shape (n, n)
        Lower-triangular, ``L L^T = K + jitter I``.
    jitter : float
        The absolute jitter added (0.0 when none was needed).

    Raises
    ------
    GPNumericalError
        If even the largest jitter does not make ``K`` positive definite.
    """
    scale = float(np.mean(np.diag(K))) if K.size else 1.0
    if not np.isfinite(scale):
        raise GPNumericalError("kernel matrix has non-finite entries; check the inputs for NaN/inf")
    for relative in RELATIVE_JITTERS:
        jitter = relative * scale
        K_try = K
        if jitter:
            K_try = K.copy()
            K_try.flat[:: len(K) + 1] += jitter
        # LAPACK dpotrf directly: scipy.linalg.cholesky adds copies and checks that cost as
        # much as the factorisation itself for n of a few hundred.
        L, info = lapack.dpotrf(K_try, lower=1, clean=1)
        if info != 0:
            continue
        if jitter and not quiet:
            logger.warning(
                "kernel matrix (n=%d) was not positive definite; added jitter %.3g "
                "(%.0e of its mean diagonal %.3g)", len(K), jitter, relative, scale,
            )
        return L, jitter
    raise GPNumericalError(
        f"kernel matrix (n={len(K)}) is not positive definite even with jitter "
        f"{RELATIVE_JITTERS[-1]:.0e} x mean diagonal; remove duplicate inputs or increase the "
        "noise variance"
    )
