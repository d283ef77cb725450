"""Tests of the grey-box model (gp_model/_greybox.py): physics step plus residual GP.

Properties: the residual GP is zero where the physics is exact; a known unmodelled term is
recovered; GP-only is the identity physics; rollouts are vectorised consistently; conditioned
sampling draws one function per rollout (same input, same residual) with the GP's joint
posterior mean and covariance at the visited inputs.
"""
import numpy as np
import pytest

from gp_model import GreyBoxGP
from tests.gp_model.cart import CART_PHYSICS, physics, trajectory, unmodelled


@pytest.mark.parametrize("shared", [True, False])
def test_residual_gp_is_zero_where_the_physics_is_exact(shared):
    states, inputs = trajectory(80, seed=0)
    model = GreyBoxGP(state_columns=[1], shared=shared, n_restarts=0).fit_trajectories(
        [(states, inputs)], physics)
    test_states, test_inputs = trajectory(30, seed=1)
    mean, var = model.predict_one_step(test_states, test_inputs, physics)
    # Residuals are exactly zero, so the GP posterior mean is exactly zero (alpha = 0).
    np.testing.assert_allclose(mean, physics(test_states, test_inputs), atol=1e-12)
    assert mean.shape == var.shape == (30, 2) and np.all(var >= 0)
    rollout = model.rollout(test_states[0], test_inputs[:-1], physics)
    np.testing.assert_allclose(rollout, test_states, atol=1e-12)


@pytest.mark.parametrize("shared", [True, False])
def test_known_unmodelled_term_is_recovered(shared):
    training = [trajectory(120, seed=s, extra=True) for s in (2, 3)]
    model = GreyBoxGP(state_columns=[1], shared=shared, noise_variance=1e-4, n_restarts=0).fit_trajectories(
        training, physics)
    states, inputs = trajectory(60, seed=4, extra=True)
    mean, var = model.predict_one_step(states[:-1], inputs[:-1], physics)
    truth_residual = unmodelled(states[:-1], inputs[:-1])
    learned = mean[:, 1] - physics(states[:-1], inputs[:-1])[:, 1]
    # The term spans about +-0.07; 5 % of that is a tight fit for 240 training pairs.
    assert np.max(np.abs(learned - truth_residual)) < 0.004
    assert np.max(np.abs(mean[:, 0] - states[1:, 0])) < 1e-3  # position step is exact physics
    # The grey box beats the physics alone over a whole free rollout.
    physics_only = [states[0]]
    for k in range(len(states) - 1):
        physics_only.append(physics(physics_only[-1][None], inputs[k:k + 1])[0])
    rollout = model.rollout(states[0], inputs[:-1], physics)
    assert np.abs(rollout - states).max() < 0.1 * np.abs(np.array(physics_only) - states).max()


def test_gp_only_learns_the_whole_increment():
    states, inputs = trajectory(100, seed=5, extra=True)
    model = GreyBoxGP(shared=True, noise_variance=1e-4, n_restarts=0).fit_trajectories(
        [(states, inputs)], None)
    assert np.allclose(model.residuals(states[:-1], inputs[:-1], states[1:], None), np.diff(states, axis=0))
    mean, _ = model.predict_one_step(states[:-1], inputs[:-1], None)
    assert np.sqrt(np.mean((mean - states[1:]) ** 2)) < 2e-3


def test_vectorised_rollout_matches_single_rollouts():
    states, inputs = trajectory(60, seed=6, extra=True)
    model = GreyBoxGP(state_columns=[1], n_restarts=0).fit_trajectories([(states, inputs)], physics)
    starts = states[[0, 10, 20]]
    controls = np.stack([inputs[0:15], inputs[10:25], inputs[20:35]])
    together = model.rollout(starts, controls, physics)
    assert together.shape == (3, 16, 2)
    for r in range(3):
        # Batched and single kernel products round differently; 15 steps amplify that to ~1e-9.
        np.testing.assert_allclose(together[r], model.rollout(starts[r], controls[r], physics), atol=1e-8)


def test_conditioned_samples_are_one_function_per_rollout():
    states, inputs = trajectory(80, seed=7, extra=True)
    # GP inputs: the control only, so a constant control revisits one GP input every step.
    model = GreyBoxGP(state_columns=[], n_restarts=0).fit_trajectories([(states, inputs)], physics)
    constant = np.full((5, 1), 0.3)
    runs = model.sample_rollouts(states[0], constant, physics, n_samples=400, seed=1)
    assert runs.shape == (400, 6, 2)
    increments = np.stack([runs[:, k + 1] - physics(runs[:, k], np.broadcast_to(constant[k], (400, 1)))
                           for k in range(5)], axis=1)  # (400, 5, 2) drawn residuals
    # Conditioning on the earlier draws at the same input leaves (almost) no variance.
    np.testing.assert_allclose(increments, np.broadcast_to(increments[:, :1], increments.shape), atol=1e-4)
    # The first draw has the GP's latent mean and variance (400 draws: mean within ~4 standard
    # errors, variance within ~30 %, the chi-square spread at 400 samples being ~7 %).
    mean, var = model.gp_.predict(model.gp_inputs(states[:1], constant[:1]), return_var=True)
    first = increments[:, 0]
    assert np.all(np.abs(first.mean(axis=0) - mean[0]) < 4 * np.sqrt(var[0] / 400) + 1e-12)
    assert np.allclose(first.var(axis=0), var[0], rtol=0.3)
    again = model.sample_rollouts(states[0], constant, physics, n_samples=400, seed=1)
    np.testing.assert_array_equal(runs, again)


def test_conditioned_samples_stay_finite_when_one_input_is_revisited_for_long():
    """Hundreds of draws at one GP input: after the first, every draw is determined by it (its
    conditional mean, the first draw again), and the sampler's inverse factor must not amplify
    rounding (with the determined draws conditioned on, such rollouts used to blow up)."""
    states, inputs = trajectory(80, seed=7, extra=True)
    model = GreyBoxGP(state_columns=[], n_restarts=0).fit_trajectories([(states, inputs)], physics)
    constant = np.full((400, 1), 0.3)
    runs = model.sample_rollouts(states[0], constant, physics, n_samples=20, seed=2)
    increments = np.stack([runs[:, k + 1] - physics(runs[:, k], np.broadcast_to(constant[k], (20, 1)))
                           for k in range(400)], axis=1)
    assert np.isfinite(runs).all()
    np.testing.assert_allclose(increments, np.broadcast_to(increments[:, :1], increments.shape), atol=1e-6)
    assert np.ptp(increments[:, 0, 0]) > 1e-3  # the first draws do differ between samples


@pytest.mark.parametrize("shared", [True, False])
def test_conditioned_sampling_reproduces_the_joint_posterior_covariance(shared):
    # GP inputs are the control only, so the inputs a rollout visits are known in advance (the
    # controls), whatever the physics does with the state: the residuals drawn along a rollout
    # are then draws of the latent function at fixed points and must have the GP's joint
    # posterior mean and covariance there (Ko et al. 2007, sec. IV-C), correlations included.
    states, inputs = trajectory(15, seed=7, extra=True)
    # Fixed hyperparameters (unit length scale in standardised units): type-II ML on the control
    # alone collapses the length scale and with it every correlation this test is about.
    model = GreyBoxGP(state_columns=[], shared=shared).fit_trajectories([(states, inputs)], physics,
                                                                       optimize=False)
    # Four close controls beyond the training range (neighbour correlations 0.6-0.96) and one
    # back inside it (nearly independent of them).
    controls = np.array([[1.2], [1.4], [1.6], [1.9], [-0.1]])
    n = 2000
    runs = model.sample_rollouts(states[0], controls, physics, n_samples=n, seed=11)
    drawn = np.stack([runs[:, k + 1] - physics(runs[:, k], np.broadcast_to(controls[k], (n, 1)))
                      for k in range(len(controls))], axis=1)  # (n, 5, 2) drawn residuals
    X = model.gp_inputs(np.zeros((len(controls), 2)), controls)
    gps = [model.gp_] if shared else model.gp_.gps
    joint = [gp.predict(X, return_cov=True) for gp in gps]
    mean = np.column_stack([m.reshape(len(X), -1) for m, _ in joint])  # (5, 2)
    cov = np.concatenate([c.reshape(len(X), len(X), -1) for _, c in joint], axis=2)  # (5, 5, 2)
    for j in range(2):
        # Whitened by the GP's joint covariance, correct draws are iid standard normal: their
        # mean has standard error 1/sqrt(n) and their second moment matrix S = I with standard
        # error 1/sqrt(n) off the diagonal and sqrt(2/n) on it (Gaussian fourth moments).
        # Five standard errors on each of the 5 + 15 entries: a correct sampler fails with
        # probability below 1e-5, and the seed is fixed.
        L = np.linalg.cholesky(cov[:, :, j])
        z = np.linalg.solve(L, (drawn[:, :, j] - mean[:, j]).T)  # (5, n)
        second = z @ z.T / n
        standard_error = np.where(np.eye(len(X), dtype=bool), np.sqrt(2 / n), np.sqrt(1 / n))
        assert np.all(np.abs(z.mean(axis=1)) < 5 / np.sqrt(n))
        assert np.all(np.abs(second - np.eye(len(X))) < 5 * standard_error), second
        # Power: independent draws with the right marginal variances (no conditioning) would
        # have S = L^-1 diag(C) L^-T, which misses I by far more than the tolerance.
        independent = np.linalg.solve(L, np.linalg.solve(L, np.diag(np.diag(cov[:, :, j]))).T)
        assert np.max(np.abs(independent - np.eye(len(X))) / standard_error) > 50


@pytest.mark.parametrize("shared", [True, False])
def test_incremental_draws_equal_the_joint_cholesky_draw(shared):
    """Along one rollout with known GP inputs, the incremental sampler's draws are exactly
    ``mean + L z`` with ``L`` the Cholesky factor of the joint posterior covariance at the visited
    inputs, in visiting order (its incremental form must not drift from the direct one)."""
    states, inputs = trajectory(15, seed=7, extra=True)
    model = GreyBoxGP(state_columns=[], shared=shared).fit_trajectories([(states, inputs)], physics,
                                                                       optimize=False)
    controls = np.array([[1.2], [1.4], [-0.3], [1.9], [0.4], [1.3]])
    normals = np.random.default_rng(3).standard_normal((1, len(controls), 2, 2))
    runs = model.sample_closed_loop(states[:1], lambda k, s: controls[k], len(controls), physics, normals=normals)
    drawn = np.stack([runs[0, k + 1] - physics(runs[:1, k], controls[k][None])[0] for k in range(len(controls))])
    X = model.gp_inputs(np.zeros((len(controls), 2)), controls)
    gps = [model.gp_] if shared else model.gp_.gps
    columns = 0
    for gp in gps:
        mean, cov = gp.predict(X, return_cov=True, use_samples=False)
        mean, cov = mean.reshape(len(X), -1), cov.reshape(len(X), len(X), -1)
        for j in range(mean.shape[1]):
            # The sampler works in standardised units: scale the joint covariance back.
            expected = mean[:, j] + np.linalg.cholesky(cov[:, :, j]) @ normals[0, :, 0, columns + j]
            # Two algebraically equal factorisations of a 6 x 6 matrix: rounding only.
            np.testing.assert_allclose(drawn[:, columns + j], expected, rtol=1e-8, atol=1e-10)
        columns += mean.shape[1]


def test_spread_scale_draws_from_the_scaled_posterior():
    """With the GP inputs fixed by the controls, a draw is ``mean + L z`` (above); scaling the
    posterior covariance and the noise by ``c**2`` must give ``mean + c (L z + noise)`` for the
    same normals, and ``c = 0`` the mean."""
    states, inputs = trajectory(15, seed=7, extra=True)
    model = GreyBoxGP(state_columns=[]).fit_trajectories([(states, inputs)], physics, optimize=False)
    controls = np.array([[1.2], [1.4], [-0.3], [1.9]])

    def drawn(scale):
        runs = model.sample_rollouts(states[0], controls, physics, n_samples=3, seed=4, include_noise=True,
                                     spread_scale=scale)
        return np.stack([runs[:, k + 1] - physics(runs[:, k], np.broadcast_to(controls[k], (3, 1)))
                         for k in range(len(controls))], axis=1)

    mean = model.gp_.predict(model.gp_inputs(np.zeros((len(controls), 2)), controls))
    np.testing.assert_allclose(drawn(0.0), np.broadcast_to(mean, (3, len(controls), 2)), atol=1e-12)
    np.testing.assert_allclose(drawn(2.5) - drawn(0.0), 2.5 * (drawn(1.0) - drawn(0.0)), rtol=1e-8, atol=1e-12)
    with pytest.raises(ValueError, match="spread_scale"):
        model.sample_rollouts(states[0], controls, physics, n_samples=1, spread_scale=-1.0)


def test_closed_loop_sampling_takes_the_policys_inputs_and_common_random_numbers():
    states, inputs = trajectory(40, seed=5, extra=True)
    model = GreyBoxGP(state_columns=[1], n_restarts=0).fit_trajectories([(states, inputs)], physics)
    normals = np.random.default_rng(0).standard_normal((3, 12, 2, 2))
    start = np.repeat(states[:1], 3, axis=0)

    def braking(k, s):  # a feedback policy: push against the velocity
        return -2.0 * s[:, 1:2]

    first = model.sample_closed_loop(start, braking, 12, physics, normals=normals)
    again = model.sample_closed_loop(start, braking, 12, physics, normals=normals)
    np.testing.assert_array_equal(first, again)  # common random numbers: the same rollouts
    pushing = model.sample_closed_loop(start, lambda k, s: np.ones((3, 1)), 12, physics, normals=normals)
    assert np.abs(pushing[:, -1, 1]).min() > np.abs(first[:, -1, 1]).max()  # the policy acts
    with pytest.raises(ValueError, match="normals"):
        model.sample_closed_loop(start, braking, 12, physics, normals=normals[:, :5])


def test_propagated_mean_is_the_rollout_and_its_covariance_the_linear_update():
    states, inputs = trajectory(60, seed=6, extra=True)
    # A noise floor keeps the near-deterministic position residual's GP well conditioned, so its
    # mean is smooth at the scale of the finite differences (without it the noise variance falls
    # to ~3e-7 and the Jacobian picks up ~1e-5 of rounding).
    model = GreyBoxGP(state_columns=[1], shared=False, n_restarts=0, min_noise_variance=1e-4).fit_trajectories(
        [(states, inputs)], physics)
    controls = inputs[:10]
    propagated = model.propagate(states[0], controls, physics)
    # The mean is the rollout's; the batched GP products round differently (as in the batched
    # rollout test above).
    np.testing.assert_allclose(propagated.mean, model.rollout(states[0], controls, physics), rtol=0, atol=1e-8)
    assert propagated.covariance.shape == (11, 2, 2) and np.all(propagated.covariance[0] == 0)
    # One step by hand: P' = J P J^T + diag(var) at the mean, J by central differences.
    for k in range(10):
        mu, u = propagated.mean[k], controls[k]
        jacobian = np.column_stack([
            (model.predict_one_step((mu + 1e-5 * e)[None], u[None], physics)[0][0]
             - model.predict_one_step((mu - 1e-5 * e)[None], u[None], physics)[0][0]) / 2e-5
            for e in np.eye(2)])
        variance = model.predict_one_step(mu[None], u[None], physics, include_noise=True)[1][0]
        expected = jacobian @ propagated.covariance[k] @ jacobian.T + np.diag(variance)
        # The same arithmetic batched and unbatched: rounding only, absolute where a latent
        # variance is the small difference of the prior and the explained part (~1e-15 of ~0.1).
        np.testing.assert_allclose(propagated.covariance[k + 1], expected, rtol=1e-9, atol=1e-13)
    assert np.all(np.diff(propagated.sd[:, 0]) > 0)  # position uncertainty grows along the run
    together = model.propagate(states[[0, 5]], np.stack([controls, inputs[5:15]]), physics,
                               initial_covariance=1e-4 * np.eye(2))
    single = model.propagate(states[5], inputs[5:15], physics, initial_covariance=1e-4 * np.eye(2))
    # Batched and single GP products round differently, and the central differences multiply that
    # rounding by 1 / (2 step) = 5e4: agreement to ~1e-7 relative.
    np.testing.assert_allclose(together.covariance[1], single.covariance, rtol=1e-6, atol=1e-15)


def test_bad_shapes_are_refused_with_the_expected_shapes():
    states, inputs = trajectory(20, seed=8)
    model = GreyBoxGP(state_columns=[1], n_restarts=0).fit_trajectories([(states, inputs)], physics)
    with pytest.raises(ValueError, match="fitted with 2 states and 1 inputs"):
        model.predict_one_step(np.zeros((3, 3)), np.zeros((3, 1)), physics)
    with pytest.raises(ValueError, match="same n"):
        model.fit(states, inputs[:-1], states, physics)
    with pytest.raises(ValueError, match="physics_step returned shape"):
        model.predict_one_step(states, inputs, lambda s, u: s[:, :1])
    with pytest.raises(ValueError, match="initial_state must have shape"):
        model.rollout(np.zeros(2), np.zeros((4, 2)), physics)
    with pytest.raises(ValueError, match="state_columns"):
        GreyBoxGP(state_columns=[5]).fit(states, inputs, states, physics)
    with pytest.raises(ValueError, match="NaN"):
        model.predict_one_step(np.full((1, 2), np.nan), np.zeros((1, 1)), physics)


# -- model files ----------------------------------------------------------------------------------


@pytest.mark.parametrize("shared", [True, False])
def test_model_file_keeps_the_physics_description_and_structure(shared, tmp_path):
    from gp_model import load_model, read_header, save_model

    training = [trajectory(60, seed=s, extra=True) for s in (9, 10)]
    model = GreyBoxGP(state_columns=[1], shared=shared, n_restarts=0).fit_trajectories(training, physics)
    path = save_model(tmp_path / "cart", model, physics=CART_PHYSICS, meta={"note": "cart"})
    loaded = load_model(path)
    header = read_header(path)
    assert header["type"] == "GreyBoxGP" and header["physics"] == CART_PHYSICS
    assert header["structure"]["state_columns"] == [1] and header["structure"]["shared"] is shared
    assert (loaded.shared, loaded.state_columns, loaded.n_states_, loaded.n_inputs_) == (shared, (1,), 2, 1)
    # Identical predictions after a round trip: the contract (tests/gp_model/contract.py).


def test_model_file_needs_a_physics_description_and_refuses_bad_files(tmp_path):
    import json
    import zipfile

    from gp_model import GaussianProcess, ModelFileError, SquaredExponentialARD, load_model, save_model

    states, inputs = trajectory(30, seed=12, extra=True)
    model = GreyBoxGP(state_columns=[1], n_restarts=0).fit_trajectories([(states, inputs)], physics)
    with pytest.raises(ValueError, match="needs physics"):
        save_model(tmp_path / "no_physics", model)
    with pytest.raises(ValueError, match="not fitted"):
        save_model(tmp_path / "unfitted", GreyBoxGP(), physics=CART_PHYSICS)
    gp = GaussianProcess(SquaredExponentialARD(1.0, np.ones(1))).fit(states[:, :1], states[:, 1])
    with pytest.raises(ValueError, match="only stored with a GreyBoxGP"):
        save_model(tmp_path / "gp", gp, physics=CART_PHYSICS)
    good = save_model(tmp_path / "good", model, physics=CART_PHYSICS)

    def rewrite(name, change):
        """A copy of the good file with its header (a dict) changed by ``change``."""
        with np.load(good, allow_pickle=False) as npz:
            arrays = {key: npz[key] for key in npz.files}
        header = json.loads(str(arrays["__header__"]))
        change(header, arrays)
        arrays["__header__"] = np.array(json.dumps(header))
        np.savez(tmp_path / name, **arrays)
        return tmp_path / name

    bad = {
        "no physics": rewrite("a.npz", lambda h, a: h.pop("physics")),
        "physics without kind": rewrite("b.npz", lambda h, a: h.update(physics={"dt": 0.1})),
        "state column out of range": rewrite("c.npz", lambda h, a: h["structure"].update(state_columns=[7])),
        "wrong number of parts": rewrite("d.npz", lambda h, a: h["structure"].update(shared=False)),
        "wrong input count": rewrite("e.npz", lambda h, a: h["structure"].update(n_inputs=3)),
        "no structure": rewrite("f.npz", lambda h, a: h.update(structure=None)),
        "unknown type": rewrite("g.npz", lambda h, a: h.update(type="BlackBoxGP")),
    }
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    bad["truncated"] = truncated
    with zipfile.ZipFile(tmp_path / "nan.npz", "w") as archive, zipfile.ZipFile(good) as source:
        for item in source.namelist():
            data = source.read(item)
            if item == "gp0/theta.npy":
                with np.load(good, allow_pickle=False) as npz:
                    buffer = __import__("io").BytesIO()
                    np.save(buffer, np.full_like(npz["gp0/theta"], np.nan))
                    data = buffer.getvalue()
            archive.writestr(item, data)
    bad["NaN hyperparameters"] = tmp_path / "nan.npz"
    for path in bad.values():  # each problem is a ModelFileError (messages: test_model_file.py)
        with pytest.raises(ModelFileError):
            load_model(path)
