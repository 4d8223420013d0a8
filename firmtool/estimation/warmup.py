"""Compile the Monte Carlo engine ahead of its first use: once per install, in one process, while
the caller samples and designs.

numba compiles firmtool's kernels on first use and caches them on disk (``cache=True``). A fresh
install, or a new numba, starts cold: the edge kernel and the filter recursion cost 10-20 s of one
core, and without coordination every estimation worker compiles the same functions at the same
time, after sampling and design. :func:`start` (the build and estimate stages call it) compiles
them in one background process (``python -m firmtool.estimation.warmup``: the first edge of the shipped
``smoke`` scenario, whose argument types are those of every problem the engine runs) while the
caller goes on; :func:`wait` blocks until it is done, before the workers start, and the workers
then load the cache. With a warm cache nothing is started.

The kernel is compiled once per robot's set of compiled hooks (:mod:`firmtool.estimation.compiled.run`):
the process compiles it, with the smoke edge's argument types, for the hooks of every planar robot
with a scenario template (the built-in ones: ``firmtool init --robot``) and for the problem's robot
that :func:`start` was given, if its hooks are importable by name; a 3-D robot's with the types of
an edge of the URDF arm's template.

It compiles in the order a build needs: the design's functions first (the nominals' rollouts), then
reports ``design`` so that a build's design stage, which runs on several worker processes, waits for
that instead of letting every worker compile the same functions at once (:func:`wait_design`); then
the estimation workers' path (the batched filter recursions, the kernel) on a batch of edges.

The background process reports on its stdout; :func:`set_notifier` registers what to call when it
starts compiling (the CLI prints one line on stderr). The library itself never prints.
"""

from __future__ import annotations

import atexit
import importlib
import os
import subprocess
import sys
import threading
from pathlib import Path
from typing import Callable

import numpy as np

from firmtool import progress
from firmtool.control import recursions, trajectories
from firmtool.estimation import compiled as kernels
from firmtool.estimation.compiled.run import HOOK_NAMES, disk_cached
from firmtool.estimation.edges import estimate_edge
from firmtool.estimation.executors import EstimationJob, job_extras, remember_problem, run_batch
from firmtool.problem import Problem, build_problem
from firmtool.roadmap.design import design, local_controller
from firmtool.roadmap.nodes import roadmap_nodes
from firmtool.scenario import load_scenario, parse_scenario
from firmtool.scenario.docs import template, template_robots

# The background process's reports (one line each on its stdout).
COMPILING, DESIGN, DONE = "compiling", "design", "done"
# A compile that takes longer is abandoned (the workers then compile for themselves): a guard
# against a stuck process, far above the ~10-60 s a cold compile takes on a loaded 2-core machine.
WAIT_SECONDS = 900.0
WARMUP_SCENARIO = "smoke"  # a shipped scenario the compiled engine supports; tiny

_running: "_Warmup | None" = None


def set_notifier(callback: Callable[[str], None] | None) -> None:
    """Call ``callback(kind)`` (once, from a helper thread; ``kind`` "planar" or "3-D": which kernel)
    when a background compile starts compiling
    (held by :func:`firmtool.progress.set_compile_notifier`, which a caller may set without importing
    this module)."""
    progress.set_compile_notifier(callback)


class _Warmup:
    """The background compile process and the thread that reads its reports."""

    def __init__(self, hooks: list[str]) -> None:
        debug = bool(os.environ.get("FIRMTOOL_DEBUG"))
        # which engine compiles, for the notice's measured range: a 3-D robot's hooks (the URDF arm's
        # firmtool.robots.urdf_compiled, or a user's 3-D robot) take longer than the planar kernel
        self.kind = compile_kind(hooks)
        # -m puts the working folder first on sys.path: the folder holding this firmtool, so that the
        # process compiles (and caches) this one, not a source tree in the caller's folder
        home = Path(__file__).resolve().parents[2]
        self.process = subprocess.Popen([sys.executable, "-m", "firmtool.estimation.warmup", *hooks], cwd=home,
                                        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                        stderr=None if debug else subprocess.DEVNULL, text=True)
        self.design_ready = threading.Event()  # the design's functions are in the cache (or the process ended)
        self.reader = threading.Thread(target=self._read, name="firmtool-warmup", daemon=True)
        self.reader.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        try:
            for line in self.process.stdout:
                notifier = progress.compile_notifier()
                if line.strip() == COMPILING and notifier is not None:
                    notifier(self.kind)
                elif line.strip() == DESIGN:
                    self.design_ready.set()
        finally:
            self.design_ready.set()  # ended (or failed): nothing more to wait for

    def wait_design(self) -> None:
        if not self.design_ready.wait(WAIT_SECONDS):
            self.stop()

    def wait(self) -> None:
        try:
            self.process.wait(WAIT_SECONDS)
        except subprocess.TimeoutExpired:
            self.stop()
        self.reader.join(5.0)

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()


_warmup_problem: Problem | None = None


def _kernel_hooks(problem: Problem | None = None):
    """The compiled hooks whose kernel :func:`engine_functions` lists: ``problem``'s robot's if it has
    hooks a disk cache can key (:func:`firmtool.estimation.compiled.run.disk_cached`), else the
    warm-up scenario's (built once)."""
    global _warmup_problem
    hooks = None if problem is None or problem.robot is None else problem.robot.compiled_kinematics()
    if hooks is not None and disk_cached(hooks):
        return hooks
    if _warmup_problem is None:
        _warmup_problem = build_problem(load_scenario(WARMUP_SCENARIO))
    return _warmup_problem.robot.compiled_kinematics()


def engine_functions(problem: Problem | None = None) -> list:
    """The numba dispatchers whose compile :func:`start` takes off the critical path: the design's
    and the estimation workers' recursions, and the kernel of ``problem``'s robot (:func:`_kernel_hooks`)."""
    return [kernels.kernel(_kernel_hooks(problem)), recursions.filter_recursion, recursions.filter_recursions,
            recursions.spread_recursion, trajectories._rollout, trajectories._rollouts]


def compile_kind(hooks: list[str]) -> str:
    """``"3-D"`` when the hooks (:func:`hook_names`) are a 3-D robot's (the URDF arm's
    ``firmtool.robots.urdf_compiled``, or a module named 3d), else ``"planar"``: what the compile notice
    quotes a measured range for."""
    return "3-D" if any("urdf" in h or "3d" in h.lower() for h in hooks) else "planar"


def hook_names(problem: Problem | None) -> list[str]:
    """``NAME=MODULE:QUALNAME`` of each compiled hook of ``problem``'s robot (what the background process
    imports to compile its kernel); empty without hooks a disk cache can key."""
    hooks = None if problem is None or problem.robot is None else problem.robot.compiled_kinematics()
    if hooks is None or not disk_cached(hooks):
        return []
    python = {name: getattr(fn, "py_func", fn) for name, fn in hooks.functions().items() if fn is not None}
    return [f"{name}={py.__module__}:{py.__qualname__}" for name, py in python.items()]


def _resolve(spec: str) -> tuple[str, Callable]:
    """(hook name, compiled function) of a :func:`hook_names` entry."""
    name, _, where = spec.partition("=")
    module, _, qualname = where.partition(":")
    obj = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return name, obj


def _disk_cached(dispatcher) -> bool:
    """Whether numba's disk cache holds a current compile of ``dispatcher`` for this machine.

    The check numba makes when it loads (the index matches the source file's stamp and this
    numba's version; an entry for this CPU and the function's bytecode), through numba's cache
    internals: any surprise there counts as "not cached" (a background compile that finds
    everything cached costs one short process).
    """
    try:
        cache = dispatcher._cache  # numba's FunctionCache (firmtool.jit's, whose key covers the callees)
        index = cache._cache_file._load_index()
        codegen = dispatcher.targetctx.codegen()
        # an entry whose whole key (CPU, bytecode, callees' sources) is what this process would look up
        return any(cache._index_key(key[0], codegen) == key for key in index)
    except Exception:  # noqa: BLE001 - numba internals: unknown means compile
        return False


def engine_is_cached(problem: Problem | None = None) -> bool:
    """Whether every function of :func:`engine_functions` is in numba's disk cache."""
    try:
        return all(_disk_cached(d) for d in engine_functions(problem))
    except ImportError:  # pragma: no cover - no numba: the numpy engine runs, nothing to compile
        return True


def start(engine: str | None, problem: Problem | None = None) -> None:
    """Start compiling the engine in the background if ``engine`` is the compiled one and numba's
    cache does not hold it yet (and no compile is under way); with ``problem``, its robot's kernel too."""
    global _running
    if engine != "numba" or _running is not None or engine_is_cached(problem):
        return
    _running = _Warmup(hook_names(problem))
    atexit.register(_running.stop)  # an interrupted caller leaves no compiler behind


def wait() -> None:
    """Block until a background compile started by :func:`start` is done (no-op without one)."""
    global _running
    if _running is not None:
        _running.wait()
        _running = None


def wait_design() -> None:
    """Block until a background compile started by :func:`start` has compiled the design stage's
    functions (no-op without one). A design on several worker processes calls this first: each
    worker then loads them from the cache instead of compiling them again, all at once."""
    if _running is not None:
        _running.wait_design()


def stop() -> None:
    """Abandon a background compile (its caller needs no edge estimated after all)."""
    global _running
    if _running is not None:
        _running.stop()
        _running = None


def compile_engine(on_design: Callable[[], None] | None = None, hooks: tuple[str, ...] = ()) -> None:
    """Compile (or load from the disk cache) the engine's functions on the shipped ``smoke``
    scenario: its sampling and design (then ``on_design()``), a batch of edges as an estimation
    worker runs them (batched controllers, the kernel) with a few particles, one edge alone, and its
    controller's spread recursion (which execution reads); then the kernels of the other robots
    (:func:`compile_kernels`) and of ``hooks`` (:func:`hook_names`)."""
    scenario = load_scenario(WARMUP_SCENARIO)
    problem = build_problem(scenario)
    centers, kinds = roadmap_nodes(problem, np.random.default_rng(0))
    d = design(problem, centers, kinds)
    if on_design is not None:
        on_design()
    job = EstimationJob(scenario_text=scenario.text, scenario_path=str(scenario.path), design=d, particles=16,
                        chunk=16, seed=0, engine="numba", **job_extras(problem))
    remember_problem(job, problem)
    run_batch(job, list(range(min(2, d.edge_source.size))))
    source, target = int(d.edge_source[0]), int(d.edge_target[0])
    estimate_edge(problem, d, d.regions(problem), source, target, 16, 0, 16, "numba")
    local_controller(problem, d, source, target).spread  # noqa: B018 - runs the spread recursion
    compile_kernels(kernels.kernel(problem.robot.compiled_kinematics()), hooks)


def compile_kernels(reference: Callable, hooks: tuple[str, ...] = ()) -> None:
    """Compile (or load) the kernel of every planar robot with a scenario template and of ``hooks`` (a
    :func:`hook_names` list) for the argument types ``reference`` (a planar kernel that ran) was
    compiled for: the kernel's arguments have the same types whatever the robot. 3-D hooks (they
    name a ``sense`` hook) get the 3-D kernel's types from an edge of the URDF arm's template
    (:func:`_reference_3d`), and then the planar robots' kernels are left to their first use (a
    3-D build waits for this process: measured, the template robots' kernels made a cold arm7_shelf
    build's estimate stage wait ~40 s)."""
    targets = [dict(_resolve(spec) for spec in hooks)] if hooks else []
    three_d = bool(targets) and targets[0].get("sense") is not None
    for robot in () if three_d else template_robots():  # a 3-D build waits for its own kernel only
        try:
            problem = build_problem(parse_scenario(template("warmup", robot), "warmup.toml"))
        except Exception:  # noqa: BLE001 - a robot whose template does not build is not warmed: it compiles when used
            continue
        found = problem.robot.compiled_kinematics()
        # the planar kernels share the reference's argument types; a 3-D one compiles below
        if found is not None and disk_cached(found) and found.dim == 2:
            targets.append(found.functions())
    for functions in targets:
        three_d = functions.get("sense") is not None
        ref = _reference_3d() if three_d else reference
        if ref is None:  # no 3-D template here (the urdf extra): the kernel compiles when used
            continue
        compiled = kernels.kernel_for({name: functions.get(name) for name in HOOK_NAMES})
        for signature in ref.signatures:
            compiled.compile(signature)


def _reference_3d() -> Callable | None:
    """The 3-D kernel compiled on an edge of the URDF arm's template (its argument types are those of
    every 3-D problem), or None where the template does not build (the urdf extra missing)."""
    try:
        problem = build_problem(parse_scenario(template("warmup", "urdf"), "warmup.toml"))
        centers, kinds = roadmap_nodes(problem, np.random.default_rng(0))
        d = design(problem, centers, kinds)
    except Exception:  # noqa: BLE001 - no URDF support here: nothing to warm
        return None
    estimate_edge(problem, d, d.regions(problem), int(d.edge_source[0]), int(d.edge_target[0]), 16, 0, 16, "numba")
    return kernels.kernel(problem.robot.compiled_kinematics())


def _main() -> int:
    """``python -m firmtool.estimation.warmup [NAME=MODULE:QUALNAME ...]``: compile (with the kernel of
    those hooks), reporting on stdout when compiling starts and ends."""
    from numba.core import event  # numba's event API: only the warm-up process listens to compiles

    class Reporter(event.Listener):
        said = False

        def on_start(self, ev) -> None:
            if not self.said and ev.data["dispatcher"].py_func.__module__.startswith("firmtool"):
                self.said = True
                print(COMPILING, flush=True)

        def on_end(self, ev) -> None:
            pass

    event.register("numba:compile", Reporter())
    try:
        compile_engine(on_design=lambda: print(DESIGN, flush=True), hooks=tuple(sys.argv[1:]))
    except KeyboardInterrupt:
        return 130
    print(DONE, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(_main())
