"""Controllers and filters against independent solutions (scipy, python-control, closed forms)."""

import control
import numpy as np
import pytest
import scipy.linalg

from firmtool.control.gains import kalman_update, lqr_gain, stationary_kalman
from firmtool.control.local import plan_local_controller
from firmtool.control.stabilisers import design_node, equilibrium_input, estimate_spread
from firmtool.control.trajectories import min_energy_trajectory
from firmtool.errors import NumericalError
from firmtool.models.linear import LightDarkNoise, LinearGaussianModel, discretize, noise_factor

DT = 0.1


def double_integrator(d=2, q=0.04):
    Ac = np.block([[np.zeros((d, d)), np.eye(d)], [np.zeros((d, d)), np.zeros((d, d))]])
    Bc = np.vstack([np.zeros((d, d)), np.eye(d)])
    return discretize(Ac, Bc, Bc, q * np.eye(d), DT)


def test_discretize_double_integrator_matches_closed_form():
    q = 0.3
    A, B, Qd = double_integrator(d=1, q=q)
    np.testing.assert_allclose(A, [[1, DT], [0, 1]], atol=1e-14)
    np.testing.assert_allclose(B, [[DT**2 / 2], [DT]], atol=1e-14)
    np.testing.assert_allclose(Qd, q * np.array([[DT**3 / 3, DT**2 / 2], [DT**2 / 2, DT]]), rtol=1e-10)


def test_noise_factor_reproduces_covariance_and_drops_null_space():
    A, B, Qd = double_integrator()
    F = noise_factor(Qd)
    np.testing.assert_allclose(F @ F.T, Qd, atol=1e-15)
    F2 = noise_factor(np.diag([1.0, 0.0]))
    assert F2.shape == (2, 1)


def test_lqr_gain_matches_python_control():
    A, B, _ = double_integrator()
    Wx, Wu = np.diag([1.0, 2.0, 0.1, 0.1]), 0.3 * np.eye(2)
    K, S = lqr_gain(A, B, Wx, Wu)
    K_ref, S_ref, _ = control.dlqr(A, B, Wx, Wu)
    np.testing.assert_allclose(K, K_ref, rtol=1e-8)
    np.testing.assert_allclose(S, S_ref, rtol=1e-8)


def test_lqr_gain_rejects_uncontrollable_unstable_pair():
    A = np.diag([1.2, 0.5])
    B = np.array([[0.0], [1.0]])  # the unstable mode is not reachable
    with pytest.raises(NumericalError, match="stabilis"):
        lqr_gain(A, B, np.eye(2), np.eye(1))


def test_stationary_kalman_is_update_form_of_the_riccati_solution():
    A, B, Qd = double_integrator()
    H = np.hstack([np.eye(2), np.zeros((2, 2))])
    R = np.diag([0.05, 0.2])
    L, P_post, P_prior = stationary_kalman(A, Qd, H, R)
    P_ref = scipy.linalg.solve_discrete_are(A.T, H.T, Qd, R)
    np.testing.assert_allclose(P_prior, P_ref, rtol=1e-9)
    S = H @ P_ref @ H.T + R
    np.testing.assert_allclose(P_post, P_ref - P_ref @ H.T @ np.linalg.solve(S, H @ P_ref), rtol=1e-8, atol=1e-14)
    # P_post is a fixed point of predict + update.
    _, P_next = kalman_update(A @ P_post @ A.T + Qd, H, R)
    np.testing.assert_allclose(P_next, P_post, rtol=1e-8, atol=1e-14)
    # python-control's dlqe is the predictor form: its gain is A L, its covariance the prior (the trap).
    L_pred, P_dlqe, _ = control.dlqe(A, np.eye(4), H, Qd, R)
    np.testing.assert_allclose(P_dlqe, P_prior, rtol=1e-7)
    np.testing.assert_allclose(L_pred, A @ L, rtol=1e-7)
    assert not np.allclose(L_pred, L)


def test_stationary_kalman_rejects_undetectable_pair():
    A = np.diag([1.1, 1.0])
    H = np.array([[0.0, 1.0]])  # the unstable first state is never seen
    with pytest.raises(NumericalError, match="detectable"):
        stationary_kalman(A, 0.01 * np.eye(2), H, np.eye(1))


def test_estimate_spread_solves_its_lyapunov_equation_and_matches_simulation():
    A, B, Qd = double_integrator(d=1, q=0.5)
    K, _ = lqr_gain(A, B, np.eye(2), np.eye(1))
    Sigma = estimate_spread(A, B, K, Qd)
    Acl = A - B @ K
    np.testing.assert_allclose(Acl @ Sigma @ Acl.T + Qd, Sigma, rtol=1e-10)
    rng = np.random.default_rng(0)
    F = noise_factor(Qd)
    x = np.zeros((20000, 2))
    for _ in range(300):
        x = x @ Acl.T + rng.standard_normal((20000, F.shape[1])) @ F.T
    # sampling error of a covariance entry ~ Sigma * sqrt(2 / 20000) ~ 0.0017: 6 standard errors
    np.testing.assert_allclose(np.cov(x.T), Sigma, atol=0.01)


def test_min_energy_trajectory_is_exact_and_rest_to_rest():
    A, B, _ = double_integrator()
    x0, xf = np.array([0.0, 0.0, 0, 0]), np.array([1.0, -2.0, 0, 0])
    x, u = min_energy_trajectory(A, B, x0, xf, 40)
    np.testing.assert_allclose(x[-1], xf, atol=1e-9)
    assert u.shape == (40, 2)
    # Single integrator: constant velocity.
    x, u = min_energy_trajectory(np.eye(2), DT * np.eye(2), np.zeros(2), np.array([1.0, 2.0]), 10)
    np.testing.assert_allclose(u, np.tile([1.0, 2.0], (10, 1)), rtol=1e-9)


def test_equilibrium_input_refuses_moving_state():
    A, B, _ = double_integrator(d=1)
    np.testing.assert_allclose(equilibrium_input(A, B, np.array([3.0, 0.0])), [0.0], atol=1e-12)
    with pytest.raises(NumericalError, match="equilibrium"):
        equilibrium_input(A, B, np.array([3.0, 1.0]))


def _model(noise):
    A, B, Qd = double_integrator()
    H = np.hstack([np.eye(2), np.zeros((2, 2))])
    return LinearGaussianModel(A=A, B=B, F=noise_factor(Qd), H=H, noise=noise,
                               sensing_x=lambda X: np.repeat(X[:, :1], 2, axis=1), dt=DT)


def test_local_controller_converges_to_target_node_and_reproduces_stationary_gain():
    model = _model(LightDarkNoise("lightdark_variance", light_x=5.0, a=0.05, c=1e-3))
    Wx, Wu = np.diag([1.0, 1.0, 0.1, 0.1]), 0.1 * np.eye(2)
    src = design_node(model, np.array([0.0, 0.0, 0, 0]), Wx, Wu, perfect=False)
    dst = design_node(model, np.array([4.0, 1.0, 0, 0]), Wx, Wu, perfect=False)
    x, u = min_energy_trajectory(model.A, model.B, src.center, dst.center, 50)
    lc = plan_local_controller(model, x, u, src.P, dst, Wx, Wu, 400, perfect=False)
    assert lc.steps == 450 and lc.edge_steps == 50
    np.testing.assert_allclose(lc.P[0], src.P)
    np.testing.assert_allclose(lc.P[-1], dst.P, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(lc.K, np.broadcast_to(dst.K, lc.K.shape), rtol=1e-6)  # LTI: TV-LQR = SLQR
    # Light-dark design: the node near the light (x=4) is better localised than the one at x=0.
    assert np.trace(dst.P) < np.trace(src.P)


def _edge(perfect=False, steps=50, stab=400):
    model = _model(LightDarkNoise("lightdark_variance", light_x=5.0, a=0.05, c=1e-3))
    Wx, Wu = np.diag([1.0, 1.0, 0.1, 0.1]), 0.1 * np.eye(2)
    src = design_node(model, np.array([0.0, 0.0, 0, 0]), Wx, Wu, perfect=perfect)
    dst = design_node(model, np.array([4.0, 1.0, 0, 0]), Wx, Wu, perfect=perfect)
    x, u = min_energy_trajectory(model.A, model.B, src.center, dst.center, steps)
    return model, x, u, src, dst, Wx, Wu, stab


@pytest.mark.parametrize("perfect", [False, True])
def test_local_controller_lazy_recursion_equals_full_one(perfect):
    model, x, u, src, dst, Wx, Wu, stab = _edge(perfect)
    full = plan_local_controller(model, x, u, src.P, dst, Wx, Wu, stab, perfect)
    L, P, spread = full.L.copy(), full.P.copy(), full.spread.copy()  # attribute access runs it to the end
    lazy = plan_local_controller(model, x, u, src.P, dst, Wx, Wu, stab, perfect)
    h = lazy.head(7)  # in pieces: 7, 58, then the rest
    assert h.steps == 7 and h.P.shape[0] == 8 and h.spread.shape[0] == 8
    L58, P58 = lazy.compute(58)
    assert lazy._forward is not None and lazy._forward.done == 58  # not run further than asked
    np.testing.assert_array_equal(P58[:59], P[:59])
    np.testing.assert_array_equal(L58[:58], L[:58])
    # bit for bit the same: the same steps in the same order, however it is split
    np.testing.assert_array_equal(lazy.P, P)
    np.testing.assert_array_equal(lazy.L, L)
    np.testing.assert_array_equal(lazy.spread, spread)
    np.testing.assert_array_equal(h.P, P[:8])
    if perfect:
        assert lazy.innovation_cov is None
    else:
        np.testing.assert_array_equal(lazy.innovation_cov, full.innovation_cov)


@pytest.mark.parametrize("terminal", ["stationary", "far"])
def test_backward_recursion_shortcut_matches_full_recursion(monkeypatch, terminal):
    """Stopping the backward Riccati recursion once S is stationary (BACKWARD_RTOL) gives the gains
    of the full recursion within 1e-9 relative: from the stationary terminal cost (stops at once) and
    from a far one (converges along a long edge first)."""
    import dataclasses

    from firmtool.control import local

    model, x, u, src, dst, Wx, Wu, _ = _edge(steps=300, stab=20)
    if terminal == "far":
        dst = dataclasses.replace(dst, S=100.0 * np.eye(4))
    short = plan_local_controller(model, x, u, src.P, dst, Wx, Wu, 20, False)
    monkeypatch.setattr(local, "BACKWARD_RTOL", -1.0)  # never stationary: the full recursion
    full = plan_local_controller(model, x, u, src.P, dst, Wx, Wu, 20, False)
    assert not np.array_equal(full.K[:300], np.broadcast_to(full.K[299], (300, 2, 4)))  # varies in the last bits
    np.testing.assert_allclose(short.K, full.K, rtol=0, atol=1e-9 * np.abs(full.K).max())
    np.testing.assert_allclose(short.P, full.P, rtol=0, atol=1e-9 * np.abs(full.P).max())
    np.testing.assert_allclose(short.spread, full.spread, rtol=0, atol=1e-9 * np.abs(full.spread).max())
    if terminal == "far":  # the far terminal cost shapes the last gains: the shortcut kept them
        assert np.abs(full.K[-21] - dst.K).max() > 1e-3 * np.abs(dst.K).max()
        stopped = np.flatnonzero((short.K != full.K).any(axis=(1, 2)))
        assert 0 < stopped.size and stopped.max() < 250  # the shortcut took over after some 50+ steps
        np.testing.assert_array_equal(short.K[250:], full.K[250:])


def test_min_energy_trajectory_memo_gives_the_fresh_result():
    from firmtool.control import trajectories

    A, B, _ = double_integrator()
    x0, xf = np.array([0.0, 0.0, 0, 0]), np.array([1.0, -2.0, 0, 0])
    trajectories._reachability_cache.clear()
    x1, u1 = min_energy_trajectory(A, B, x0, xf, 40)
    x2, u2 = min_energy_trajectory(A.copy(), B.copy(), x0, 2 * xf, 40)  # hit: keyed by value
    assert len(trajectories._reachability_cache) == 1
    trajectories._reachability_cache.clear()
    x3, u3 = min_energy_trajectory(A, B, x0, 2 * xf, 40)
    np.testing.assert_array_equal(x2, x3)
    np.testing.assert_array_equal(u2, u3)
    np.testing.assert_allclose(x1[-1], xf, atol=1e-9)


def test_filter_recursion_reports_an_innovation_covariance_that_is_not_positive_definite():
    """A numerical fault in the compiled filter recursion is reported as such, not as NaNs."""
    from firmtool.control.recursions import filter_recursion
    from firmtool.errors import NumericalError

    n, nz, T = 2, 1, 3
    L, P, innovation = np.zeros((T, n, nz)), np.zeros((T + 1, n, n)), np.zeros((T, nz, nz))
    P[0] = 0.1 * np.eye(n)
    args = (np.eye(n)[None], np.array([[[1.0, 0.0]]]), np.zeros(T, dtype=np.int64))
    filter_recursion(*args, np.full((T, nz), 0.5), 0.01 * np.eye(n), L, P, innovation, 0, T)
    assert np.all(np.isfinite(P)) and np.all(np.linalg.eigvalsh(P[1:]) > 0)
    with pytest.raises(NumericalError, match="not positive definite"):  # R < 0: S = P- + R < 0
        filter_recursion(*args, np.full((T, nz), -10.0), 0.01 * np.eye(n), L, P, innovation, 0, T)


def test_cholesky_solve_gives_the_textbook_column_loop_bit_for_bit():
    """The compiled solve runs its substitutions with the columns inside (to vectorise); each entry
    must still be the column-by-column loop's value, subtraction for subtraction."""
    from firmtool.control.linalg import cholesky_solve

    rng = np.random.default_rng(5)
    for q, nc in ((1, 3), (4, 7), (8, 16)):
        M = rng.standard_normal((q, q))
        S = M @ M.T + q * np.eye(q)
        B = rng.standard_normal((q, nc))
        C, out = np.zeros((q, q)), np.zeros((q, nc))
        assert cholesky_solve(S, B, C, out)
        ref = np.zeros((q, nc))
        for c in range(nc):
            for i in range(q):
                s = B[i, c]
                for j in range(i):
                    s -= C[i, j] * ref[j, c]
                ref[i, c] = s / C[i, i]
            for i in range(q - 1, -1, -1):
                s = ref[i, c]
                for j in range(i + 1, q):
                    s -= C[j, i] * ref[j, c]
                ref[i, c] = s / C[i, i]
        np.testing.assert_array_equal(out, ref)
        np.testing.assert_allclose(out, np.linalg.solve(S, B), rtol=1e-10)


def test_min_energy_trajectories_equal_the_single_edge_ones():
    from firmtool.control.trajectories import min_energy_trajectories

    A, B, _ = double_integrator()
    rng = np.random.default_rng(2)
    x0 = np.hstack([rng.uniform(-3, 3, (9, 2)), np.zeros((9, 2))])
    xf = np.hstack([rng.uniform(-3, 3, (9, 2)), np.zeros((9, 2))])
    for steps in (3, 17, 60):
        x, u = min_energy_trajectories(A, B, x0, xf, steps)
        for e in range(9):
            xs, us = min_energy_trajectory(A, B, x0[e], xf[e], steps)
            np.testing.assert_array_equal(x[e], xs)
            np.testing.assert_array_equal(u[e], us)


_LC_ARRAYS = ("x_ref", "u_ref", "K", "L", "P", "innovation_cov", "spread")


def _assert_same_controller(a, b) -> None:
    assert a.edge_steps == b.edge_steps and a.steps == b.steps
    for name in _LC_ARRAYS:
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert x.shape == y.shape and np.array_equal(x, y), name


@pytest.mark.parametrize("scenario", ["arm", "point_perfect", "unicycle_perfect", "smoke"])
def test_batched_local_controllers_equal_the_single_edge_ones(scenario):
    """design.local_controllers (the estimate stage's batched design) gives every edge the controller
    local_controller designs for it alone, bit for bit: the batched path (linear models, stationary
    stabilisers: the arm with light-dark sensing, the point robot perfect and imperfect) and the
    per-edge fallback (the unicycle's periodic stabilisers); with the filter's first segment run in
    the batch or not, and whatever the batch's size and order."""
    import re
    from pathlib import Path

    from firmtool.problem import build_problem
    from firmtool.roadmap.design import design, local_controller, local_controllers
    from firmtool.roadmap.nodes import roadmap_nodes
    from firmtool.scenario import parse_scenario

    root = Path(__file__).resolve().parents[1] / "scenarios"
    text = (root / f"{'arm8_lightdark' if scenario == 'arm' else scenario}.toml").read_text()
    for key, value in (("nodes", 14), ("goal_nodes", 2), ("goal_bias", 0.3), ("bridge_nodes", 0), ("neighbors", 4)):
        text = re.sub(rf"(?m)^{key} = .*$", f"{key} = {value}", text)
    problem = build_problem(parse_scenario(text, "test.toml"))
    centers, kinds = roadmap_nodes(problem, np.random.default_rng(0))
    d = design(problem, centers, kinds)
    pairs = [(int(s), int(t)) for s, t in zip(d.edge_source, d.edge_target)][:40]
    assert len(pairs) >= 8
    reference = [local_controller(problem, d, s, t) for s, t in pairs]
    for past_edge, order in ((None, pairs), (8, pairs[::-1]), (0, pairs[3:9])):
        batch = local_controllers(problem, d, order, past_edge)
        if past_edge is not None and not problem.perfect:
            assert all(lc._forward.done >= min(lc.steps, lc.edge_steps + past_edge) for lc in batch)
        for (s, t), lc in zip(order, batch):
            _assert_same_controller(lc, reference[pairs.index((s, t))])
