"""Robots with a linear Gaussian model: the shared part of the point robot and the arm, and the base
of a user's linear robot (e.g. one given as a python-control ``StateSpace``).

The dynamics come from the scenario (``[model] dynamics``: a single or double integrator per
configuration coordinate, or continuous ``A, B, G, Q`` matrices), each discretised exactly once
(:func:`firmtool.models.linear.discretize`), or from :meth:`LinearRobot.statespace` (a
python-control ``StateSpace``: continuous ones are discretised the same way, discrete ones used as
they are). A subclass says how many configuration coordinates it has (:meth:`LinearRobot.dof`).

The model is checked before any work (:meth:`LinearRobot.check`): ``(A, B)`` stabilisable and
controllable (node stabilisers and rest-to-rest nominals), configurations at rest equilibria,
``(A, H)`` detectable with process noise on every unstable mode (the stationary Kalman filter).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from firmtool.errors import InputError, ScenarioError
from firmtool.models.linear import LinearGaussianModel, discretize, discretize_statespace, noise_factor
from firmtool.robots.base import Robot
from firmtool.util.schema import INVALID, MAX_STATE_DIM, Errors, Field, shape_text, valid

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.problem import Problem
    from firmtool.scenario import Scenario

INTEGRATORS = ("single_integrator", "double_integrator")


class LinearRobot(Robot):
    """A robot whose model is linear (see the module docs). Subclasses define :meth:`dof` and
    :meth:`points`, and set :attr:`config_lo`, :attr:`config_hi` in ``__init__``."""

    model_fields: ClassVar[tuple[Field, ...]] = (
        Field("dynamics", "string", choices=(*INTEGRATORS, "matrices"),
              doc="an integrator per configuration coordinate, or continuous matrices A, B, G, Q"),
        Field("process_noise_std", "number", None, bound="nonnegative", unit="per sqrt(s)",
              doc="std of the white noise on each integrator's input (required unless dynamics = 'matrices')"),
        Field("A", "array", None, shape=(None, None), doc="continuous dynamics matrix (n, n) (dynamics = 'matrices')",
              example=[[0.0, 0.0], [0.0, 0.0]]),
        Field("B", "array", None, shape=(None, None), doc="continuous input matrix (n, m) (dynamics = 'matrices')",
              example=[[1.0, 0.0], [0.0, 1.0]]),
        Field("G", "array", None, shape=(None, None), doc="noise input matrix (n, r) (dynamics = 'matrices')",
              example=[[1.0, 0.0], [0.0, 1.0]]),
        Field("Q", "array", None, shape=(None, None), doc="noise intensity (r, r), symmetric PSD (dynamics = 'matrices')",
              example=[[0.0025, 0.0], [0.0, 0.0025]]),
    )

    @classmethod
    def read_model(cls, values: dict[str, Any], errors: Errors) -> dict[str, Any]:
        dynamics = values.get("dynamics", INVALID)
        if not valid(dynamics):
            return values
        matrices = ("A", "B", "G", "Q")
        if dynamics != "matrices":
            for key in matrices:
                if key in values and values[key] is not None and valid(values[key]):
                    errors.add(f"model.{key}", f"only read with dynamics = 'matrices' (found dynamics = {dynamics!r})")
            if "process_noise_std" in values and values["process_noise_std"] is None:
                errors.add("model.process_noise_std", "missing required field")
            return values
        if values.get("process_noise_std") is None:
            values["process_noise_std"] = 0.0
        for key in matrices:
            if values.get(key) is None:
                errors.add(f"model.{key}", "missing required field")
                values[key] = INVALID
        A = values["A"]
        if not valid(A):
            return values
        n = A.shape[0]
        if A.shape != (n, n) or n == 0:
            errors.add("model.A", f"expected a square matrix but found {A.shape}")
            return values
        if n > MAX_STATE_DIM:
            errors.add("model.A", f"expected at most {MAX_STATE_DIM} states, found {n}")
            return values
        for key in ("B", "G"):
            M = values[key]
            if not valid(M):
                continue
            if M.shape[0] != n:
                errors.add(f"model.{key}", f"expected shape {shape_text((n, None))} but found {M.shape}")
                values[key] = INVALID
            elif M.shape[1] == 0:
                errors.add(f"model.{key}", f"expected at least one column, found shape {M.shape}")
                values[key] = INVALID
        G, Q = values["G"], values["Q"]
        if valid(G, Q):
            r = G.shape[1]
            if Q.shape != (r, r):
                errors.add("model.Q", f"expected shape {shape_text((r, r))} but found {Q.shape}")
            else:
                problem = psd_problem(Q, strict=False)
                if problem:
                    errors.add("model.Q", problem)
        return values

    def __init__(self, scenario: "Scenario") -> None:
        super().__init__(scenario)
        A, B, F, H = self.linear_system()
        self.model = LinearGaussianModel(A=A, B=B, F=F, H=np.asarray(H, dtype=float), noise=self.noise(),
                                         sensing_x=self.sensing_x, dt=float(self.dt))

    # -- what a subclass says ------------------------------------------------------------------------

    def dof(self) -> int:
        """Number of configuration coordinates (integrator dynamics: one integrator per coordinate)."""
        raise NotImplementedError

    def statespace(self):
        """``(sys, G, Q)`` to give the dynamics as a python-control ``StateSpace`` (see
        :func:`firmtool.models.linear.discretize_statespace`; continuous: discretised over the
        scenario's ``model.dt``), or None (the default) for the scenario's ``[model] dynamics``.
        The configuration is then the first :meth:`dof` states; ``sys.C`` is the observation
        matrix unless the scenario gives ``measurement.H``."""
        return None

    def default_observation(self, n: int) -> np.ndarray:
        """The observation matrix when the scenario gives none: the configuration is measured."""
        d = self.config_dim
        return np.hstack([np.eye(d), np.zeros((d, n - d))])

    def check_observation(self, H: np.ndarray, n: int) -> None:
        """ScenarioError naming ``measurement.H`` if the scenario's ``H`` does not fit."""
        if H.shape[1] != n:
            raise ScenarioError(self.scenario.path, "measurement.H", f"expected shape (nz, {n}) but found {H.shape}")

    # -- the model -----------------------------------------------------------------------------------

    @property
    def dt(self) -> float:
        return self.scenario.model.dt

    def linear_system(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Discrete ``(A, B, F, H)`` (sets :attr:`config_dim`)."""
        sc = self.scenario
        d = self.dof()
        self.config_dim = d
        ss = self.statespace()
        if ss is not None:
            sys, G, Q = ss
            try:
                A, B, F, step = discretize_statespace(sys, G, Q, sc.model.dt)
            except InputError as exc:
                raise ScenarioError(sc.path, "model.robot", f"the robot's StateSpace: {exc}") from None
            if A.shape[0] < d:
                raise ScenarioError(sc.path, "model.robot", f"the robot's StateSpace has {A.shape[0]} states, "
                                                            f"fewer than its {d} configuration coordinates")
            H = sc.measurement.H if sc.measurement.H is not None else np.atleast_2d(np.asarray(sys.C, dtype=float))
        else:
            A, B, F = self._scenario_dynamics(d)
            H = sc.measurement.H
        n = A.shape[0]
        if H is None:
            H = self.default_observation(n)
        else:
            self.check_observation(np.atleast_2d(H), n)
        return A, B, F, H

    def _scenario_dynamics(self, d: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Continuous (A, B, G, Q) of ``[model]`` -> discrete (A, B, F)."""
        sc, spec = self.scenario, self.scenario.model
        if spec.dynamics == "single_integrator":
            Ac, Bc, Gc = np.zeros((d, d)), np.eye(d), np.eye(d)
            Qc = spec.process_noise_std**2 * np.eye(d)
        elif spec.dynamics == "double_integrator":
            Ac = np.block([[np.zeros((d, d)), np.eye(d)], [np.zeros((d, d)), np.zeros((d, d))]])
            Bc = Gc = np.vstack([np.zeros((d, d)), np.eye(d)])
            Qc = spec.process_noise_std**2 * np.eye(d)
        else:
            Ac, Bc, Gc, Qc = spec.A, spec.B, spec.G, spec.Q
            if Ac.shape[0] < d:
                raise ScenarioError(sc.path, "model.A", f"expected at least {d} states for this robot's "
                                                        f"{d} configuration coordinates")
        try:
            with np.errstate(all="ignore"):
                A, B, Qd = discretize(Ac, Bc, Gc, Qc, spec.dt)
                F = noise_factor(Qd) if np.all(np.isfinite(Qd)) else Qd
        except (np.linalg.LinAlgError, ValueError, ArithmeticError):
            A = B = F = np.full((1, 1), np.nan)
        if not all(np.all(np.isfinite(M)) for M in (A, B, F)):
            raise ScenarioError(sc.path, "model.dt", f"expected a step over which the dynamics stay finite "
                                                     f"(discretising over dt = {spec.dt:g} overflows)")
        return A, B, F

    def nominals_are_straight(self) -> bool:
        # Integrators move every coordinate on the same rest-to-rest profile, so their nominal is the
        # straight configuration segment; other linear models' nominals may bend.
        return self.statespace() is None and self.scenario.model.dynamics in INTEGRATORS

    def check(self, problem: "Problem") -> None:
        if self.statespace() is not None:  # the matrices are the robot's code, not scenario keys
            where = f"model.robot ({type(self).__name__}.statespace)"
            check_linear_model(problem, dynamics_field=where, equilibrium_field=where, noise_field=where)
            return
        check_linear_model(problem, noise_field="model.G/Q" if self.scenario.model.params.get("dynamics") == "matrices"
                           else "model.process_noise_std")


def psd_problem(M: np.ndarray, strict: bool) -> str | None:
    """None if ``M`` is symmetric positive (semi-)definite, else what was expected."""
    if not np.allclose(M, M.T, atol=1e-12 * max(1.0, np.abs(M).max())):
        return "expected a symmetric matrix"
    w = np.linalg.eigvalsh(M)
    if (strict and w.min() <= 0) or w.min() < -1e-12 * max(1.0, np.abs(w).max()):
        kind = "positive definite" if strict else "positive semi-definite"
        return f"expected a {kind} matrix (smallest eigenvalue {w.min():.3g})"
    return None


def _uncontrollable_modes(A: np.ndarray, C: np.ndarray, unstable_only: bool) -> list[complex]:
    """Eigenvalues of A (all, or those with |lambda| >= 1) that fail the PBH rank test with C:
    rank [A - lambda I, C] < n (for observability pass A' and H')."""
    n = A.shape[0]
    bad = []
    if C.size and np.abs(C).max() > 0:
        C = C / np.abs(C).max()  # the rank of [A - lambda I, C] does not depend on C's scale
    scale = max(1.0, float(np.abs(A).max()))
    for lam in np.linalg.eigvals(A):
        if unstable_only and abs(lam) < 1 - 1e-9:
            continue
        M = np.hstack([A - lam * np.eye(n), C])
        s = np.linalg.svd(M, compute_uv=False)
        if s.size < n or s[n - 1] <= 1e-9 * scale:
            bad.append(complex(lam))
    return bad


def check_linear_model(problem: "Problem", noise_field: str = "model.process_noise_std",
                       dynamics_field: str = "model.A/B", equilibrium_field: str = "model.A") -> None:
    """Input errors (not numerical failures later) for a linear model the planner cannot use:
    (A, B) not stabilisable or not controllable (node stabilisers and rest-to-rest nominals),
    configurations at rest that are no equilibrium, (A, H) not detectable (the Kalman filter).
    The ``*_field`` arguments name where the user gave what is wrong."""
    sc, model = problem.scenario, problem.model
    A, B = np.asarray(model.A, dtype=float), np.asarray(model.B, dtype=float)
    text = lambda modes: ", ".join(f"{z.real:.4g}" + (f"{z.imag:+.4g}j" if abs(z.imag) > 1e-12 else "")  # noqa: E731
                                   for z in modes[:3])
    bad = _uncontrollable_modes(A, B, unstable_only=True)
    if bad:
        raise ScenarioError(sc.path, dynamics_field, f"(A, B) is not stabilisable: discretised mode(s) {text(bad)} "
                                                  "on or outside the unit circle cannot be controlled")
    bad = _uncontrollable_modes(A, B, unstable_only=False)
    if bad:
        raise ScenarioError(sc.path, dynamics_field, f"(A, B) is not controllable: mode(s) {text(bad)} cannot be "
                                                  "steered (rest-to-rest nominal trajectories need every state)")
    d = problem.config_dim
    drift = (A - np.eye(A.shape[0]))[:, :d]
    if np.linalg.matrix_rank(np.hstack([B, drift]), tol=1e-9 * max(1.0, np.abs(A).max())) > \
            np.linalg.matrix_rank(B, tol=1e-9 * max(1.0, np.abs(B).max())):
        raise ScenarioError(sc.path, equilibrium_field, "expected every configuration at rest to be an equilibrium "
                                                "(A v + B u = v solvable for u), so nodes can be held")
    if not sc.perfect:
        H = np.asarray(model.H, dtype=float)
        bad = _uncontrollable_modes(A.T, H.T, unstable_only=True)
        if bad:
            raise ScenarioError(sc.path, "measurement.H", f"(A, H) is not detectable: discretised mode(s) {text(bad)} "
                                                          "on or outside the unit circle are not observed")
        # The stationary Kalman filter's Riccati equation also needs process noise on those modes.
        bad = _uncontrollable_modes(A, np.asarray(model.F, dtype=float), unstable_only=True)
        if bad:
            raise ScenarioError(sc.path, noise_field, f"expected process noise on every mode on or outside the unit "
                                                      f"circle (mode(s) {text(bad)} get none) with imperfect "
                                                      "measurements: the stationary Kalman filter needs it")
