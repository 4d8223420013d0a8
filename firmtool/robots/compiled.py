"""What a robot offers the compiled Monte Carlo engine: compiled hooks for its kinematics.

The compiled engine (:mod:`firmtool.estimation.compiled`) runs the whole step of an edge's Monte Carlo
in one numba kernel, and knows no robot: a robot that wants it returns a :class:`CompiledKinematics`
from :meth:`CompiledHooks.compiled_kinematics` (the default, None, runs the numpy engine). The kernel is
compiled once per set of hook functions (specialised on them, not on robot classes) and cached on
disk; the hooks' constants travel as its arguments, so two arms with other link lengths share one
compiled kernel. The planar point and chain hooks of the built-in robots are in
:mod:`firmtool.robots.planar`, written the way a user's robot writes its own; the 3-D hooks of a URDF
arm (``dim = 3``) in :mod:`firmtool.robots.urdf_compiled`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from firmtool.errors import InputError


@dataclass(frozen=True)
class CompiledKinematics:
    """A robot's compiled hooks for the compiled Monte Carlo engine, and the constants they read.

    The engine runs planar robots (``dim = 2``, a 2-D world) and 3-D ones (``dim = 3``). A robot
    returns one only if each hook is exactly the twin of its Python method named below: the engine
    then computes the same Monte Carlo as the numpy engine, and the tests of a robot compare the two
    (``tests/test_kernels.py`` shows how, ``tests/test_kernels_3d.py`` in 3-D).

    In 3-D the hooks take the key points' z too: ``key_points(X, params, PX, PY, PZ, lane, na)``,
    ``task_point(xh, params, work) -> (tx, ty, tz)``, ``task_covariance(P, params, work) -> (s11,
    s12, s13, s22, s23, s33)``, ``goal_gate(X, XH, PX, PY, PZ, params, center, radius, E, B, GG,
    na)``; ``sense(PX, PY, PZ, params, S, na)`` fills the sensing coordinates ``S`` (n_sensing, N)
    (the twin of :meth:`Robot.sensing_from_points <firmtool.robots.Robot.sensing_from_points>`'s
    distinct columns; ``sensing[j]`` is then the row of ``S`` that sets measurement j's noise); the
    capsules have a radius each (``radii``) and lie between key points ``stride l`` and
    ``stride l + offset``; self-collision is not tested.

    Compiled functions (numba ``njit``, module-level functions of an importable module, so that the
    kernel compiled against them is cached on disk; hooks defined in ``__main__`` are compiled in
    every process and the engine's notice says so). Arrays of particles are columns: states ``X``
    (n, N), key points ``PX``, ``PY`` (n_points, N); only the first ``na`` columns are live.

    Attributes
    ----------
    key_points : ``key_points(X, params, PX, PY, lane, na)`` fills the key points of the states (the
        twin of :meth:`Robot.points <firmtool.robots.Robot.points>`); ``lane`` is an (N,) work array.
    task_point : ``task_point(xh, params, work) -> (tx, ty)``, the task point of one estimate ``xh``
        (n,) (the twin of :meth:`Robot.task_point <firmtool.robots.Robot.task_point>`, which must be
        the last key point); it may leave in ``work`` (work_size,) what ``task_covariance`` reads.
    task_covariance : ``task_covariance(P, params, work) -> (s11, s12, s22)``, the task covariance
        ``J P J'`` at the estimate ``task_point`` was last called on, ``J`` (2, task_block) the
        leading columns of :meth:`Robot.task_jacobian <firmtool.robots.Robot.task_jacobian>` and
        ``P`` (task_block, task_block) the leading block of the estimate's covariance.
    goal_gate : ``goal_gate(X, XH, PX, PY, params, center, radius, E, B, GG, na)`` or None: sets
        ``GG[a] = 0`` only where the goal test cannot pass for particle a (the estimate's task point
        is then outside the goal ball ``(center (2,), radius)``), ``E``, ``B`` (N,) work arrays: a
        cheap necessary condition, vectorised over particles. None: every particle is tested.
    params : (p,) float64, the constants every hook receives (an arm's link lengths).
    n_points : the number of key points P.
    sensing : (nz,) int64, the key point whose x sets measurement j's noise (the twin of
        :meth:`Robot.sensing_from_points <firmtool.robots.Robot.sensing_from_points>`).
    segments : ``(n_seg, offset)``, the collision shape: capsules of ``world.robot_radius`` between
        key points ``l`` and ``l + offset`` for ``l < n_seg`` (offset 0: discs at the points).
    self_collision : whether non-adjacent capsules are tested against each other.
    half_lengths : (n_seg,) upper bounds of half of each capsule's length, for the self-collision
        test's bounding-circle prefilter (inf: no bound, the prefilter passes).
    task_block : the leading state coordinates the task point depends on (at most n).
    work_size : the length of the ``work`` array of ``task_point`` and ``task_covariance``.
    dim : 2 (planar) or 3.
    stride : capsule ``l`` starts at key point ``stride l`` (3-D; 1 in 2-D).
    radii : (n_seg,) the capsules' radii (3-D; in 2-D every capsule has ``world.robot_radius``).
    sense : the 3-D sensing hook (above), None in 2-D; n_sensing : the rows it fills.
    step : ``step(X, U, params, XN, na)``, the noise-free step ``XN = f(X, U)`` of a nonlinear model (the
        twin of its ``Model.f``, e.g. the unicycle's), or None: the model is linear (``A X + B U``). With the
        robot's own sensor such a model's measurement must be linear, ``h = H x`` with a constant
        ``observation_jacobian`` (the unicycle's position); landmark sensing is the engine's own.
    self_pairs : 3-D: (S, 2) the capsule pairs tested for self-collision (None: none; in 2-D
        ``self_collision`` tests every non-adjacent pair instead).
    """

    key_points: Callable
    task_point: Callable
    task_covariance: Callable
    params: np.ndarray
    n_points: int
    sensing: np.ndarray
    segments: tuple[int, int]
    self_collision: bool
    task_block: int
    work_size: int = 1
    goal_gate: Callable | None = None
    half_lengths: np.ndarray | None = field(default=None)
    dim: int = 2
    stride: int = 1
    radii: np.ndarray | None = field(default=None)
    sense: Callable | None = None
    n_sensing: int = 0
    step: Callable | None = None
    self_pairs: np.ndarray | None = field(default=None)

    def __post_init__(self) -> None:
        dim, stride = int(self.dim), int(self.stride)
        if dim not in (2, 3):
            raise InputError(f"compiled kinematics: dim must be 2 or 3, found {self.dim!r}")
        for name in ("key_points", "task_point", "task_covariance", "goal_gate", "sense", "step"):
            fn = getattr(self, name)
            optional = name in ("goal_gate", "step") or (name == "sense" and dim == 2)
            # callable, not necessarily a dispatcher: with NUMBA_DISABLE_JIT=1 numba.njit gives back the function
            if not (fn is None and optional) and not callable(fn):
                raise InputError(f"compiled kinematics: {name} must be a numba-compiled function, found {fn!r}")
        if dim == 2 and (self.sense is not None or stride != 1 or self.radii is not None):
            raise InputError("compiled kinematics: sense, stride and radii are for 3-D robots (dim = 3)")
        n_seg, offset = (int(v) for v in self.segments)
        if n_seg < 1 or offset < 0 or stride < 1 or stride * (n_seg - 1) + offset >= self.n_points:
            raise InputError(f"compiled kinematics: segments {self.segments} (stride {stride}) do not fit "
                             f"{self.n_points} key points")
        sensing = np.ascontiguousarray(self.sensing, dtype=np.int64).reshape(-1)
        rows = self.n_points if dim == 2 else int(self.n_sensing)
        if sensing.size and (sensing.min() < 0 or sensing.max() >= rows):
            raise InputError(f"compiled kinematics: sensing {sensing.tolist()} names a "
                             f"{'key point' if dim == 2 else 'sensing row'} outside 0..{rows - 1}")
        if dim == 3:
            radii = np.ascontiguousarray(self.radii, dtype=float).reshape(-1) if self.radii is not None else None
            if radii is None or radii.shape != (n_seg,) or not np.all(np.isfinite(radii) & (radii > 0)):
                raise InputError(f"compiled kinematics: radii must be {n_seg} positive radii, one per capsule")
            if self.self_collision:
                raise InputError("compiled kinematics: the 3-D engine tests the self-collision pairs self_pairs "
                                 "names, not self_collision")
            pairs = np.zeros((0, 2), dtype=np.int64) if self.self_pairs is None else \
                np.ascontiguousarray(self.self_pairs, dtype=np.int64).reshape(-1, 2)
            if pairs.size and (pairs.min() < 0 or pairs.max() >= n_seg):
                raise InputError(f"compiled kinematics: self_pairs must index the {n_seg} capsules")
            object.__setattr__(self, "self_pairs", pairs)
            object.__setattr__(self, "radii", radii)
        half = np.full(n_seg, np.inf) if self.half_lengths is None else \
            np.ascontiguousarray(self.half_lengths, dtype=float).reshape(-1)
        if half.shape != (n_seg,):
            raise InputError(f"compiled kinematics: half_lengths must have one entry per capsule ({n_seg})")
        object.__setattr__(self, "segments", (n_seg, offset))
        object.__setattr__(self, "sensing", sensing)
        object.__setattr__(self, "half_lengths", half)
        object.__setattr__(self, "params", np.ascontiguousarray(self.params, dtype=float).reshape(-1))
        object.__setattr__(self, "self_collision", bool(self.self_collision))
        object.__setattr__(self, "work_size", max(int(self.work_size), 1))
        object.__setattr__(self, "dim", dim)
        object.__setattr__(self, "stride", stride)
        object.__setattr__(self, "n_sensing", max(int(self.n_sensing), 1))

    def functions(self) -> dict[str, Callable | None]:
        """The hook functions by the names the engine's kernel calls them (what it is compiled against);
        ``sense`` only in 3-D (its presence selects the 3-D kernel)."""
        out = {"key_points": self.key_points, "task_point": self.task_point,
               "task_covariance": self.task_covariance, "goal_gate": self.goal_gate}
        if self.dim == 3:
            out["sense"] = self.sense
        return out


class CompiledHooks:
    """The part of the :class:`~firmtool.robots.Robot` interface the compiled engine reads."""

    def compiled_kinematics(self) -> CompiledKinematics | None:
        """The compiled engine's hooks for this robot, or None (the default: the numpy engine runs). A
        robot returns them only if each is exactly the twin of its Python method
        (:class:`CompiledKinematics`); a subclass that changes those methods should return None or
        hooks of its own."""
        return None
