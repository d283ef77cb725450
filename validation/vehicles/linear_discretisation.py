"""Exact zero-order-hold discretisation of a linear model, numpy and the standard library only:
the Bo105 reference (:mod:`validation.vehicles.bo105`), the effects added to it and the Bo105
reference FMU, which carries a copy of this file (docs/fmus.md), discretise with this code.

The matrix exponential is Higham's scaling and squaring with the [13/13] Pade approximant, the
algorithm ``scipy.linalg.expm`` implements, written here with numpy alone so that an FMU needs
no scipy.
"""
from __future__ import annotations

import numpy as np


def zero_order_hold(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH discretisation of ``x_dot = A x + B u`` at step ``h``:
    ``x(t + h) = Phi x(t) + Gamma u(t)`` with ``u`` held over the step, from
    ``expm([[A, B], [0, 0]] h) = [[Phi, Gamma], [0, I]]`` (Van Loan, IEEE TAC 23(3), 1978).

    Parameters
    ----------
    A : ndarray, shape (n, n)
        1/s.
    B : ndarray, shape (n, m)
        State units per input unit per s.
    h : float
        Step, s.

    Returns
    -------
    Phi : ndarray, shape (n, n)
    Gamma : ndarray, shape (n, m)
    """
    n, m = B.shape
    augmented = np.zeros((n + m, n + m))
    augmented[:n, :n], augmented[:n, n:] = A, B
    transition = expm(augmented * h)
    return transition[:n, :n], transition[:n, n:]


# Higham (2005), "The scaling and squaring method for the matrix exponential revisited",
# SIAM J. Matrix Anal. Appl. 26(4), 1179-1193: Table 2.3 (theta_13) and eq. (2.1)-(2.3), the
# [13/13] Pade approximant (the algorithm scipy.linalg.expm implements; numpy only here).
_THETA_13 = 5.371920351148152
_PADE_13 = (64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0,
            129060195264000.0, 10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0,
            40840800.0, 960960.0, 16380.0, 182.0, 1.0)


def expm(M: np.ndarray) -> np.ndarray:
    """Matrix exponential of ``M`` (n, n) by scaling and squaring with the [13/13] Pade
    approximant (Higham 2005, Algorithm 2.3 with m = 13 throughout):
    ``expm(M) = r_13(M / 2^s)^(2^s)``, ``s`` the least with ``||M / 2^s||_1 <= theta_13``."""
    norm = np.linalg.norm(M, 1)
    s = max(0, int(np.ceil(np.log2(norm / _THETA_13)))) if norm > 0 else 0
    X = M / 2.0**s
    b = _PADE_13
    I = np.eye(len(M))  # noqa: E741
    X2 = X @ X
    X4 = X2 @ X2
    X6 = X4 @ X2
    U = X @ (X6 @ (b[13] * X6 + b[11] * X4 + b[9] * X2) + b[7] * X6 + b[5] * X4 + b[3] * X2 + b[1] * I)
    V = X6 @ (b[12] * X6 + b[10] * X4 + b[8] * X2) + b[6] * X6 + b[4] * X4 + b[2] * X2 + b[0] * I
    R = np.linalg.solve(V - U, V + U)
    for _ in range(s):
        R = R @ R
    return R
