"""The unicycle (x, y, heading; speed and turn rate) with a light-dark position sensor
(:class:`firmtool.models.unicycle.UnicycleModel`), paper Examples 3.3 and 3.4.

It cannot be regulated to a pose at rest (its linearisation there is neither controllable nor, with
a position sensor, observable), so every node stabiliser is a periodic LQG tracking a figure eight
through the node (:mod:`firmtool.control.stabilisers`), and edges follow turn-drive-turn nominals that
respect the nonholonomic constraint and arrive in phase.

``[model]`` keys: ``dynamics = "unicycle"``, ``process_noise_std`` (position, per sqrt(s)),
``heading_noise_std`` (rad per sqrt(s)), ``max_turn_rate`` (edge nominals; the speed limit is
``controller.max_speed``), ``orbit_radius`` and ``orbit_speed`` (the node orbit: two circles of
that radius driven at that speed).

The configuration is the position (``config_dim = 2``); the heading is the one further state
coordinate, 0 at every sampled node (each node is the phase-0 point of a figure-eight orbit
facing +x). :meth:`UnicycleRobot.is_valid` (node sampling, nominal checks) keeps the orbit's reach
``2 orbit_radius`` clear around the robot; :meth:`points_valid` (the Monte Carlo and execution)
tests the robot's true disc.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from firmtool.control.gains import lqr_weights
from firmtool.control.stabilisers import OrbitSpec, cached_periodic_node
from firmtool.errors import ScenarioError
from firmtool.models.unicycle import UnicycleModel, turn_drive_turn
from firmtool.robots.base import Robot
from firmtool.robots.registry import register
from firmtool.robots.relocalisation import Relocalisation, spread_coordinate
from firmtool.util.schema import Field


class UnicycleRobot(Robot):
    """A unicycle with periodic node stabilisers (see the module docs)."""

    # 23-26 ms of thread CPU time (bench_online.py): the run-time design alone (periodic stabiliser,
    # TV-LQG over ~300 steps with the linearisation of every step) takes ~26 ms
    replan_candidate_seconds: ClassVar[float] = 30e-3
    angle_coordinates: ClassVar[tuple[int, ...]] = (2,)  # the heading
    model_fields: ClassVar[tuple[Field, ...]] = (
        Field("dynamics", "string", choices=("unicycle",), doc="the unicycle's kinematics, exactly discretised"),
        Field("process_noise_std", "number", bound="nonnegative", unit="m / sqrt(s)", doc="position process noise"),
        Field("heading_noise_std", "number", 0.0, bound="nonnegative", unit="rad / sqrt(s)", doc="heading process noise"),
        Field("max_turn_rate", "number", 1.0, bound="positive", unit="rad/s", doc="turn-rate limit of edge nominals"),
        Field("orbit_radius", "number", 0.1, bound="positive", unit="m", doc="radius of the node orbit's two circles"),
        Field("orbit_speed", "number", 0.2, bound="positive", unit="m/s", doc="speed along the node orbit"),
    )
    rest_state_text: ClassVar[str] = ("expected heading 0 (every node faces +x; give the position only, "
                                      "or a heading of 0)")
    # firmtool init: a unicycle driving past a box in a 5 x 3 room, light-dark position sensing
    template = {
        "model": {"robot": "unicycle", "dynamics": "unicycle", "dt": 0.1, "process_noise_std": 0.03,
                  "heading_noise_std": 0.03},
        "measurement": {"kind": "imperfect", "noise": "lightdark_variance", "light_x": 5.0, "a": 0.002,
                        "c": 0.0001},
        "world": {"bounds": [[0.0, 0.0], [5.0, 3.0]], "robot_radius": 0.1,
                  "obstacles": [{"center": [2.5, 1.2], "half_size": [0.3, 0.6]}]},
        "task": {"start": [0.6, 0.6], "goal": [4.4, 0.8]},
        "roadmap": {"nodes": 20, "neighbors": 6, "min_separation": 0.6, "max_edge_length": 2.5},
        "controller": {"velocity_weight": 0.5, "control_weight": 0.5, "max_speed": 0.5, "node_radius": 1.5,
                       "covariance_tolerance": 0.3, "max_steps": 300},
        "estimation": {"particles": 100},
    }

    def __init__(self, scenario) -> None:
        super().__init__(scenario)
        spec, w = scenario.model, scenario.world
        if self.world_dim != 2:
            raise ScenarioError(scenario.path, "world.bounds", "expected a planar world for robot = 'unicycle'")
        if scenario.measurement.H is not None:
            raise ScenarioError(scenario.path, "measurement.H",
                                "not used for robot = 'unicycle' (its sensor measures the position)")
        F = np.diag([spec.process_noise_std, spec.process_noise_std, spec.heading_noise_std]) * np.sqrt(spec.dt)
        self.model = UnicycleModel(F=F, noise=self.noise(), dt=spec.dt)
        self.config_dim = 2
        self.config_lo, self.config_hi = np.array(w.lo), np.array(w.hi)
        self.reach = 2.0 * spec.orbit_radius

    def points(self, X: np.ndarray) -> np.ndarray:
        """The robot's position: states (M, 3) -> (M, 1, 2)."""
        return np.asarray(X)[:, None, :2]

    def task_jacobian(self, X: np.ndarray) -> np.ndarray:
        """d position / d state (M, 2, 3): the identity on (x, y), zero in the heading."""
        if type(self).points is not UnicycleRobot.points or type(self).task_point is not UnicycleRobot.task_point:
            return super().task_jacobian(X)
        X = np.atleast_2d(X)
        J = np.zeros((X.shape[0], 2, X.shape[1]))
        J[:, 0, 0] = J[:, 1, 1] = 1.0
        return J

    def velocity_command(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """``u = (v, omega)``: forward speed and turn rate, a differential drive's ``cmd_vel``."""
        v, omega = np.asarray(u, dtype=float)[:2]
        return np.array([v, 0.0, 0.0]), np.array([0.0, 0.0, omega])

    def heading(self, X: np.ndarray) -> np.ndarray:
        """The heading, the state's third coordinate: states (M, 3) -> (M,)."""
        return np.asarray(X, dtype=float)[:, 2]

    def is_valid(self, X: np.ndarray) -> np.ndarray:
        """Nodes and nominals keep the node orbit's reach clear around the robot's disc."""
        P = self.points(X)
        return ~self.collision().capsules_collide(P, P, self.scenario.world.robot_radius + self.reach)

    def world_reach(self) -> float:
        """The disc and the node orbit's margin that :meth:`is_valid` keeps (a region start tests it)."""
        return float(self.scenario.world.robot_radius + self.reach)

    # -- periodic node stabilisers -------------------------------------------------------------------

    def _weights(self, problem):

        return lqr_weights(problem)

    def periodic_node(self, problem, center: np.ndarray):
        """The periodic (PLQG / PLQR) stabiliser of the node at ``center``, memoised per centre."""
        Wx, Wu = self._weights(problem)
        spec = problem.scenario.model
        return cached_periodic_node((problem.scenario.sha256,), problem.model, center,
                                    OrbitSpec(spec.orbit_radius, spec.orbit_speed), Wx, Wu, problem.perfect)

    def design_node(self, problem, center, Wx, Wu, memo):
        return self.periodic_node(problem, center)

    def node_controller(self, problem, center, stored):
        """The whole orbit, recomputed from the centre (the roadmap stores its phase-0 values)."""
        return self.periodic_node(problem, center)

    def after_jump(self, problem, mean, covariance):
        """A unicycle's third coordinate is its heading, not a velocity, and nothing "stops" it: the
        belief stays as corrected (the heading as a push leaves it). Widening the heading instead
        (kept or anywhere, variance + pi^2 / 2) made the decisions after pushes flail (pushes at
        steps 0 and 400, 20 episodes: 0.95 -> 0.70 success) and recovered no kidnap (0.10-0.20 at
        steps 800-1600): at rest a unicycle cannot see its heading, so a wide one stays wide until
        it moves."""
        return np.array(mean, dtype=float), np.array(covariance, dtype=float)

    def relocalisation(self, problem, mean, covariance):
        """The heading anywhere, and a probe that shows it.

        :data:`HEADING_HYPOTHESES` hypotheses, the kept heading first with weight
        :data:`HEADING_KEPT_WEIGHT` (a push leaves it, a kidnap does not); the probe drives straight
        out at the orbit speed and back, round trips for up to :data:`PROBE_STEPS` steps, as far as
        the robot is valid at every heading within the reach plus a margin around the estimate,
        from :data:`PROBE_REACH` down; the margin is one standard deviation of the position, then
        none (a probe in a tight spot risks a collision, no probe near-certainly fails). The probe
        ends once one mode holds 0.95 of the weight with a heading standard deviation under
        :data:`HEADING_RESOLVED`, or once the estimated position leaves the disc it checked by more
        than two of its standard deviations (the open-loop probe's drift).

        Where no reach is free around an uncertain position, the robot first stands still for
        :data:`SETTLE_STEPS` steps (at rest its position shows, its heading does not), then looks for
        a probe again around the position it now knows.

        Parameters
        ----------
        mean : (3,) the belief's mean after the jump's correction; covariance : (3, 3).

        Returns
        -------
        Relocalisation or None
            None when not even the shortest reach is free and the position is known to better
            than that reach (standing still would not make room): then the policy decides from the
            belief at once. The stand-still's follow-up (``then``) gives None likewise.
        """
        return self._relocalisation(problem, mean, covariance, settle=True)

    def _relocalisation(self, problem, mean, covariance, settle: bool):

        mean = np.asarray(mean, dtype=float)
        c = self.angle_coordinates[0]
        means, covs, weights = spread_coordinate(mean, covariance, c, HEADING_HYPOTHESES, HEADING_KEPT_WEIGHT)
        spec = problem.scenario.model
        position_std = float(np.sqrt(np.linalg.eigvalsh(np.asarray(covariance)[:2, :2])[-1]))
        # a probe in a tight spot risks a collision, no probe near-certainly fails (the heading stays
        # wrong): the margin shrinks before the probe is given up
        for margin in (position_std, 0.0):
            reach = _free_reach(problem, mean[:2], margin, means[:, c], c)
            if reach is not None:
                break
        else:
            if not settle or position_std < min(PROBE_REACH):
                return None
            # no probe fits around this estimate, but the estimate is a jump's correction, as
            # uncertain as one measurement: standing still shows where the robot is (and nothing
            # of its heading, so the follow-up starts from the heading as it was given)
            kept, kept_var = float(mean[c]), float(np.asarray(covariance)[c, c])

            def then(m: np.ndarray, P: np.ndarray):
                m, P = np.array(m, dtype=float), np.array(P, dtype=float)
                m[c] = kept
                P[c, :] = 0.0
                P[:, c] = 0.0
                P[c, c] = kept_var
                return self._relocalisation(problem, m, P, settle=False)

            return Relocalisation(means, covs, weights, np.zeros((SETTLE_STEPS, problem.model.m)), angle=c,
                                  resolved=HEADING_RESOLVED, then=then)
        # never past the reach (but one step, if the reach is shorter than a step)
        legs = max(1, int(np.floor(reach / (spec.orbit_speed * spec.dt) + 1e-9)))
        out_and_back = np.concatenate([np.tile([spec.orbit_speed, 0.0], (legs, 1)),
                                       np.tile([-spec.orbit_speed, 0.0], (legs, 1))])
        trips = max(1, PROBE_STEPS // out_and_back.shape[0])
        start, limit = mean[:2].copy(), reach + margin

        def inside(m: np.ndarray, P: np.ndarray) -> bool:
            # the probe is open loop: its drift (process noise, a heading off its line) shows in the
            # estimate, which must not leave the disc that was checked by more than its own noise
            # (two standard deviations: ended on the estimate alone, 15-19 of 40 probes after
            # unicycle kidnaps stopped before their heading was resolved)
            spread = float(np.sqrt(np.linalg.eigvalsh(P[:2, :2])[-1]))
            return float(np.hypot(*(m[:2] - start))) <= limit + 2.0 * spread

        return Relocalisation(means, covs, weights, np.tile(out_and_back, (trips, 1)), angle=c,
                              resolved=HEADING_RESOLVED, allowed=inside)

    def jump_prior(self, problem):
        """Position anywhere in the world, heading anywhere."""
        span = np.asarray(problem.config_hi, dtype=float) - np.asarray(problem.config_lo, dtype=float)
        return np.concatenate([span ** 2, [np.pi ** 2]])

    def start_covariance(self, problem, state):
        """At rest a unicycle's heading is not observable (its linearisation there is not
        detectable): no stationary filter exists. Its nodes' belief is the periodic filter's at phase
        0 of the orbit through the node; so is the belief at a start state."""
        return self.periodic_node(problem, state).P.copy()

    # -- nominals ------------------------------------------------------------------------------------

    def nominal_trajectory(self, problem, x0, xf):
        """Kinematically feasible: turn in place, drive straight, turn."""
        return turn_drive_turn(problem.model, x0, xf, problem.scenario.controller.max_speed,
                               problem.scenario.model.max_turn_rate)

    def runtime_nominal(self, problem, x0, xf, tries):
        """The same turn-drive-turn nominal (no speed to brake: the state has none)."""
        return self.nominal_trajectory(problem, x0, xf)


HEADING_HYPOTHESES = 12  # 30 degrees apart
HEADING_KEPT_WEIGHT = 0.5  # prior weight of "the jump left the heading alone" (a push)
HEADING_RESOLVED = np.pi / HEADING_HYPOTHESES  # rad: half the hypotheses' spacing
PROBE_REACH = (0.6, 0.4, 0.25, 0.15, 0.1)  # m, the probe's reach, the longest whose disc is free
# Steps a probe may take. Its evidence grows with the number of round trips: with the position
# measured to sigma, a reach d tells the heading's sign after about (6 sigma / d)^2 steps (a reach
# of 0.15 m in the dark, sigma 0.3 m: ~150 steps); 2 round trips left modes of 0.37-0.8 there and
# ended in collisions (unicycle kidnaps at step 1600).
PROBE_STEPS = 300
SETTLE_STEPS = 20  # at rest before a probe where none fits: a position measured 20 times, sigma / 4.5
DISC_SAMPLES = 256  # directions (and radii) at most in the probe's disc check: 12 x 256 x 256 states


def _free_reach(problem, position: np.ndarray, margin: float, headings: np.ndarray, heading: int) -> float | None:
    """The longest of :data:`PROBE_REACH` such that the robot is valid (its disc and the user's
    checker, at each of ``headings`` (K,) of state coordinate ``heading``) everywhere within that
    reach plus ``margin`` of ``position`` (2,), or None. Points are sampled half the robot's radius apart, at most
    :data:`DISC_SAMPLES` directions and radii (then further apart: a tiny robot in a wide disc)."""
    spacing = 0.5 * problem.scenario.world.robot_radius
    for reach in PROBE_REACH:
        outer = reach + margin
        count = int(np.clip(np.ceil(2.0 * np.pi * outer / spacing), 32, DISC_SAMPLES))
        angles = np.linspace(0.0, 2.0 * np.pi, count, endpoint=False)
        ring = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        radii = np.linspace(0.0, outer, int(np.clip(np.ceil(outer / spacing) + 1, 2, DISC_SAMPLES)))
        pts = (position[None, None] + radii[:, None, None] * ring[None]).reshape(-1, 2)
        X = np.repeat(problem.state_of(pts), headings.size, axis=0)
        X[:, heading] = np.tile(headings, pts.shape[0])
        if np.all(problem.states_valid(X, problem.robot.points(X))):
            return reach
    return None


register("unicycle", UnicycleRobot)
