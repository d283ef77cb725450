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

from dataclasses import dataclass

import numpy as np

from ._gp import GaussianProcess, PerOutputGP
from ._inference import maximize_marginal_likelihood
from ._kernels import SquaredExponentialARD


@dataclass(frozen=True)
class PropagatedRollout:
    """A mean rollout with its propagated state covariance (:meth:`GreyBoxGP.propagate`).

    Attributes
    ----------
    mean : ndarray, shape (steps + 1, n_states) or (r, steps + 1, n_states)
    covariance : ndarray, shape (steps + 1, n_states, n_states) or (r, steps + 1, n_states, n_states)
    """

    mean: np.ndarray
    covariance: np.ndarray

    @property
    def sd(self) -> np.ndarray:
        """Standard deviation of each state, shape like :attr:`mean`."""
        return np.sqrt(np.maximum(np.diagonal(self.covariance, axis1=-2, axis2=-1), 0.0))

#: Conditional variance, relative to the prior's, below which a draw counts as determined by the
#: earlier ones (:class:`_ConditionedSampler`). Conditioning on such a draw would divide by its
#: conditional sd: at 1e-10 (tried first) the inverse factor grew by 1e5 per revisited input and
#: closed-loop rollouts that hover (blimp turns at 4 Hz) blew up after ~100 steps.
_SAMPLING_JITTER = 1e-8
#: Central-difference step of :meth:`GreyBoxGP.propagate`, in state units (rounding ~1e-11
#: relative against truncation ~1e-10 for states of order 1).
PROPAGATION_STEP = 1e-3


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
    min_noise_variance : float, optional
        Floor under each residual GP's noise variance (standardised), passed to
        :func:`~gp_model.maximize_marginal_likelihood`.

    Attributes
    ----------
    gp_ : GaussianProcess or PerOutputGP
        The residual GP (after :meth:`fit`).
    n_states_, n_inputs_ : int
    state_columns_ : ndarray of int
    """

    def __init__(self, *, state_columns=None, shared: bool = True, noise_variance: float = 1e-2,
                 n_restarts: int = 1, min_noise_variance: float | None = None) -> None:
        if n_restarts < 0:
            raise ValueError(f"n_restarts must be >= 0, got {n_restarts}")
        self.state_columns = None if state_columns is None else tuple(int(c) for c in state_columns)
        self.shared = bool(shared)
        self.noise_variance = float(noise_variance)
        self.n_restarts = int(n_restarts)
        self.min_noise_variance = None if min_noise_variance is None else float(min_noise_variance)

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
        else:
            self.gp_ = PerOutputGP.fit(make_gp, X, residual)
        if optimize:
            for j, gp in enumerate(self._gps()):
                maximize_marginal_likelihood(gp, n_restarts=self.n_restarts, seed=seed + j,
                                             min_noise_variance=self.min_noise_variance)
        return self

    def _gps(self) -> list:
        """The residual GPs: ``[gp_]`` when shared, else one per output."""
        return [self.gp_] if self.shared else list(self.gp_.gps)

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

    def propagate(self, initial_state, inputs, physics_step, *, initial_covariance=None,
                  include_noise: bool = True, step: float = PROPAGATION_STEP) -> PropagatedRollout:
        """Mean rollout with the state covariance propagated along it to first order.

        The one-step map ``g(s, u) = physics_step(s, u) + E[residual | s, u]`` is linearised at
        the propagated mean, ``J = dg/ds`` by central differences of step ``step`` in every state
        column, and ``P(k+1) = J P(k) J^T + Sigma(k)`` with ``Sigma(k)`` the residual GPs'
        predictive variance at the mean (diagonal: the outputs are independent given the inputs;
        with ``include_noise`` the observation noise too, which stands for the process noise the
        GP learned). This is the first-order Taylor approximation of the moment-matching free
        run (Girard, Rasmussen, Quinonero-Candela & Murray-Smith, NIPS 2003, sec. 3; Kocijan,
        *Modelling and Control of Dynamic Systems Using Gaussian Process Models*, 2016,
        sec. 2.6.1), the prediction step of an extended Kalman filter: its mean is that of
        :meth:`rollout` (to the rounding of batched products), and a step costs ``2 n_states + 1``
        one-step means, in one batch, and one predictive variance (at the mean: the triangular
        solve a variance needs costs ``n_train^2`` per point and per output, most of a step's
        time when taken at every perturbed point).

        Parameters
        ----------
        initial_state : ndarray, shape (n_states,) or (r, n_states)
        inputs : ndarray, shape (steps, n_inputs) or (r, steps, n_inputs)
        physics_step : callable or None
        initial_covariance : ndarray, shape (n_states, n_states) or (r, n_states, n_states), optional
            Covariance of the start state; default zero (the start is known).
        include_noise : bool, default True
            Add the GPs' noise variance to ``Sigma(k)``.
        step : float
            Central-difference step, in state units.

        Returns
        -------
        PropagatedRollout
            ``mean`` (steps + 1, n_states) and ``covariance`` (steps + 1, n_states, n_states), or
            with a leading axis r for r start states; row 0 is the start.
        """
        state, inputs, single = self._check_rollout(initial_state, inputs)
        r, n = state.shape
        covariance = np.zeros((r, n, n))
        if initial_covariance is not None:
            covariance = np.broadcast_to(np.asarray(initial_covariance, dtype=float), (r, n, n)).copy()
        offsets = step * np.concatenate([np.zeros((1, n)), np.eye(n), -np.eye(n)])  # (2n + 1, n)
        means, covariances = [state], [covariance]
        for k in range(inputs.shape[1]):
            points = (state[:, None, :] + offsets[None]).reshape(-1, n)
            u = np.repeat(inputs[:, k], len(offsets), axis=0)
            moved = self._physics(physics_step, points, u) + self.gp_.predict(self.gp_inputs(points, u))
            moved = moved.reshape(r, len(offsets), n)
            jacobian = np.swapaxes(moved[:, 1:n + 1] - moved[:, n + 1:], 1, 2) / (2 * step)  # (r, n, n)
            state = moved[:, 0]
            # The variance only at the mean (the perturbed points serve the Jacobian alone).
            _, variance = self._gp_predict(self.gp_inputs(points[::len(offsets)], inputs[:, k]),
                                           include_noise=include_noise)
            variance = variance * np.ones(n)
            covariance = jacobian @ covariance @ np.swapaxes(jacobian, 1, 2)
            covariance += variance[:, :, None] * np.eye(n)
            means.append(state)
            covariances.append(covariance)
        mean, covariance = np.stack(means, axis=1), np.stack(covariances, axis=1)
        return PropagatedRollout(mean[0], covariance[0]) if single else PropagatedRollout(mean, covariance)

    def sample_rollouts(self, initial_state, inputs, physics_step, *, n_samples: int,
                        seed: int = 0, include_noise: bool = False, spread_scale: float = 1.0) -> np.ndarray:
        """Rollouts that draw the GP residual instead of taking its mean (Ko et al., sec. IV-C).

        Each draw is conditioned on the residuals already drawn along the same rollout, so a
        rollout is one sample of a single function from the GP posterior (revisiting an input
        gives the same residual), not independent noise at every step
        (:meth:`sample_closed_loop` with the inputs fixed up front).

        Parameters
        ----------
        initial_state : ndarray, shape (n_states,)
        inputs : ndarray, shape (steps, n_inputs)
        physics_step : callable or None
        n_samples : int
        seed : int, default 0
            Seeds the standard normals of every draw.
        include_noise : bool, default False
            Add independent observation noise (variance ``sigma_n^2``) to every drawn residual;
            it is not part of the function and is not conditioned on.
        spread_scale : float, default 1
            Draw from a GP whose posterior covariance and noise variance are ``spread_scale**2``
            times the fitted ones (every standard normal multiplied by it: the conditioned draws
            then keep the scaled process's law, since the conditional mean's weights do not
            change with the covariance's scale). 0 gives the mean rollout. A calibration of the
            samples' size on validation flights; 1 is the posterior as fitted.

        Returns
        -------
        ndarray, shape (n_samples, steps + 1, n_states)
        """
        if n_samples < 1:
            raise ValueError(f"n_samples must be >= 1, got {n_samples}")
        if not (np.isfinite(spread_scale) and spread_scale >= 0):
            raise ValueError(f"spread_scale must be finite and >= 0, got {spread_scale}")
        state0, inputs, single = self._check_rollout(initial_state, inputs)
        if not single:
            raise ValueError("sample_rollouts takes one start state, shape (n_states,)")
        steps = inputs.shape[1]
        normals = spread_scale * np.random.default_rng(seed).standard_normal((n_samples, steps, 2, self.n_states_))
        return self.sample_closed_loop(np.repeat(state0, n_samples, axis=0), lambda k, states: inputs[0, k],
                                       steps, physics_step, normals=normals, include_noise=include_noise)

    def sample_closed_loop(self, initial_states, policy, steps: int, physics_step, *, normals,
                           include_noise: bool = False) -> np.ndarray:
        """Sampled rollouts whose inputs a policy chooses from the sampled states, step by step.

        At step k the policy sees every rollout's current state and returns its inputs; the
        residual is drawn from the GP conditioned on the residuals already drawn along the same
        rollout (Rasmussen & Williams 2006, eq. A.6, updated one draw at a time with the inverse
        Cholesky factor of the drawn points' posterior covariance), from the given standard
        normals. Fixed normals make the draws common random numbers: the same rollouts for every
        policy evaluated with them, as PEGASUS needs (Ng & Jordan, UAI 2000).

        Parameters
        ----------
        initial_states : ndarray, shape (r, n_states)
        policy : callable
            ``policy(k, states (r, n_states)) -> inputs`` of shape (r, n_inputs) or (n_inputs,).
        steps : int
        physics_step : callable or None
        normals : ndarray, shape (r, steps, 2, n_states)
            Standard normals: ``[:, k, 0]`` draw the latent residual at step k, ``[:, k, 1]`` its
            observation noise (read only with ``include_noise``).
        include_noise : bool, default False

        Returns
        -------
        ndarray, shape (r, steps + 1, n_states)
        """
        state = np.asarray(initial_states, dtype=float)
        normals = np.asarray(normals, dtype=float)
        r, n = state.shape
        if n != self.n_states_ or normals.shape != (r, steps, 2, n):
            raise ValueError(f"initial_states must have shape (r, {self.n_states_}) and normals "
                             f"(r, {steps}, 2, {self.n_states_}); got {state.shape} and {normals.shape}")
        sampler = _ConditionedSampler(self._gps(), n_rollouts=r, capacity=steps)
        noise_sd = np.sqrt(self._noise_variances()) if include_noise else np.zeros(n)
        path = [state]
        for k in range(steps):
            u = np.broadcast_to(np.asarray(policy(k, state), dtype=float), (r, self.n_inputs_))
            residual = sampler.draw(self.gp_inputs(state, u), normals[:, k, 0])
            state = self._physics(physics_step, state, u) + residual + noise_sd * normals[:, k, 1]
            path.append(state)
        return np.stack(path, axis=1)

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


class _ConditionedSampler:
    """Draws of the residual GPs' latent functions along r rollouts, each draw conditioned on the
    draws already made along the same rollout.

    Per GP, in its standardised units and at its point hyperparameters: the posterior covariance
    of two inputs is ``c(a, b) = k(a, b) - (V k_a) . (V k_b)`` (``V`` the predictive form's
    variance factor, ``k_a = k(basis, a)``). With ``Linv`` the inverse Cholesky factor of ``c``
    over the points drawn so far and ``w = Linv (f_o - mu_o)`` their whitened draws, the next
    draw at ``x`` has mean ``mu(x) + l . w`` and variance ``c(x, x) - l . l`` with
    ``l = Linv c(x_o, x)`` (Rasmussen & Williams 2006, eq. A.6), and ``Linv`` grows by the row
    ``[-l^T Linv, 1] / d`` with ``d`` the new conditional standard deviation: O(t^2) a draw, not
    O(t^3). A draw whose conditional variance is below :data:`_SAMPLING_JITTER` of the prior's is
    determined by the earlier ones: it is their conditional mean, and it joins the drawn points
    with a zero row of ``Linv`` (conditioning on it adds nothing; dividing by its ``d`` would only
    amplify rounding).
    """

    def __init__(self, gps, *, n_rollouts: int, capacity: int) -> None:
        self.parts = []
        for gp in gps:
            form = gp.predictive_forms(use_samples=False)[0]
            outputs = form.weights.reshape(len(form.basis), -1).shape[1]
            self.parts.append({
                "gp": gp, "form": form, "weights": form.weights.reshape(len(form.basis), -1),
                "kernel_weights": gp.kernel.weights(form.theta[:-1]), "prior": float(np.exp(form.theta[0])),
                "points": np.empty((n_rollouts, capacity, form.basis.shape[1])),
                "projected": np.empty((n_rollouts, capacity, len(form.basis))),
                "inverse": np.zeros((n_rollouts, capacity, capacity)),
                "whitened": np.empty((n_rollouts, capacity, outputs))})
        self.t = 0

    def draw(self, X: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """Latent draws at the GP inputs ``X`` (r, d) from standard normals (r, n_outputs);
        returns (r, n_outputs) in output units."""
        t, columns, draws = self.t, 0, []
        for part in self.parts:
            gp, form = part["gp"], part["form"]
            z = gp.input_scaler_.transform(X)
            k_basis = gp.kernel(z, form.basis, theta=form.theta[:-1])  # (r, m)
            mean = k_basis @ part["weights"]  # (r, q)
            projected = k_basis @ form.variance_factor.T  # V k_x, (r, m)
            variance = part["prior"] - np.sum(projected**2, axis=1)
            lower = np.zeros((len(z), 0))
            if t:
                distance = np.einsum("rtd,d->rt", (part["points"][:, :t] - z[:, None]) ** 2, part["kernel_weights"])
                cross = part["prior"] * np.exp(-distance) - np.einsum("rtm,rm->rt", part["projected"][:, :t], projected)
                lower = np.einsum("rts,rs->rt", part["inverse"][:, :t, :t], cross)
                mean = mean + np.einsum("rt,rtq->rq", lower, part["whitened"][:, :t])
                variance = variance - np.sum(lower**2, axis=1)
            free = variance > _SAMPLING_JITTER * part["prior"]  # (r,): not determined by the earlier draws
            sd = np.sqrt(np.where(free, variance, 1.0))
            q = mean.shape[1]
            z_draw = np.where(free[:, None], normals[:, columns:columns + q], 0.0)
            draws.append(gp.output_scaler_.inverse_transform(mean + sd[:, None] * z_draw))
            part["points"][:, t], part["projected"][:, t], part["whitened"][:, t] = z, projected, z_draw
            row = -np.einsum("rs,rst->rt", lower, part["inverse"][:, :t, :t]) / sd[:, None]
            part["inverse"][:, t, :t] = np.where(free[:, None], row, 0.0)
            part["inverse"][:, t, t] = np.where(free, 1.0 / sd, 0.0)
            columns += q
        self.t += 1
        return np.hstack(draws)


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
