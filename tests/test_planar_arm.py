"""Planar arm kinematics: forward kinematics, Jacobians vs. finite differences, tip IK."""

from __future__ import annotations

import numpy as np
import pytest

from firmtool.errors import InputError
from firmtool.geometry import make_backend
from firmtool.models.planar_arm import (
    inverse_kinematics_tip,
    joint_positions,
    joint_x_jacobian,
    link_segments,
    reach,
    tip_jacobian,
)

LL = np.array([1.0, 0.8, 0.6, 0.5])


def test_straight_arm():
    P = joint_positions(np.zeros(4), LL)
    np.testing.assert_allclose(P, [[0, 0], [1, 0], [1.8, 0], [2.4, 0], [2.9, 0]], atol=1e-15)
    P = joint_positions([np.pi / 2, 0, 0, 0], LL, base=(1.0, -2.0))
    np.testing.assert_allclose(P, [[1, -2], [1, -1], [1, -0.2], [1, 0.4], [1, 0.9]], atol=1e-15)


def test_right_angles():
    # relative angles: up, then right turn, then left turn, then fold back
    P = joint_positions([np.pi / 2, -np.pi / 2, np.pi / 2, np.pi], LL)
    np.testing.assert_allclose(P, [[0, 0], [0, 1], [0.8, 1], [0.8, 1.6], [0.8, 1.1]], atol=1e-15)


def test_vectorised_matches_single():
    rng = np.random.default_rng(0)
    th = rng.uniform(-np.pi, np.pi, (50, 4))
    P = joint_positions(th, LL, base=(0.3, 0.1))
    assert P.shape == (50, 5, 2)
    for m in range(0, 50, 7):
        np.testing.assert_allclose(P[m], joint_positions(th[m], LL, base=(0.3, 0.1)), atol=1e-15)
    S, E = link_segments(th, LL)
    np.testing.assert_allclose(np.linalg.norm(E - S, axis=-1), np.broadcast_to(LL, (50, 4)), atol=1e-12)
    np.testing.assert_array_equal(S[:, 1:], E[:, :-1])


def _fd(f, th, h=1e-6):
    cols = []
    for j in range(th.size):
        e = np.zeros(th.size)
        e[j] = h
        cols.append((f(th + e) - f(th - e)) / (2 * h))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("L", [1, 2, 3, 5, 8])
def test_jacobians_vs_central_differences(L):
    rng = np.random.default_rng(L)
    ll = rng.uniform(0.2, 1.5, L)
    base = rng.uniform(-1, 1, 2)
    for _ in range(20):
        th = rng.uniform(-np.pi, np.pi, L)
        J = tip_jacobian(th, ll, base)
        assert J.shape == (2, L)
        assert np.abs(J - _fd(lambda t: joint_positions(t, ll, base)[-1], th)).max() < 1e-6
        Jx = joint_x_jacobian(th, ll, base)
        assert Jx.shape == (L, L)
        assert np.abs(Jx - _fd(lambda t: joint_positions(t, ll, base)[:-1, 0], th)).max() < 1e-6
        assert np.all(Jx[0] == 0)  # joint 1 is the base


def test_jacobians_batch():
    rng = np.random.default_rng(3)
    th = rng.uniform(-np.pi, np.pi, (6, 4))
    J, Jx = tip_jacobian(th, LL), joint_x_jacobian(th, LL)
    assert J.shape == (6, 2, 4) and Jx.shape == (6, 4, 4)
    for m in range(6):
        np.testing.assert_allclose(J[m], tip_jacobian(th[m], LL), atol=1e-15)
        np.testing.assert_allclose(Jx[m], joint_x_jacobian(th[m], LL), atol=1e-15)


def test_ik_reaches_reachable_targets():
    rng = np.random.default_rng(5)
    inner, outer = reach(LL)
    base = np.array([0.5, -0.25])
    for i in range(40):
        rho = rng.uniform(inner + 0.05, outer - 0.05)
        phi = rng.uniform(-np.pi, np.pi)
        target = base + rho * np.array([np.cos(phi), np.sin(phi)])
        th0 = rng.uniform(-np.pi, np.pi, 4)
        sol = inverse_kinematics_tip(target, LL, th0, rng=i, base=base)
        assert sol is not None
        assert np.linalg.norm(joint_positions(sol, LL, base)[-1] - target) < 1e-6
        assert np.all(np.abs(sol - th0) <= np.pi + 1e-12)


def test_ik_out_of_reach_returns_none():
    assert inverse_kinematics_tip([3.0, 0.0], LL, np.zeros(4), rng=0) is None
    assert inverse_kinematics_tip([0.0, 2.91], LL, np.zeros(4), rng=0) is None
    # a long first link leaves a hole around the base
    ll = np.array([2.0, 0.5, 0.3])
    assert reach(ll) == pytest.approx((1.2, 2.8))
    assert inverse_kinematics_tip([0.5, 0.5], ll, np.zeros(3), rng=0) is None
    assert inverse_kinematics_tip([1.5, 0.5], ll, np.zeros(3), rng=0) is not None


def test_ik_validity():
    ll = np.array([1.0, 1.0])
    target = np.array([1.0, 1.0])  # two solutions: elbow (theta_2) at +pi/2 or -pi/2
    elbow_pos = lambda th: th[:, 1] > 0  # noqa: E731
    elbow_neg = lambda th: th[:, 1] < 0  # noqa: E731
    for valid, sign in ((elbow_pos, 1), (elbow_neg, -1)):
        sol = inverse_kinematics_tip(target, ll, np.array([0.3, -0.5 * sign]), validity=valid, rng=1)
        assert sol is not None and np.sign(sol[1]) == sign
        assert np.linalg.norm(joint_positions(sol, ll)[-1] - target) < 1e-6
    assert inverse_kinematics_tip(target, ll, np.zeros(2), validity=lambda th: np.zeros(len(th), bool),
                                  rng=1) is None


def test_ik_with_collision_validity():
    """The arm's links as capsules: IK must return a collision-free configuration."""
    ll = np.full(5, 0.5)
    backend = make_backend("numpy", np.array([[1.0, 0.6]]), np.array([[0.25, 0.25]]),
                           np.array([-3.0, -3.0]), np.array([3.0, 3.0]), self_collision=True)

    def valid(th):
        S, E = link_segments(th, ll)
        return ~backend.capsules_collide(S, E, 0.05)

    target = np.array([1.8, 0.4])
    sol = inverse_kinematics_tip(target, ll, np.zeros(5), validity=valid, rng=2, max_restarts=50)
    assert sol is not None and valid(sol[None])[0]
    assert np.linalg.norm(joint_positions(sol, ll)[-1] - target) < 1e-6


def test_input_errors():
    with pytest.raises(InputError):
        joint_positions(np.zeros(3), LL)
    with pytest.raises(InputError):
        joint_positions(np.zeros(4), [1.0, -1.0, 1.0, 1.0])
    with pytest.raises(InputError):
        tip_jacobian(np.zeros((2, 2, 4)), LL)
    with pytest.raises(InputError):
        joint_positions(np.zeros(4), LL, base=(0.0, 0.0, 0.0))
    with pytest.raises(InputError):
        inverse_kinematics_tip([1.0], LL, np.zeros(4))
    with pytest.raises(InputError):
        inverse_kinematics_tip([1.0, 0.0], LL, np.zeros((1, 4)))
