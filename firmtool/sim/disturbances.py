"""Large disturbances injected into the simulated true system during execution.

The filter is never told: a disturbance moves the TRUE state only, and the estimate learns of it
(or not) through the measurements, as a real robot would.

Specification strings (``firmtool execute --disturbance SPEC``, repeatable)::

    push:STEP:SIZE            at step STEP, the true configuration moves by SIZE (scenario units) in a
                              random direction of the position (configuration) coordinates
    push:random:SIZE:RATE     the same push at random steps: each step with probability RATE
    kidnap:STEP               at step STEP, the true state jumps to a uniformly drawn valid
                              configuration at rest (facing anywhere)
    kidnap:random:RATE        the same jump at random steps, probability RATE per step
    obstacle:STEP:C:H         at step STEP a box of centre C and half sizes H (comma-separated, one
                              number per world axis: obstacle:30:5.0,1.5:0.3,1.0) appears in the true
                              world, and the policy is told (Policy.update_world, as a map update
                              would tell a robot) once it has observed that step
    obstacle-unseen:STEP:C:H  the same box, the policy not told (it meets it only by colliding)

STEP counts control steps from the start of the episode (0 = before the first step). A push is
drawn among the directions whose straight segment from the current configuration stays free of
collision (up to 64 draws; a robot boxed in on all sides is pushed anyway): the push is the
disturbance, not a teleport through a wall. Velocities are left unchanged by a push and set to zero
by a kidnap; an angle the robot keeps continuous along a run that is no configuration coordinate (a
unicycle's heading, :attr:`firmtool.robots.Robot.angle_coordinates`) is drawn uniformly (the robot
is set down facing anywhere) and put on the turn nearest the old value (no 2 pi jump of the number).

In Python a disturbance may also be a user's callable (:class:`UserDisturbance`):
``fn(step, state, rng) -> new state or None``, asked before every control step with the true
state (n,); returning a state (n,) puts the true system there (an event ``disturbance`` named
``user:NAME``), None leaves it alone.

Reproducibility: the random times of an episode are drawn once at its start from
``SeedSequence([seed, 0xD157, episode])`` and the direction / destination of its ``i``-th event from
``SeedSequence([seed, 0xD157, episode, i + 1])``, so the same disturbances hit the same episode
whatever the controller does (replanning on or off). A user's callable number ``j`` (in the order
given) draws from ``SeedSequence([seed, 0xD157, episode, 0, j])``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from firmtool.errors import InputError, quoted
from firmtool.models.angles import on_turn_of
from firmtool.problem import Problem
from firmtool.roadmap.nodes import segment_is_valid

PUSH, KIDNAP, OBSTACLE, OBSTACLE_UNSEEN = "push", "kidnap", "obstacle", "obstacle-unseen"
KINDS = (PUSH, KIDNAP, OBSTACLE, OBSTACLE_UNSEEN)
DISTURBANCE_KEY = 0xD157
PUSH_DRAWS = 64  # directions tried for a collision-free push
KIDNAP_DRAWS = 10_000  # configurations tried for a valid kidnap destination

SPEC_HELP = ("push:STEP:SIZE (true state pushed SIZE scenario units in a random position direction at "
             "step STEP), push:random:SIZE:RATE (pushes at random steps, probability RATE per step), "
             "kidnap:STEP (true state jumps to a random valid state at rest, the filter is not told), "
             "kidnap:random:RATE, obstacle:STEP:CX,CY:HX,HY (a box appears in the true world at step STEP, the "
             "policy is told), obstacle-unseen:STEP:CX,CY:HX,HY (the policy is not told). Repeatable.")


@dataclass(frozen=True)
class Disturbance:
    """One disturbance specification: a kind, a fixed step or a per-step rate, a push size, or the
    box an obstacle disturbance adds."""

    kind: str  # one of KINDS
    step: int | None = None  # fixed step, or None for random times
    rate: float = 0.0  # probability per step when ``step`` is None
    size: float = 0.0  # push length (scenario units)
    center: tuple[float, ...] = ()  # an obstacle's box
    half_size: tuple[float, ...] = ()

    @property
    def changes_world(self) -> bool:
        return self.kind in (OBSTACLE, OBSTACLE_UNSEEN)

    def box(self) -> dict:
        """An obstacle disturbance's box as a scenario table."""
        return {"center": list(self.center), "half_size": list(self.half_size)}

    def __str__(self) -> str:
        when = f"{self.step}" if self.step is not None else "random"
        if self.changes_world:
            return f"{self.kind}:{when}:{','.join(f'{v:g}' for v in self.center)}:" \
                   f"{','.join(f'{v:g}' for v in self.half_size)}"
        if self.kind == PUSH:
            return f"push:{when}:{self.size:g}" + ("" if self.step is not None else f":{self.rate:g}")
        return f"kidnap:{when}" + ("" if self.step is not None else f":{self.rate:g}")


def _number(text: str, spec: str, what: str, kind: type = float) -> float:
    try:
        value = kind(text)
    except ValueError:
        raise InputError(f"--disturbance {quoted(spec)}: {what} must be a{'n integer' if kind is int else ' number'}, "
                         f"found {quoted(text)} (format: {SPEC_HELP})") from None
    if not np.isfinite(value):
        raise InputError(f"--disturbance {quoted(spec)}: {what} must be finite, found {quoted(text)}")
    return value


def parse_disturbance(spec: str) -> Disturbance:
    """Parse one specification string; :class:`InputError` (one line) if it is malformed.

    Examples
    --------
    >>> parse_disturbance("push:40:0.8")
    Disturbance(kind='push', step=40, rate=0.0, size=0.8)
    >>> parse_disturbance("kidnap:random:0.01")
    Disturbance(kind='kidnap', step=None, rate=0.01, size=0.0)
    """
    parts = spec.strip().split(":")
    kind = parts[0].lower()
    if kind not in KINDS:
        raise InputError(f"--disturbance {quoted(spec)}: expected 'push', 'kidnap', 'obstacle' or 'obstacle-unseen' first "
                         f"(format: {SPEC_HELP})")
    if kind in (OBSTACLE, OBSTACLE_UNSEEN):
        return _obstacle(spec, kind, parts)
    expected = {(PUSH, False): 3, (PUSH, True): 4, (KIDNAP, False): 2, (KIDNAP, True): 3}
    random_times = len(parts) > 1 and parts[1].lower() == "random"
    if len(parts) != expected[(kind, random_times)]:
        form = {(PUSH, False): "push:STEP:SIZE", (PUSH, True): "push:random:SIZE:RATE",
                (KIDNAP, False): "kidnap:STEP", (KIDNAP, True): "kidnap:random:RATE"}[(kind, random_times)]
        raise InputError(f"--disturbance {quoted(spec)}: expected {form}")
    step, rate, size = None, 0.0, 0.0
    if random_times:
        rate = _number(parts[-1], spec, "RATE")
        if not 0.0 < rate <= 1.0:
            raise InputError(f"--disturbance {quoted(spec)}: RATE is a probability per step, expected 0 < RATE <= 1")
    else:
        step = int(_number(parts[1], spec, "STEP", int))
        if step < 0:
            raise InputError(f"--disturbance {quoted(spec)}: STEP must be >= 0")
    if kind == PUSH:
        size = _number(parts[2], spec, "SIZE")
        if size <= 0:
            raise InputError(f"--disturbance {quoted(spec)}: SIZE must be > 0")
    return Disturbance(kind=kind, step=step, rate=rate, size=size)


def _obstacle(spec: str, kind: str, parts: list[str]) -> Disturbance:
    """``obstacle[-unseen]:STEP:CX,CY[,CZ]:HX,HY[,HZ]`` (its dimension is checked against the world
    when the box is added)."""
    if len(parts) != 4:
        raise InputError(f"--disturbance {quoted(spec)}: expected {kind}:STEP:CX,CY:HX,HY")
    step = int(_number(parts[1], spec, "STEP", int))
    if step < 0:
        raise InputError(f"--disturbance {quoted(spec)}: STEP must be >= 0")
    center = tuple(_number(v, spec, "a centre coordinate") for v in parts[2].split(","))
    half = tuple(_number(v, spec, "a half size") for v in parts[3].split(","))
    if len(center) != len(half) or len(center) not in (2, 3):
        raise InputError(f"--disturbance {quoted(spec)}: expected as many half sizes as centre coordinates (2 or 3)")
    if min(half) <= 0:
        raise InputError(f"--disturbance {quoted(spec)}: the half sizes must be > 0")
    return Disturbance(kind=kind, step=step, center=center, half_size=half)


def parse_disturbances(specs: list[str] | tuple[str, ...] | None) -> tuple[Disturbance, ...]:
    return tuple(parse_disturbance(s) for s in (specs or ()))


@dataclass(frozen=True)
class UserDisturbance:
    """A user's disturbance: ``fn(step, state, rng)`` is asked before every control step.

    Parameters
    ----------
    fn : callable
        ``fn(step: int, state: ndarray (n,), rng: numpy Generator) -> ndarray (n,) or None``: the
        new true state, or None for no disturbance at this step. ``step`` counts control steps from
        the start of the episode; ``state`` is a copy.
    name : str
        For events and reports (default: the callable's ``__name__``).
    """

    fn: Callable[[int, np.ndarray, np.random.Generator], np.ndarray | None]
    name: str = ""

    def __str__(self) -> str:
        return "user:" + (self.name or getattr(self.fn, "__name__", type(self.fn).__name__))


def as_disturbances(items: Iterable[str | Disturbance | UserDisturbance | Callable] | None
                    ) -> tuple[Disturbance | UserDisturbance, ...]:
    """Specification strings, :class:`Disturbance` and callables (wrapped as :class:`UserDisturbance`)."""
    out: list[Disturbance | UserDisturbance] = []
    for item in items or ():
        if isinstance(item, (Disturbance, UserDisturbance)):
            out.append(item)
        elif isinstance(item, str):
            out.append(parse_disturbance(item))
        elif callable(item):
            out.append(UserDisturbance(item))
        else:
            raise InputError(f"disturbance: expected a specification string, a Disturbance or a callable, "
                             f"found {type(item).__name__}")
    return tuple(out)


def schedule(disturbances: tuple[Disturbance, ...], max_steps: int,
             rng: np.random.Generator) -> list[tuple[int, Disturbance]]:
    """The (step, disturbance) events of one episode, sorted by step (stable in spec order)."""
    events: list[tuple[int, int, Disturbance]] = []
    for order, dist in enumerate(disturbances):
        if dist.step is not None:
            events.append((dist.step, order, dist))
        else:  # drawn for every spec, so that adding one spec does not shift another's times
            times = np.flatnonzero(rng.random(max_steps) < dist.rate)
            events.extend((int(t), order, dist) for t in times)
    events.sort(key=lambda e: (e[0], e[1]))
    return [(t, d) for t, _, d in events]


def apply(problem: Problem, dist: Disturbance, x: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """The true state after the disturbance, and how far the configuration moved.

    Parameters
    ----------
    x : (n,) true state.

    Returns
    -------
    x_new : (n,) new true state; moved : Euclidean configuration-space displacement.
    """
    d = problem.config_dim
    new = x.copy()
    if dist.kind == PUSH:
        for _ in range(PUSH_DRAWS):
            direction = rng.standard_normal(d)
            direction /= max(np.linalg.norm(direction), 1e-300)
            new[:d] = x[:d] + dist.size * direction
            if segment_is_valid(problem, x, new):
                break
    else:
        turned = [c for c in problem.robot.angle_coordinates if c >= d]  # configuration angles are drawn as such
        for _ in range(max(1, KIDNAP_DRAWS // 256)):
            q = rng.uniform(problem.config_lo, problem.config_hi, size=(256, d))
            states = problem.state_of(q)
            # an angle that is no configuration coordinate (a unicycle's heading) faces anywhere too:
            # drawn uniformly, before the validity test (a footprint may depend on it)
            for c in turned:
                states[:, c] = rng.uniform(-np.pi, np.pi, size=256)
            ok = problem.is_valid(states)
            if ok.any():
                new = states[int(np.argmax(ok))].copy()
                # an angle kept continuous along the run stays so: the drawn pose, on the turn
                # nearest the old value
                for c in turned:
                    new[c] = on_turn_of(new[c], x[c])
                break
    return new, float(np.linalg.norm(new[:d] - x[:d]))
