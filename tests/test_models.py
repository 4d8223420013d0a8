"""Models from python-control StateSpace objects, and the measurement noise registry.

- a continuous StateSpace is discretised with its noise exactly as a scenario's matrices are (the
  same A, B, F), against python-control's own zero-order hold and a quadrature of the noise
  integral; a discrete one is used as it is;
- a linear robot given by a StateSpace builds the same model as the scenario's integrators;
- each noise form is its closed form; a form without a compiled twin (a user's callable, a
  registered form of one's own) runs on the numpy engine, and the estimate stage says so.
"""

from __future__ import annotations

from pathlib import Path

import control
import numpy as np
import pytest
import scipy.integrate
import scipy.linalg

from firmtool.estimation import compiled as kernels
from firmtool.errors import InputError, ScenarioError
from firmtool.models import noise
from firmtool.models.linear import discretize, discretize_statespace, from_statespace, noise_factor
from firmtool.problem import build_problem
from firmtool.robots import register
from firmtool.robots.point import PointRobot
from firmtool.scenario import parse_scenario
from firmtool.util.schema import Field

ROOT = Path(__file__).resolve().parents[1]
POINT = (ROOT / "scenarios" / "point_lightdark.toml").read_text()
DT = 0.1


def _double_integrator(d: int = 2):
    Z, I = np.zeros((d, d)), np.eye(d)
    A, B = np.block([[Z, I], [Z, Z]]), np.vstack([Z, I])
    return A, B, np.hstack([I, Z])


def test_continuous_statespace_is_discretised_exactly_with_its_noise():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(3, 3)) - 2 * np.eye(3)
    B, G = rng.normal(size=(3, 2)), rng.normal(size=(3, 2))
    Q = np.array([[0.3, 0.1], [0.1, 0.2]])
    sys = control.ss(A, B, np.eye(3), 0)
    Ad, Bd, F, dt = discretize_statespace(sys, G, Q, dt=0.2)
    assert dt == 0.2
    zoh = control.c2d(sys, 0.2, method="zoh")  # python-control's own hold
    np.testing.assert_allclose(Ad, zoh.A, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(Bd, zoh.B, rtol=1e-12, atol=1e-14)
    # the noise covariance: int_0^dt e^(A s) G Q G' e^(A' s) ds by quadrature
    Qd, _ = scipy.integrate.quad_vec(lambda s: scipy.linalg.expm(A * s) @ G @ Q @ G.T @ scipy.linalg.expm(A.T * s),
                                     0.0, 0.2, epsabs=1e-14, epsrel=1e-12)
    np.testing.assert_allclose(F @ F.T, Qd, rtol=1e-9, atol=1e-14)
    # the same numbers as a scenario's continuous matrices (models/linear.discretize)
    A2, B2, Qd2 = discretize(A, B, G, Q, 0.2)
    assert np.array_equal(Ad, A2) and np.array_equal(Bd, B2) and np.array_equal(F, noise_factor(Qd2))


def test_discrete_statespace_is_used_as_it_is():
    A, B, C = _double_integrator(1)
    Ad = np.eye(2) + DT * A
    sys = control.ss(Ad, B * DT, C, 0, DT)
    G, Q = np.array([[0.0], [1.0]]), np.array([[0.04]])
    m = from_statespace(sys, G, Q, noise=noise.ConstantNoise(0.1))
    assert m.dt == DT and np.array_equal(m.A, Ad) and np.array_equal(m.B, B * DT) and np.array_equal(m.H, C)
    np.testing.assert_allclose(m.F @ m.F.T, G @ Q @ G.T, atol=1e-15)
    with pytest.raises(InputError, match="dt: the discrete system's step is 0.1"):
        from_statespace(sys, G, Q, noise=noise.ConstantNoise(0.1), dt=0.2)


@pytest.mark.parametrize("make, match", [
    (lambda: discretize_statespace(control.ss(*_double_integrator(1), 0), np.eye(2), np.eye(2)), "needs the step dt"),
    (lambda: discretize_statespace(control.ss(*_double_integrator(1), [[1.0]]), np.eye(2), np.eye(2), 0.1), "D = 0"),
    (lambda: discretize_statespace(control.ss(*_double_integrator(1), 0), np.eye(3), np.eye(3), 0.1), r"G: expected shape \(2, n\)"),
    (lambda: discretize_statespace(control.ss(*_double_integrator(1), 0), np.eye(2), -np.eye(2), 0.1), "positive semi-definite"),
    (lambda: discretize_statespace(np.eye(2), np.eye(2), np.eye(2), 0.1), "control.StateSpace"),
])
def test_statespace_errors_name_what_is_wrong(make, match):
    with pytest.raises(InputError, match=match):
        make()


class StateSpacePoint(PointRobot):
    """The point robot of point_lightdark with its dynamics given as a continuous StateSpace."""

    def statespace(self):
        A, B, C = _double_integrator(2)
        q = self.scenario.model.process_noise_std
        return control.ss(A, B, C, 0), B, q**2 * np.eye(2)


def test_a_robot_given_by_a_statespace_builds_the_scenarios_model():
    register("test_ss_point", StateSpacePoint, replace=True)
    ref = build_problem(parse_scenario(POINT, "p.toml"))
    mine = build_problem(parse_scenario(POINT.replace('robot = "point"', 'robot = "test_ss_point"'), "p.toml"))
    for name in ("A", "B", "F", "H"):
        assert np.array_equal(getattr(mine.model, name), getattr(ref.model, name)), name
    assert mine.model.dt == ref.model.dt
    assert not mine.robot.nominals_are_straight()  # a StateSpace robot checks its nominals' states
    assert kernels.supports(mine) is not None  # a subclass opts in to the compiled kinematics itself


class DeafPoint(PointRobot):
    """A StateSpace whose second axis has no input: (A, B) is not stabilisable."""

    def statespace(self):
        A, B, C = _double_integrator(2)
        return control.ss(A, B[:, :1], C, 0), B, 0.01 * np.eye(2)


def test_a_statespace_robots_model_errors_name_the_robot():
    register("test_deaf_point", DeafPoint, replace=True)
    with pytest.raises(ScenarioError, match=r"model\.robot \(DeafPoint\.statespace\): \(A, B\) is not stabilisable"):
        build_problem(parse_scenario(POINT.replace('robot = "point"', 'robot = "test_deaf_point"'), "p.toml"))


@pytest.mark.parametrize("form, params, law", [
    ("lightdark_std", dict(light_x=1.5, eta=0.2, sigma_b=0.01), lambda d: (0.2 * abs(d) + 0.01) ** 2),
    ("lightdark_variance", dict(light_x=1.5, a=0.3, c=0.02), lambda d: 0.3 * d * d + 0.02),
    ("constant", dict(std=0.4), lambda d: 0.16 + 0.0 * d),
])
def test_noise_forms_are_their_closed_forms(form, params, law):
    model = noise.make(form, **params, unused=1.0)  # the former LightDarkNoise call form
    s = np.linspace(-3.0, 4.0, 29).reshape(-1, 1)
    np.testing.assert_allclose(model.variance(s), law(s - 1.5), rtol=1e-14)
    assert model.form == form and model.compiled in kernels.NOISE_FORMS
    assert set(model.compiled_params()) == {f.name for f in type(model).fields}


class Quartic(noise.NoiseModel):
    """A form of one's own: var = k (s - light_x)^4 + c, no compiled twin."""

    form = "test_quartic"
    fields = (Field("light_x", "number", doc="light line"), Field("k", "number", bound="positive", doc="growth"),
              Field("c", "number", bound="positive", doc="floor"))

    def __init__(self, light_x: float, k: float, c: float) -> None:
        self.light_x, self.k, self.c = light_x, k, c

    def variance(self, sensing):
        return self.k * (np.asarray(sensing) - self.light_x) ** 4 + self.c


def test_a_registered_noise_form_is_read_from_scenarios_and_runs_on_numpy(monkeypatch):
    noise.register("test_quartic", Quartic)
    text = POINT.replace('noise = "lightdark_variance"', 'noise = "test_quartic"').replace("a = 0.004", "k = 1e-5")
    problem = build_problem(parse_scenario(text, "q.toml"))
    assert isinstance(problem.model.noise, Quartic) and problem.model.noise.k == 1e-5
    monkeypatch.delenv(kernels.ENGINE_ENV, raising=False)
    engine, notice = kernels.engine_choice(problem)
    assert engine == "numpy" and "measurement noise 'test_quartic' is not compiled" in notice
    with pytest.raises(ScenarioError, match=r"measurement\.a: unknown field"):
        parse_scenario(text.replace("k = 1e-5", "k = 1e-5\na = 0.1"), "q.toml")
    with pytest.raises(ScenarioError, match=r"measurement\.noise: expected one of .*test_quartic"):
        parse_scenario(text.replace('noise = "test_quartic"', 'noise = "quartic"'), "q.toml")


def test_linear_and_unicycle_models_are_models():
    from firmtool.models.base import Model

    for name in ("point_lightdark", "unicycle_lightdark", "arm8_lightdark"):
        problem = build_problem(parse_scenario((ROOT / "scenarios" / f"{name}.toml").read_text(), f"{name}.toml"))
        assert isinstance(problem.model, Model), name
        X = problem.state_of(problem.config_lo[None] + 0.3 * (problem.config_hi - problem.config_lo))
        assert problem.model.measurement_variance(X).shape == (1, problem.model.nz)


def test_a_callable_noise_is_never_compiled():
    law = noise.CallableNoise(lambda s: 0.01 + 0.001 * s**2)
    np.testing.assert_allclose(law.variance(np.array([[1.0, 2.0]])), [[0.011, 0.014]])
    assert law.compiled is None
    with pytest.raises(InputError, match="shape"):
        noise.CallableNoise(lambda s: np.zeros(3)).variance(np.zeros((2, 2)))
    problem = build_problem(parse_scenario(POINT, "p.toml"))
    import dataclasses

    swapped = dataclasses.replace(problem, model=dataclasses.replace(problem.model, noise=law))
    assert "is not compiled" in kernels.supports(swapped)
