"""ProMP: basis, evaluation, sampling, conditioning (joint and task space), learning, files.

Sections: smoke, shapes/batching, bad input, accuracy on a synthetic scene, statistical checks
(seeded), shipped primitive. The synthetic scene is one ground-truth ProMP (``_truth``) whose
samples, with random durations and noise, are the demonstrations; the task-space checks use a
3-link planar arm written here.
"""

from __future__ import annotations

import numpy as np
import pytest

from policies.promp import NIWPrior, ProMP, RBFBasis

LINKS_M = np.array([0.5, 0.4, 0.3])


# ----------------------------------------------------------------------------- synthetic scene
def _truth(n_dims: int = 3, n_basis: int = 8, seed: int = 0) -> ProMP:
    """A ground-truth primitive with correlated weights (smooth random trajectories)."""
    rng = np.random.default_rng(seed)
    K = n_basis
    mu = np.concatenate([np.sin(np.linspace(0, np.pi, K)) * (0.5 + 0.2 * d) + 0.1 * d for d in range(n_dims)])
    idx = np.arange(K)
    smooth = 0.02 * np.exp(-0.5 * (idx[:, None] - idx[None, :]) ** 2 / 2.0**2)
    A = rng.normal(0, 0.5, (n_dims, n_dims))
    joint = A @ A.T / n_dims + 0.5 * np.eye(n_dims)
    Sigma_w = np.kron(joint, smooth) + 1e-6 * np.eye(n_dims * K)
    return ProMP(RBFBasis(K), mu, Sigma_w, (2e-3) ** 2 * np.eye(n_dims), duration_s=1.0,
                 joint_names=tuple(f"j{d}" for d in range(n_dims)), robot_id="toy")


def _demos(truth: ProMP, n: int, rng: np.random.Generator, rate_hz: float = 200.0):
    """n demonstrations: sampled weights, durations 0.8-1.2 s, observation noise Sigma_y."""
    demos, times = [], []
    w = truth.sample_weights(rng, n).reshape(n, truth.n_dims, -1)
    for i in range(n):
        T = rng.uniform(0.8, 1.2)
        t = np.arange(int(T * rate_hz) + 1) / rate_hz
        t = t * T / t[-1]
        phi = truth.basis(t / T)
        q = phi @ w[i].T + rng.multivariate_normal(np.zeros(truth.n_dims), truth.Sigma_y, len(t))
        demos.append(q)
        times.append(t + rng.uniform(0, 5))  # demos need not start at t = 0
    return demos, times


def _fk(q):
    """Planar 3-link arm: end point (2,)."""
    a = np.cumsum(q)
    return np.array([LINKS_M @ np.cos(a), LINKS_M @ np.sin(a)])


def _jac(q):
    a = np.cumsum(q)
    J = np.zeros((2, 3))
    for j in range(3):
        J[0, j] = -(LINKS_M[j:] * np.sin(a[j:])).sum()
        J[1, j] = (LINKS_M[j:] * np.cos(a[j:])).sum()
    return J


@pytest.fixture(scope="module")
def truth():
    return _truth()


@pytest.fixture(scope="module")
def learned(truth):
    demos, times = _demos(truth, 40, np.random.default_rng(1))
    return ProMP.learn(demos, times, n_basis=8, joint_names=truth.joint_names, robot_id="toy")


# ----------------------------------------------------------------------------- smoke
def test_smoke_learn_evaluate_condition(learned):
    promp, info = learned
    q, qd = promp.mean_trajectory(np.linspace(0, promp.duration_s, 5))
    assert q.shape == qd.shape == (5, 3)
    assert info.mode == "map" and info.converged and info.iterations >= 1
    cond = promp.condition_on_joint(0.5, q_mean=q[2])
    assert isinstance(cond, ProMP) and cond is not promp


# ----------------------------------------------------------------------------- basis
def test_basis_normalised_and_derivative_matches_finite_differences():
    basis = RBFBasis(12, width=0.06)
    z = np.linspace(0, 1, 301)
    phi, dphi = basis.evaluate(z)
    np.testing.assert_allclose(phi.sum(axis=1), 1.0, atol=1e-12)
    assert (phi > 0).all()
    h = 1e-6
    fd = (basis(np.clip(z + h, 0, 1)) - basis(np.clip(z - h, 0, 1))) / (np.clip(z + h, 0, 1) - np.clip(z - h, 0, 1))[:, None]
    np.testing.assert_allclose(dphi, fd, rtol=1e-4, atol=1e-6)  # one-sided at the ends


def test_basis_polynomial_terms_and_defaults():
    basis = RBFBasis(5, n_poly=2)
    assert basis.n_functions == 7 and basis.width == pytest.approx(0.25)
    phi, dphi = basis.evaluate(np.array([0.5]))
    np.testing.assert_allclose(phi[0, 5:], [0.5, 0.25])
    np.testing.assert_allclose(dphi[0, 5:], [1.0, 1.0])
    np.testing.assert_allclose(phi[0, :5].sum(), 1.0)


# ----------------------------------------------------------------------------- shapes / batching
def test_shapes_of_evaluation_and_sampling(truth):
    t = np.linspace(0, 1, 7)
    q, qd = truth.mean_trajectory(t)
    assert q.shape == qd.shape == (7, 3)
    assert truth.covariance(t).shape == (7, 6, 6)
    sq, sqd = truth.std(t)
    assert sq.shape == sqd.shape == (7, 3)
    Q, QD = truth.sample(np.random.default_rng(0), 4, t)
    assert Q.shape == QD.shape == (4, 7, 3)
    assert truth.sample_weights(np.random.default_rng(0), 0).shape == (0, 24)
    q1, _ = truth.mean_trajectory(0.3)  # a scalar time is a batch of one
    assert q1.shape == (1, 3)
    np.testing.assert_allclose(q1, truth.mean_trajectory(np.array([0.3]))[0])
    x, x_cov = truth.task_marginal(t, _fk, _jac)
    assert x.shape == (7, 2) and x_cov.shape == (7, 2, 2)


def test_phase_and_time_arguments_agree(truth):
    z = np.linspace(0, 1, 9)
    a = truth.mean_trajectory(z * 2.5, duration_s=2.5)
    b = truth.mean_trajectory(phase=z, duration_s=2.5)
    np.testing.assert_allclose(a[0], b[0])
    np.testing.assert_allclose(a[1], b[1])


def test_velocity_is_time_derivative_of_position(truth):
    t = np.linspace(0, 1.7, 4001)
    q, qd = truth.mean_trajectory(t, duration_s=1.7)
    np.testing.assert_allclose(np.gradient(q, t, axis=0)[5:-5], qd[5:-5], atol=1e-4)


def test_time_scaling_keeps_positions_at_equal_phase_and_scales_velocities(truth):
    slow = truth.with_duration(2.0)
    assert slow.duration_s == 2.0 and truth.duration_s == 1.0
    q1, qd1 = truth.mean_trajectory([0.25, 0.5])
    q2, qd2 = slow.mean_trajectory([0.5, 1.0])
    np.testing.assert_allclose(q2, q1)
    np.testing.assert_allclose(qd2, qd1 / 2.0)
    s1 = truth.std([0.5])[1]
    s2 = slow.std([1.0])[1]
    np.testing.assert_allclose(s2, s1 / 2.0)


# ----------------------------------------------------------------------------- conditioning
def test_condition_on_joint_passes_through_via_point_and_shrinks_variance(truth):
    t = 0.6
    q_star = truth.mean_trajectory([t])[0][0] + np.array([0.1, -0.05, 0.2])
    cond = truth.condition_on_joint(t, q_mean=q_star)
    np.testing.assert_allclose(cond.mean_trajectory([t])[0][0], q_star, atol=1e-6)
    assert (cond.std([t])[0][0] < 1e-3 * truth.std([t])[0][0]).all()
    # far from the via point the distribution keeps (most of) its spread
    assert (cond.std([0.0])[0][0] > 0.1 * truth.std([0.0])[0][0]).all()


def test_conditioning_returns_new_object_and_leaves_original_unchanged(truth):
    mu, Sw = truth.mu_w.copy(), truth.Sigma_w.copy()
    cond = truth.condition_on_joint(0.3, q_mean=np.zeros(3))
    cond2 = truth.condition_on_task(0.5, truth.task_marginal([0.5], _fk, _jac)[0][0] + [0.05, 0.0], None, _fk, _jac)
    assert cond is not truth and cond2 is not truth
    np.testing.assert_array_equal(truth.mu_w, mu)
    np.testing.assert_array_equal(truth.Sigma_w, Sw)
    with pytest.raises(ValueError, match="read-only"):
        truth.mu_w[0] = 1.0
    assert cond.joint_names == truth.joint_names and cond.robot_id == "toy"


def test_condition_with_uncertain_via_point_matches_gaussian_formula(truth):
    t = 0.4
    cov = truth.covariance([t])[0][:3, :3]
    R = np.diag([1e-3, 2e-3, 5e-4])
    q_star = np.array([0.2, 0.0, -0.1])
    cond = truth.condition_on_joint(t, q_mean=q_star, q_cov=R)
    mean0 = truth.mean_trajectory([t])[0][0]
    gain = cov @ np.linalg.inv(cov + R)
    np.testing.assert_allclose(cond.mean_trajectory([t])[0][0], mean0 + gain @ (q_star - mean0), atol=1e-9)
    np.testing.assert_allclose(cond.covariance([t])[0][:3, :3], cov - gain @ cov, atol=1e-9)


def test_condition_on_velocity(truth):
    qd_star = np.array([1.0, -0.5, 0.0])
    cond = truth.condition_on_joint(0.5, qd_mean=qd_star, duration_s=0.8)
    np.testing.assert_allclose(cond.mean_trajectory([0.5], duration_s=0.8)[1][0], qd_star, atol=1e-6)
    both = truth.condition_on_joint(0.5, q_mean=np.zeros(3), qd_mean=qd_star)
    q, qd = both.mean_trajectory([0.5])
    np.testing.assert_allclose(q[0], 0.0, atol=1e-6)
    np.testing.assert_allclose(qd[0], qd_star, atol=1e-6)


def test_condition_on_task_reaches_target_on_toy_arm(truth):
    t = 0.55
    x0 = _fk(truth.mean_trajectory([t])[0][0])
    target = x0 + np.array([0.12, -0.08])
    cond = truth.condition_on_task(t, target, None, _fk, _jac)
    np.testing.assert_allclose(_fk(cond.mean_trajectory([t])[0][0]), target, atol=1e-6)
    x_cov_before = truth.task_marginal([t], _fk, _jac)[1][0]
    x_cov_after = cond.task_marginal([t], _fk, _jac)[1][0]
    assert np.trace(x_cov_after) < 1e-6 * np.trace(x_cov_before)


def test_condition_on_task_with_noise_is_between_prior_and_target(truth):
    t = 0.55
    x0 = _fk(truth.mean_trajectory([t])[0][0])
    target = x0 + np.array([0.1, 0.0])
    prior_cov = truth.task_marginal([t], _fk, _jac)[1][0]
    cond = truth.condition_on_task(t, target, prior_cov, _fk, _jac, max_residual_m=None)
    x1 = _fk(cond.mean_trajectory([t])[0][0])
    # equal prior and measurement uncertainty -> roughly halfway (nonlinear kinematics: loosely)
    frac = (x1 - x0) @ (target - x0) / np.sum((target - x0) ** 2)
    assert 0.35 < frac < 0.65


def test_condition_on_task_unreachable_point_raises(truth):
    with pytest.raises(ValueError, match="unreachable"):
        truth.condition_on_task(0.5, np.array([3.0, 0.0]), None, _fk, _jac)


# ----------------------------------------------------------------------------- learning
def test_em_objective_is_monotone_for_map_and_ml(truth):
    demos, times = _demos(truth, 6, np.random.default_rng(2))
    for prior in (NIWPrior(), None):
        _, info = ProMP.learn(demos, times, n_basis=8, prior=prior, max_iter=60)
        obj = info.objective
        assert len(obj) == info.iterations + 1
        assert np.all(np.diff(obj) >= -1e-9 * np.abs(obj[1:])), info.mode
        assert obj[-1] > obj[0]
    _, info_ml = ProMP.learn(demos, times, n_basis=8, prior=None, max_iter=60)
    np.testing.assert_allclose(info_ml.objective, info_ml.log_likelihood)


def test_map_beats_ml_on_held_out_demos_when_demos_are_few(truth):
    rng = np.random.default_rng(3)
    held_out = _demos(truth, 30, rng)
    wins = 0
    for trial in range(3):
        train = _demos(truth, 4, rng)
        map_p, _ = ProMP.learn(*train, n_basis=8, prior=NIWPrior())
        ml_p, _ = ProMP.learn(*train, n_basis=8, prior=None)
        wins += map_p.log_likelihood(*held_out).mean() > ml_p.log_likelihood(*held_out).mean()
    assert wins == 3


def test_learning_recovers_the_generating_primitive(truth, learned):
    promp, _ = learned
    t = np.linspace(0, 1, 50)
    q_true, _ = truth.mean_trajectory(phase=t)
    q_hat, _ = promp.mean_trajectory(phase=t)
    sd_true = truth.std(phase=t)[0]
    sd_hat = promp.std(phase=t)[0]
    # mean within ~ a third of the spread (40 demos), spread within 35 %
    assert np.abs(q_hat - q_true).max() < 0.35 * sd_true.mean()
    np.testing.assert_allclose(sd_hat, sd_true, rtol=0.35)
    np.testing.assert_allclose(np.sqrt(np.diag(promp.Sigma_y)), 2e-3, rtol=0.15)
    assert promp.duration_s == pytest.approx(1.0, abs=0.08)


def test_log_likelihood_prefers_the_generating_distribution(truth, learned):
    promp, _ = learned
    own = _demos(truth, 8, np.random.default_rng(5))
    shifted = ProMP(promp.basis, promp.mu_w + 0.4, promp.Sigma_w, promp.Sigma_y, promp.duration_s)
    wider = ProMP(promp.basis, promp.mu_w, 9.0 * promp.Sigma_w, promp.Sigma_y, promp.duration_s)
    ll = promp.log_likelihood(*own)
    assert ll.shape == (8,)
    assert (ll > shifted.log_likelihood(*own)).all()
    assert (ll > wider.log_likelihood(*own)).all()


# ----------------------------------------------------------------------------- statistics (seeded)
def test_sample_moments_match_covariance(truth):
    t = np.array([0.1, 0.5, 0.9])
    Q, QD = truth.sample(np.random.default_rng(11), 20000, t)
    X = np.concatenate([Q, QD], axis=2)  # (s, n, 6)
    emp = np.einsum("sni,snj->nij", X - X.mean(0), X - X.mean(0)) / (len(X) - 1)
    cov = truth.covariance(t)
    scale = np.sqrt(np.einsum("nii,njj->nij", cov, cov))
    assert np.abs(emp - cov).max() / scale.max() < 0.05
    np.testing.assert_allclose(Q.mean(0), truth.mean_trajectory(t)[0], atol=0.01)


def test_sampling_is_deterministic_given_seed(truth):
    a = truth.sample(np.random.default_rng(5), 3, [0.2, 0.7])
    b = truth.sample(np.random.default_rng(5), 3, [0.2, 0.7])
    np.testing.assert_array_equal(a[0], b[0])
    c = truth.sample(np.random.default_rng(6), 3, [0.2, 0.7])
    assert not np.allclose(a[0], c[0])


def test_conditioned_samples_pass_near_via_point(truth):
    q_star = np.array([0.3, 0.2, 0.1])
    cond = truth.condition_on_joint(0.5, q_mean=q_star, q_cov=1e-4 * np.eye(3))
    Q, _ = cond.sample(np.random.default_rng(9), 4000, [0.5])
    np.testing.assert_allclose(Q[:, 0].mean(0), cond.mean_trajectory([0.5])[0][0], atol=2e-3)
    assert (Q[:, 0].std(0) < 0.011).all()


# ----------------------------------------------------------------------------- files
def test_save_load_round_trip(tmp_path, learned):
    promp, _ = learned
    promp = ProMP(promp.basis, promp.mu_w, promp.Sigma_w, promp.Sigma_y, promp.duration_s, promp.joint_names,
                  promp.robot_id, promp.duration_std_s, {"made_by": "test", "n_demos": 40})
    path = promp.save(tmp_path / "p.npz")
    back = ProMP.load(path, robot_id="toy", joint_names=("j0", "j1", "j2"), n_dims=3)
    for name in ("mu_w", "Sigma_w", "Sigma_y"):
        np.testing.assert_array_equal(getattr(back, name), getattr(promp, name))
    assert back.basis == promp.basis and back.duration_s == promp.duration_s
    assert back.joint_names == promp.joint_names and back.metadata == {"made_by": "test", "n_demos": 40}
    assert not list(tmp_path.glob("*.tmp*"))


def test_load_file_for_another_robot_raises(tmp_path, truth):
    path = truth.save(tmp_path / "toy.npz")
    with pytest.raises(ValueError, match=r"toy\.npz.*'robot_id' is 'toy' but 'barrett_wam' was expected"):
        ProMP.load(path, robot_id="barrett_wam")
    with pytest.raises(ValueError, match=r"toy\.npz.*'joint_names' lists 3 joints but 7 were expected"):
        ProMP.load(path, n_dims=7)
    with pytest.raises(ValueError, match=r"'joint_names' is \['j0', 'j1', 'j2'\]"):
        ProMP.load(path, joint_names=("a", "b", "c"))


def test_load_bad_files(tmp_path, truth):
    with pytest.raises(FileNotFoundError, match="missing.npz"):
        ProMP.load(tmp_path / "missing.npz")
    junk = tmp_path / "junk.npz"
    junk.write_text("not a zip")
    with pytest.raises(ValueError, match=r"ProMP file .*junk\.npz.* is not a readable \.npz archive"):
        ProMP.load(junk)
    partial = tmp_path / "partial.npz"
    np.savez(partial, format=np.array("rt2.promp"), mu_w=np.zeros(3))
    with pytest.raises(ValueError, match=r"partial\.npz: not a ProMP file, missing field"):
        ProMP.load(partial)
    path = truth.save(tmp_path / "ok.npz")
    data = dict(np.load(path))
    data["Sigma_w"] = data["Sigma_w"][:-1, :-1]
    np.savez(tmp_path / "cut.npz", **data)
    with pytest.raises(ValueError, match=r"cut\.npz: Sigma_w must have shape"):
        ProMP.load(tmp_path / "cut.npz")
    data = dict(np.load(path))
    data["version"] = np.array(99)
    np.savez(tmp_path / "future.npz", **data)
    with pytest.raises(ValueError, match=r"field 'version' is 99"):
        ProMP.load(tmp_path / "future.npz")
    with pytest.raises(ValueError, match=r"must end in \.npz"):
        truth.save(tmp_path / "p.yaml")


# ----------------------------------------------------------------------------- bad input
def _good(n=3, T=40, D=3):
    t = np.linspace(0, 1, T)
    return [np.sin(np.outer(t, np.arange(1, D + 1)) + i) for i in range(n)], [t.copy() for _ in range(n)]


@pytest.mark.parametrize("mutate, match", [
    (lambda q, t: (q[:1] + [q[1][:, :2]] + q[2:], t), r"demos\[1\] must have shape \(N, 3\), got shape \(40, 2\)"),
    (lambda q, t: ([q[0].ravel()] + q[1:], t), r"demos\[0\] must have shape \(N, N\)"),
    (lambda q, t: (q[:2] + [np.where(np.arange(40)[:, None] == 7, np.nan, q[2])], t), r"demos\[2\] must not contain NaN or inf; found nan at index \(7, 0\)"),
    (lambda q, t: ([np.full_like(q[0], np.inf)] + q[1:], t), r"demos\[0\] must not contain NaN or inf; found inf"),
    (lambda q, t: (q, t[:2] + [t[2][:-1]]), r"times\[2\] has 39 samples but demos\[2\] has 40"),
    (lambda q, t: (q, [t[0][::-1]] + t[1:]), r"times\[0\] must be strictly increasing"),
    (lambda q, t: ([x[:5] for x in q], [x[:5] for x in t]), r"demos\[0\] has too few samples: 5 < 8"),
    (lambda q, t: (q, t[:2]), r"got 3 demos but 2 time arrays"),
    (lambda q, t: (q[:1], t[:1]), r"at least 2 demonstrations"),
    (lambda q, t: ([], []), r"no demonstrations"),
    (lambda q, t: ([np.array([["a"] * 3] * 40)] + q[1:], t), r"demos\[0\] must be numeric"),
])
def test_bad_demos_raise(mutate, match):
    q, t = _good()
    q, t = mutate(q, t)
    with pytest.raises(ValueError, match=match):
        ProMP.learn(q, t, n_basis=8)


def test_bad_learning_options_raise():
    q, t = _good()
    with pytest.raises(ValueError, match=r"unknown prior scale 'full'; valid: \['diag', 'joint_iso'\]"):
        NIWPrior(scale="full")
    with pytest.raises(ValueError, match="n_basis must be an integer >= 2"):
        ProMP.learn(q, t, n_basis=1)
    with pytest.raises(ValueError, match="max_iter must be a positive integer"):
        ProMP.learn(q, t, max_iter=0)
    with pytest.raises(ValueError, match=r"demos\[0\] must have shape \(N, 7\)"):
        ProMP.learn(q, t, n_basis=8, joint_names=tuple("abcdefg"))
    with pytest.raises(ValueError, match="prior must be an NIWPrior"):
        ProMP.learn(q, t, n_basis=8, prior="map")


def test_bad_evaluation_and_conditioning_input_raises(truth):
    with pytest.raises(ValueError, match=r"t_s / duration_s .* must lie in \[0, 1\]"):
        truth.mean_trajectory([0.5, 1.5])
    with pytest.raises(ValueError, match="exactly one of t_s and phase"):
        truth.mean_trajectory([0.5], phase=[0.5])
    with pytest.raises(ValueError, match="duration_s must be finite and > 0"):
        truth.with_duration(-1.0)
    with pytest.raises(ValueError, match="rng must be a numpy.random.Generator"):
        truth.sample(np.random.RandomState(0), 2, [0.5])
    with pytest.raises(ValueError, match=r"q_mean must have shape \(3,\), got shape \(7,\)"):
        truth.condition_on_joint(0.5, q_mean=np.zeros(7))
    with pytest.raises(ValueError, match="q_cov must be symmetric"):
        truth.condition_on_joint(0.5, q_mean=np.zeros(3), q_cov=np.triu(np.ones((3, 3))))
    with pytest.raises(ValueError, match="give q_mean and/or qd_mean"):
        truth.condition_on_joint(0.5)
    with pytest.raises(ValueError, match="t_s must be one time"):
        truth.condition_on_joint([0.5, 0.6], q_mean=np.zeros(3))
    with pytest.raises(ValueError, match=r"jacobian\(q\) must have shape \(2, 3\)"):
        truth.condition_on_task(0.5, np.zeros(2), None, _fk, lambda q: np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"fk\(q\) returns 2 values but x_target has 3"):
        truth.condition_on_task(0.5, np.zeros(3), None, _fk, _jac)
    with pytest.raises(ValueError, match="x_target must not contain NaN or inf"):
        truth.condition_on_task(0.5, [np.nan, 0.0], None, _fk, _jac)


def test_bad_constructor_input_raises(truth):
    with pytest.raises(ValueError, match="Sigma_w must be positive semi-definite"):
        ProMP(truth.basis, truth.mu_w, -np.eye(truth.n_weights), truth.Sigma_y)
    with pytest.raises(ValueError, match="mu_w must have n_dims \\* 8 entries"):
        ProMP(truth.basis, np.zeros(10), np.eye(10), np.eye(1))
    with pytest.raises(ValueError, match="joint_names has 2 names but the weights describe 3 joints"):
        ProMP(truth.basis, truth.mu_w, truth.Sigma_w, truth.Sigma_y, joint_names=("a", "b"))
