"""Grey-box dynamics: a physics step plus a GP on its one-step residual (Ko et al., ICRA 2007).

Ko, Klein, Fox & Haehnel, "Gaussian processes and reinforcement learning for identification and
control of an autonomous blimp", ICRA 2007, sec. IV-B: with ``f`` the physics model integrated
over one sample interval, the GP learns

    s(k+1) - s(k) - f(s(k), u(k))          (their eq. 14, "RKGP" / "ODEGP")

from inputs that leave out what the residual cannot depend on (absolute position and yaw, by
translation and yaw invariance), with one set of hyperparameters shared by all residual outputs.
A GP-only model (their "GP" baseline, a GP on ``s(k+1) - s(k)``) is the same class with no
physics (``physics_step=None``).

Conventions
-----------
- ``physics_step(states, inputs) -> next_states`` maps arrays of shape (n, n_states) and
  (n, n_inputs) to the physics prediction of the next state, shape (n, n_states); here ``f`` of
  the paper is ``physics_step(s, u) - s``. The callable is given to every method that needs it
  and never stored, so a fitted model holds arrays only. Extra per-row quantities the physics
  needs (e.g. an uneven sample interval) travel as extra input columns; the GP sees them too.
- GP inputs: ``states[:, state_columns]`` followed by every input column.
- Angles are not wrapped: a residual is a plain difference of state columns.
"""
from __future__ import annotations

import numpy as np

from ._gp import GaussianProcess, PerOutputGP
from ._inference import maximize_marginal_likelihood
from ._kernels import SquaredExponentialARD

_SAMPLING_JITTER = 1e-10  # relative jitter on conditional covariances (standardised units)


def _identity_step(states, inputs):
    return states


class GreyBoxGP:
    """A physics step plus a GP on its one-step residual.

    Parameters
    ----------
    state_columns : sequence of int, optional
        State columns the GP sees (default all). Ko et al. leave out position and yaw.
    shared : bool, default True
        One GP with hyperparameters shared across the residual outputs (Ko et al.); False fits
        one GP per output (:class:`~gp_model.PerOutputGP`).
    noise_variance : float, default 1e-2
        Starting noise variance of the standardised residuals.
    n_restarts : int, default 1
        Extra starts of the type-II maximum-likelihood search (0: only the default start);
        see :func:`~gp_model.maximize_marginal_likelihood`.

    Attributes
    ----------
    gp_ : GaussianProcess or PerOutputGP
        The residual GP (after :meth:`fit`).
    n_states_, n_inputs_ : int
    state_columns_ : ndarray of int
    """

    def __init__(self, *, state_columns=None, shared: bool = True, noise_variance: float = 1e-2,
                 n_restarts: int = 1) -> None:
        if n_restarts < 0:
            raise ValueError(f"n_restarts must be >= 0, got {n_restarts}")
        self.state_columns = None if state_columns is None else tuple(int(c) for c in state_columns)
        self.shared = bool(shared)
        self.noise_variance = float(noise_variance)
        self.n_restarts = int(n_restarts)

    # -- data --------------------------------------------------------------------------------
    def _check(self, states, inputs, *, fitted: bool = True) -> tuple[np.ndarray, np.ndarray]:
        states = np.asarray(states, dtype=float)
        inputs = np.asarray(inputs, dtype=float)
        if states.ndim != 2 or inputs.ndim != 2 or len(states) != len(inputs):
            raise ValueError(f"states and inputs must have shapes (n, n_states) and (n, n_inputs) "
                             f"with the same n; got {states.shape} and {inputs.shape}")
        if fitted and (states.shape[1] != self.n_states_ or inputs.shape[1] != self.n_inputs_):
            raise ValueError(f"this model was fitted with {self.n_states_} states and "
                             f"{self.n_inputs_} inputs; got {states.shape[1]} and {inputs.shape[1]}")
        if not (np.isfinite(states).all() and np.isfinite(inputs).all()):
            raise ValueError("states or inputs contain NaN or inf")
        return states, inputs

    def gp_inputs(self, states, inputs) -> np.ndarray:
        """GP regressors ``[states[:, state_columns], inputs]``, shape (n, d)."""
        states, inputs = self._check(states, inputs)
        return np.hstack([states[:, self.state_columns_], inputs])

    @staticmethod
    def _physics(physics_step, states, inputs) -> np.ndarray:
        step = _identity_step if physics_step is None else physics_step
        predicted = np.asarray(step(states, inputs), dtype=float)
        if predicted.shape != states.shape:
            raise ValueError(f"physics_step returned shape {predicted.shape}, expected {states.shape}")
        return predicted

    def residuals(self, states, inputs, next_states, physics_step) -> np.ndarray:
        """``next_states - physics_step(states, inputs)``, shape (n, n_states)."""
        states, inputs = self._check(states, inputs, fitted=False)
        next_states = np.asarray(next_states, dtype=float)
        if next_states.shape != states.shape:
            raise ValueError(f"next_states must have shape {states.shape}, got {next_states.shape}")
        return next_states - self._physics(physics_step, states, inputs)

    # -- fitting -----------------------------------------------------------------------------
    def fit(self, states, inputs, next_states, physics_step, *, optimize: bool = True,
            seed: int = 0) -> GreyBoxGP:
        """Fit the residual GP to one-step transitions.

        Parameters
        ----------
        states, next_states : ndarray, shape (n, n_states)
            ``s(k)`` and ``s(k+1)``.
        inputs : ndarray, shape (n, n_inputs)
            ``u(k)``, held over the interval.
        physics_step : callable or None
            ``physics_step(states, inputs) -> next_states``; None for a GP-only model.
        optimize : bool, default True
            Choose hyperparameters by type-II maximum likelihood (Ko et al.); False keeps the
            configured ones.
        seed : int, default 0
            Seed of the restarts (output ``j`` of a per-output model uses ``seed + j``).
        """
        states, inputs = self._check(states, inputs, fitted=False)
        self.n_states_, self.n_inputs_ = states.shape[1], inputs.shape[1]
        columns = range(self.n_states_) if self.state_columns is None else self.state_columns
        self.state_columns_ = np.asarray(list(columns), dtype=int)
        if self.state_columns_.size and (self.state_columns_.min() < 0
                                         or self.state_columns_.max() >= self.n_states_):
            raise ValueError(f"state_columns {self.state_columns} outside 0..{self.n_states_ - 1}")
        residual = self.residuals(states, inputs, next_states, physics_step)
        X = self.gp_inputs(states, inputs)

        def make_gp() -> GaussianProcess:
            return GaussianProcess(SquaredExponentialARD(1.0, np.ones(X.shape[1])),
                                   noise_variance=self.noise_variance)

        if self.shared:
            self.gp_ = make_gp().fit(X, residual)
            if optimize:
                maximize_marginal_likelihood(self.gp_, n_restarts=self.n_restarts, seed=seed)
        else:
            self.gp_ = PerOutputGP.fit(make_gp, X, residual)
            if optimize:
                for j, gp in enumerate(self.gp_.gps):
                    maximize_marginal_likelihood(gp, n_restarts=self.n_restarts, seed=seed + j)
        return self

    def fit_trajectories(self, trajectories, physics_step, **options) -> GreyBoxGP:
        """:meth:`fit` on every consecutive pair of samples of several trajectories.

        Parameters
        ----------
        trajectories : sequence of (states, inputs)
            Shapes (n_i, n_states), (n_i, n_inputs); ``inputs[k]`` acts from sample k to k+1,
            the last row is unused. Pairs never straddle two trajectories.
        physics_step : callable or None
        **options
            Passed to :meth:`fit`.
        """
        pairs = [(np.asarray(s, float)[:-1], np.asarray(u, float)[:-1], np.asarray(s, float)[1:])
                 for s, u in trajectories]
        if not pairs:
            raise ValueError("no trajectories")
        states, inputs, next_states = (np.vstack(parts) for parts in zip(*pairs))
        return self.fit(states, inputs, next_states, physics_step, **options)

    # -- prediction --------------------------------------------------------------------------
    def _gp_predict(self, X, *, include_noise: bool):
        return self.gp_.predict(X, return_var=True, include_noise=include_noise)

    def predict_one_step(self, states, inputs, physics_step, *, include_noise: bool = False):
        """Next state from ``s(k)``, ``u(k)``: physics plus GP residual.

        Returns
        -------
        mean, var : ndarray, shape (n, n_states)
            ``physics_step(s, u) + E[residual]`` and the residual's predictive variance
            (latent, or of a noisy observation with ``include_noise``).
        """
        states, inputs = self._check(states, inputs)
        mean, var = self._gp_predict(self.gp_inputs(states, inputs), include_noise=include_noise)
        return self._physics(physics_step, states, inputs) + mean, var

    def rollout(self, initial_state, inputs, physics_step) -> np.ndarray:
        """Mean rollout: feed back ``physics_step(s, u) + E[residual]`` step after step.

        Parameters
        ----------
        initial_state : ndarray, shape (n_states,) or (r, n_states)
            One start state, or r of them rolled out together (vectorised).
        inputs : ndarray, shape (steps, n_inputs) or (r, steps, n_inputs)
            ``inputs[..., k, :]`` acts from step k to k+1.
        physics_step : callable or None

        Returns
        -------
        ndarray, shape (steps + 1, n_states) or (r, steps + 1, n_states)
            Row 0 is the start state.
        """
        state, inputs, single = self._check_rollout(initial_state, inputs)
        path = [state]
        for k in range(inputs.shape[1]):
            mean, _ = self.predict_one_step(state, inputs[:, k], physics_step)
            state = mean
            path.append(state)
        path = np.stack(path, axis=1)
        return path[0] if single else path

    def sample_rollouts(self, initial_state, inputs, physics_step, *, n_samples: int,
                        seed: int = 0, include_noise: bool = False) -> np.ndarray:
        """Rollouts that draw the GP residual instead of taking its mean (Ko et al., sec. IV-C).

        Each draw is conditioned on the residuals already drawn along the same rollout, so a
        rollout is one sample of a single function from the GP posterior (revisiting an input
        gives the same residual), not independent noise at every step.

        Parameters
        ----------
        initial_state : ndarray, shape (n_states,)
        inputs : ndarray, shape (steps, n_inputs)
        physics_step : callable or None
        n_samples : int
        seed : int, default 0
        include_noise : bool, default False
            Add independent observation noise (variance ``sigma_n^2``) to every drawn residual;
            it is not part of the function and is not conditioned on.

        Returns
        -------
        ndarray, shape (n_samples, steps + 1, n_states)
        """
        if n_samples < 1:
            raise ValueError(f"n_samples must be >= 1, got {n_samples}")
        state0, inputs, single = self._check_rollout(initial_state, inputs)
        if not single:
            raise ValueError("sample_rollouts takes one start state, shape (n_states,)")
        rng = np.random.default_rng(seed)
        runs = np.empty((n_samples, inputs.shape[1] + 1, self.n_states_))
        for r in range(n_samples):
            state = state0[0]
            runs[r, 0] = state
            visited, drawn = [], []  # GP inputs and drawn residuals along this rollout
            for k in range(inputs.shape[1]):
                u = inputs[0, k]
                x = self.gp_inputs(state[None], u[None])[0]
                visited.append(x)
                if self.shared:
                    residual = _conditional_draw(self.gp_, np.array(visited), drawn, rng)
                else:
                    residual = np.concatenate([
                        _conditional_draw(gp, np.array(visited), [d[j:j + 1] for d in drawn], rng)
                        for j, gp in enumerate(self.gp_.gps)])
                drawn.append(residual)
                if include_noise:
                    residual = residual + rng.standard_normal(self.n_states_) * np.sqrt(
                        self._noise_variances())
                state = self._physics(physics_step, state[None], u[None])[0] + residual
                runs[r, k + 1] = state
        return runs

    def _noise_variances(self) -> np.ndarray:
        """Observation-noise variance of each residual output in its own units, shape (n_states,)."""
        if self.shared:
            return self.gp_.noise_variance * self.gp_.output_scaler_.scale_**2
        return np.array([gp.noise_variance * gp.output_scaler_.scale_[0] ** 2 for gp in self.gp_.gps])

    def _check_rollout(self, initial_state, inputs):
        initial_state = np.asarray(initial_state, dtype=float)
        inputs = np.asarray(inputs, dtype=float)
        single = initial_state.ndim == 1
        state = np.atleast_2d(initial_state)
        if single and inputs.ndim == 2:
            inputs = inputs[None]
        if (state.ndim != 2 or state.shape[1] != self.n_states_ or inputs.ndim != 3
                or len(inputs) != len(state) or inputs.shape[2] != self.n_inputs_):
            raise ValueError(
                f"initial_state must have shape ({self.n_states_},) with inputs (steps, {self.n_inputs_}), "
                f"or (r, {self.n_states_}) with inputs (r, steps, {self.n_inputs_}); "
                f"got {initial_state.shape} and {inputs.shape}")
        if not (np.isfinite(state).all() and np.isfinite(inputs).all()):
            raise ValueError("initial_state or inputs contain NaN or inf")
        return state, inputs, single


def _conditional_draw(gp: GaussianProcess, visited: np.ndarray, drawn: list, rng) -> np.ndarray:
    """Draw the latent GP output at ``visited[-1]`` given the values ``drawn`` at ``visited[:-1]``.

    Gaussian conditioning on the joint posterior over the visited inputs (Rasmussen & Williams
    2006, eq. A.6): ``mu_* + C_*o C_oo^-1 (f_o - mu_o)``, ``C_** - C_*o C_oo^-1 C_o*``.
    ``visited`` (t, d), ``drawn`` t-1 latent draws of shape (m,) -> (m,).
    """
    mean, cov = gp.predict(visited, return_cov=True, use_samples=False)
    mean = mean.reshape(len(visited), -1)  # (t, m)
    cov = cov.reshape(len(visited), len(visited), -1)  # (t, t, m)
    draw = np.empty(mean.shape[1])
    for j in range(mean.shape[1]):
        c = cov[:, :, j]
        mu, var = mean[-1, j], c[-1, -1]
        if drawn:
            old = c[:-1, :-1] + _SAMPLING_JITTER * max(np.trace(c), 1e-300) * np.eye(len(c) - 1)
            cross = c[-1, :-1]
            weights = np.linalg.solve(old, cross)
            mu = mu + weights @ (np.array(drawn)[:, j] - mean[:-1, j])
            var = var - weights @ cross
        draw[j] = mu + np.sqrt(max(var, 0.0)) * rng.standard_normal()
    return draw


# -- portable state (used by gp_model._model_file) -----------------------------------------------
def greybox_to_parts(model: GreyBoxGP) -> tuple[dict, list]:
    """JSON-safe structure and the residual GPs of a fitted :class:`GreyBoxGP`.

    Returns
    -------
    structure : dict
        ``state_columns`` (the fitted ``state_columns_``), ``shared``, ``n_states``,
        ``n_inputs``, ``noise_variance``, ``n_restarts``.
    gps : list of GaussianProcess
        ``[gp_]`` when shared, else the per-output GPs in output order.
    """
    if not hasattr(model, "gp_"):
        raise ValueError("the GreyBoxGP is not fitted; call fit() before saving it")
    structure = {"state_columns": [int(c) for c in model.state_columns_], "shared": model.shared,
                 "n_states": int(model.n_states_), "n_inputs": int(model.n_inputs_),
                 "noise_variance": model.noise_variance, "n_restarts": model.n_restarts}
    return structure, [model.gp_] if model.shared else list(model.gp_.gps)


def greybox_from_parts(structure: dict, gps: list) -> GreyBoxGP:
    """Inverse of :func:`greybox_to_parts`; raises KeyError/ValueError on inconsistent content."""
    model = GreyBoxGP(state_columns=structure["state_columns"], shared=bool(structure["shared"]),
                      noise_variance=float(structure["noise_variance"]),
                      n_restarts=int(structure["n_restarts"]))
    model.n_states_, model.n_inputs_ = int(structure["n_states"]), int(structure["n_inputs"])
    model.state_columns_ = np.asarray(structure["state_columns"], dtype=int)
    d = len(model.state_columns_) + model.n_inputs_
    if model.state_columns_.size and (model.state_columns_.min() < 0
                                      or model.state_columns_.max() >= model.n_states_):
        raise ValueError(f"state_columns {structure['state_columns']} outside 0..{model.n_states_ - 1}")
    expected = 1 if model.shared else model.n_states_
    if len(gps) != expected:
        raise ValueError(f"a {'shared' if model.shared else 'per-output'} grey-box model with "
                         f"{model.n_states_} states has {expected} GP part(s), not {len(gps)}")
    for gp in gps:
        outputs = gp.Y_train_.shape[1]
        if gp.X_train_.shape[1] != d or outputs != (model.n_states_ if model.shared else 1):
            raise ValueError(f"a residual GP has {gp.X_train_.shape[1]} inputs and {outputs} outputs; "
                             f"expected {d} inputs and {model.n_states_ if model.shared else 1}")
    model.gp_ = gps[0] if model.shared else PerOutputGP(gps)
    return model
