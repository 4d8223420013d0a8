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

It compiles in the order a build needs: the design's functions first (the nominals' rollouts), then
reports ``design`` so that a build's design stage, which runs on several worker processes, waits for
that instead of letting every worker compile the same functions at once (:func:`wait_design`); then
the estimation workers' path (the batched filter recursions, the kernel) on a batch of edges.

The background process reports on its stdout; :func:`set_notifier` registers what to call when it
starts compiling (the CLI prints one line on stderr). The library itself never prints.
"""

from __future__ import annotations

import atexit
import os
import subprocess
import sys
import threading
from pathlib import Path
from typing import Callable

from firmtool.control import recursions, trajectories
from firmtool.estimation import compiled as kernels
from firmtool.estimation.edges import estimate_edge
from firmtool.estimation.executors import EstimationJob, job_extras, remember_problem, run_batch
from firmtool.problem import build_problem
from firmtool.roadmap.design import design, local_controller
from firmtool.roadmap.nodes import roadmap_nodes
from firmtool.scenario import load_scenario

# The background process's reports (one line each on its stdout).
COMPILING, DESIGN, DONE = "compiling", "design", "done"
# A compile that takes longer is abandoned (the workers then compile for themselves): a guard
# against a stuck process, far above the ~10-60 s a cold compile takes on a loaded 2-core machine.
WAIT_SECONDS = 900.0
WARMUP_SCENARIO = "smoke"  # a shipped scenario the compiled engine supports; tiny

_notifier: Callable[[], None] | None = None
_running: "_Warmup | None" = None


def set_notifier(callback: Callable[[], None] | None) -> None:
    """Call ``callback()`` (once, from a helper thread) when a background compile starts compiling."""
    global _notifier
    _notifier = callback


class _Warmup:
    """The background compile process and the thread that reads its reports."""

    def __init__(self) -> None:
        debug = bool(os.environ.get("FIRMTOOL_DEBUG"))
        # -m puts the working folder first on sys.path: the folder holding this firmtool, so that the
        # process compiles (and caches) this one, not a source tree in the caller's folder
        home = Path(__file__).resolve().parents[1]
        self.process = subprocess.Popen([sys.executable, "-m", "firmtool.estimation.warmup"], cwd=home,
                                        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                        stderr=None if debug else subprocess.DEVNULL, text=True)
        self.design_ready = threading.Event()  # the design's functions are in the cache (or the process ended)
        self.reader = threading.Thread(target=self._read, name="firmtool-warmup", daemon=True)
        self.reader.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        try:
            for line in self.process.stdout:
                if line.strip() == COMPILING and _notifier is not None:
                    _notifier()
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


def engine_functions() -> list:
    """The numba dispatchers whose compile :func:`start` takes off the critical path."""
    return [kernels.run, recursions.filter_recursion, recursions.filter_recursions,
            recursions.spread_recursion, trajectories._rollout, trajectories._rollouts]


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


def engine_is_cached() -> bool:
    """Whether every function of :func:`engine_functions` is in numba's disk cache."""
    try:
        return all(_disk_cached(d) for d in engine_functions())
    except ImportError:  # pragma: no cover - no numba: the numpy engine runs, nothing to compile
        return True


def start(engine: str | None) -> None:
    """Start compiling the engine in the background if ``engine`` is the compiled one and numba's
    cache does not hold it yet (and no compile is under way)."""
    global _running
    if engine != "numba" or _running is not None or engine_is_cached():
        return
    _running = _Warmup()
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


def compile_engine(on_design: Callable[[], None] | None = None) -> None:
    """Compile (or load from the disk cache) the engine's functions on the shipped ``smoke``
    scenario: its sampling and design (then ``on_design()``), a batch of edges as an estimation
    worker runs them (batched controllers, the kernel) with a few particles, one edge alone, and its
    controller's spread recursion (which execution reads)."""
    import numpy as np

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


def _main() -> int:
    """``python -m firmtool.estimation.warmup``: compile, reporting on stdout when compiling starts and ends."""
    from numba.core import event

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
        compile_engine(on_design=lambda: print(DESIGN, flush=True))
    except KeyboardInterrupt:
        return 130
    print(DONE, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(_main())
