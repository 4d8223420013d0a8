"""Compiled Monte Carlo engine: the whole edge step in one numba kernel (plain loops, no temporaries),
compiled against the robot's compiled hooks.

:func:`simulate` is a drop-in twin of :func:`firmtool.estimation.edges.simulate` for the problems it knows:
a :class:`~firmtool.models.linear.LinearGaussianModel` on a robot that offers compiled hooks
(:class:`~firmtool.robots.compiled.CompiledKinematics`: its key points, the sensing point of each
measurement, its capsules over the key points, its task point), planar with the numpy or numba
collision geometry, or 3-D among the fcl backend's boxes and spheres. Per step and per live particle it does, in this order, exactly what the numpy path does:

    control from the estimate -> true-state step with process noise -> key points (once) ->
    observation noise with R at the TRUE state -> filter update with the precomputed gain ->
    control effort -> collision test -> goal region of a goal ball (every step) -> node membership
    (from the stabiliser phase on)

The engine knows no robot: the kernel is compiled once per set of hook functions, which it calls by
name (:func:`firmtool.jit.specialise`), and cached on disk; the hooks' constants are its arguments.
A user's robot gets the engine by returning hooks from its ``compiled_kinematics()``, without
editing firmtool (``tests/test_kernels.py`` runs one defined in the test file).

Modules, one job each:

- :mod:`~firmtool.estimation.compiled.rng`: random numbers (xoshiro256++, ziggurat) and the two noise
  sources of a step;
- :mod:`~firmtool.estimation.compiled.step`: the step helpers (control, true step, filter update,
  effort), all particles as columns;
- :mod:`~firmtool.estimation.compiled.collide`: capsules against boxes and bounds, self-collision,
  the gate; :mod:`~firmtool.estimation.compiled.collide3d` the same in 3-D (a radius per capsule,
  turned boxes, spheres);
- :mod:`~firmtool.estimation.compiled.locate`: node membership's per-step candidates, a segment's in
  one compiled pass (the compiled test itself is the roadmap's, :mod:`firmtool.roadmap.membership`);
- :mod:`~firmtool.estimation.compiled.summary`: an estimate's integer summaries (step histogram,
  outcome counts) in one pass;
- :mod:`~firmtool.estimation.compiled.goal`: the goal test (``ball_decision``, ``goal_test``);
  :mod:`~firmtool.estimation.compiled.goal3d` in a 3-D task space;
- :mod:`~firmtool.estimation.compiled.run`: the kernel (the steps of all live particles) and its compilation per
  hook set; :mod:`~firmtool.estimation.compiled.bindings`: what it calls per world dimension;
- :mod:`~firmtool.estimation.compiled.driver`: :func:`simulate`, the data it prepares, its caches;
- :mod:`~firmtool.estimation.compiled.select`: :func:`supports`, :func:`engine_choice`,
  :func:`engine_for`.

Each compiled function's docstring names the numpy function it reproduces and the test that pins
the two together. They are cached on disk by :func:`firmtool.jit.cached_njit`, whose key also covers
the compiled functions of other modules they call (the controllers' product, the geometry's
distances, the robot's hooks) and the constants they read: an edit of those recompiles the kernel
instead of loading stale machine code.
"""

from firmtool.estimation.compiled.driver import FIRST_SEGMENT_PAST_EDGE, simulate
from firmtool.estimation.compiled.run import kernel, kernel_for, kernels
from firmtool.estimation.compiled.select import ENGINE_ENV, engine_choice, engine_for, supports
from firmtool.estimation.compiled.step import NOISE_FORMS
from firmtool.jit import numba

__all__ = ["ENGINE_ENV", "FIRST_SEGMENT_PAST_EDGE", "NOISE_FORMS", "engine_choice", "engine_for", "kernel",
           "kernel_for", "kernels", "numba", "simulate", "supports"]
