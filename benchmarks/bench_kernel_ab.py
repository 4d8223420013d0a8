"""A/B of versions of the compiled Monte Carlo engine in one process: does every particle end identically,
and how long does the step kernel take per particle-step?

    git show 8f15dfb:firmtool/estimation/compiled.py > /tmp/k_house.py  # the single-file engine before the split
    ROUNDS=15 python benchmarks/bench_kernel_ab.py /tmp/k_house.py firmtool/estimation/compiled

A version is either a single-file engine of before the split (``compiled.py``, with the robot kinds
``planar_point`` and ``planar_chain``), copied into a fresh temporary directory and loaded as its own
module (so that it compiles its kernel once, here, with no disk cache that could be stale), or this
checkout's package ``firmtool/estimation/compiled`` (a directory), imported as installed (its kernels
compiled per robot's hooks, or loaded from numba's disk cache, whose key covers every callee). A
single-file version reads a robot's hooks as the kind they are (a point's or a chain's: the shipped
robots). Both use this checkout's package for everything else. Cases: the shipped point and arm
scenarios (``point_lightdark``, ``arm8_lightdark``), each with its own imperfect measurements and with
``kind = "perfect"``, ``--edges`` of the roadmap's edges x ``--particles`` particles (gains designed and
their filter recursion run beforehand).

Identity: per case and noise mode (the kernel's own noise, as in builds, and numpy's stream,
``numpy_noise=True``), every version runs every edge from the same start and generator seed, and
each particle's outcome, stopping step and cost terms and the final true states and estimates are
compared with the first version's, bit for bit.

Speed: rounds alternate the versions' order; per round and version, the kernel's thread CPU time
(less sensitive to other jobs on the cores than wall time) and ``simulate``'s wall time per
particle-step. Reported: medians with the range over rounds, and the median and range of the
per-round ratio to the first version (each ratio from the same round, i.e. the same machine state).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import re
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import SCENARIOS, one_blas_thread  # noqa: E402

CASES = [(name, kind) for name in ("arm", "point") for kind in ("imperfect", "perfect")]


def _case(name: str, kind: str, edges_count: int, particles: int, tmp: Path) -> dict:
    """The designed roadmap of one scenario (perfect: its [measurement] replaced), edges, controllers, starts."""
    from firmtool.estimation.edges import initial_ensemble
    from firmtool.io.roadmap_file import RoadmapFile
    from firmtool.pipeline import design_of, design_stage, problem_of, sample_stage
    from firmtool.roadmap.design import local_controller

    text = SCENARIOS[name].read_text()
    if kind == "perfect":
        text = re.sub(r"(?ms)^\[measurement\]\n.*?(?=^\[)", '[measurement]\nkind = "perfect"\n\n', text)
    src = tmp / f"{name}_{kind}.toml"
    src.write_text(text)
    out = tmp / f"{name}_{kind}.h5"
    sample_stage(src, out)
    design_stage(out)
    rm = RoadmapFile(out)
    problem, d = problem_of(rm), design_of(rm)
    assert problem.perfect == (kind == "perfect")
    regions = d.regions(problem)
    rng = np.random.default_rng(0)
    edges = np.sort(rng.choice(d.edge_source.size, min(edges_count, d.edge_source.size), replace=False))
    lcs = [local_controller(problem, d, int(d.edge_source[e]), int(d.edge_target[e])) for e in edges]
    for lc in lcs:
        lc.P  # the filter recursion run outside the timing
    starts = [initial_ensemble(problem, d, int(d.edge_source[e]), particles, np.random.default_rng([1, e]))
              for e in edges]
    return dict(name=f"{name} {kind}", problem=problem, regions=regions, edges=edges, lcs=lcs, starts=starts)


def _legacy_kinematics(hooks) -> SimpleNamespace:
    """What a single-file engine of before the split reads of a robot: its kinematics kind."""
    if hooks.n_points == 1:
        return SimpleNamespace(kind="planar_point", link_lengths=np.zeros(0), self_collision=False)
    return SimpleNamespace(kind="planar_chain", link_lengths=hooks.params, self_collision=hooks.self_collision)


def _load(path: str, i: int, tmp: Path):
    """The engine at ``path`` (a single file: module ``kvar{i}`` from a copy; a directory: this checkout's
    package) with its kernel timed (thread CPU time) into ``acc[0]``."""
    acc = [0.0]

    def timed(inner):
        def wrapped(*a, inner=inner, acc=acc):
            t = time.thread_time()
            r = inner(*a)
            acc[0] += time.thread_time() - t
            return r
        return wrapped

    if Path(path).is_dir():
        m = importlib.import_module("firmtool.estimation.compiled")
        driver = importlib.import_module("firmtool.estimation.compiled.driver")
        real, wrappers = driver.kernel, {}

        def kernel(hooks):
            inner = real(hooks)
            if inner not in wrappers:
                wrappers[inner] = timed(inner)
            return wrappers[inner]

        driver.kernel = kernel
        return m, acc
    copy = tmp / f"kvar{i}" / "kernels.py"
    copy.parent.mkdir()
    shutil.copy(path, copy)
    spec = importlib.util.spec_from_file_location(f"kvar{i}", copy)
    m = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(m)
    m._kernel = timed(m.kernel())
    legacy_init = m._ProblemData.__init__

    def init(self, problem, legacy_init=legacy_init):  # the robot's hooks as the old engine's kinematics kind
        robot = problem.robot
        kinematics = _legacy_kinematics(robot.compiled_kinematics())
        robot.compiled_kinematics = lambda: kinematics
        try:
            legacy_init(self, problem)
        finally:
            del robot.compiled_kinematics

    m._ProblemData.__init__ = init
    return m, acc


def _run(m, acc, case: dict, numpy_noise: bool = False):
    acc[0] = 0.0
    ps, outs, t0 = 0, [], time.perf_counter()
    for e, lc, (x, xh) in zip(case["edges"], case["lcs"], case["starts"]):
        x, xh = x.copy(), xh.copy()
        o = m.simulate(case["problem"], lc, case["regions"], x, xh, np.random.default_rng([2, e]), numpy_noise)
        ps += int(o.steps.sum())
        outs.append((o, x, xh))
    return ps, acc[0], time.perf_counter() - t0, outs


def _differences(ref, outs) -> tuple[int, int]:
    """(particles compared, particles whose outcome, steps, cost terms, final state or estimate differ)."""
    total = bad = 0
    for (a, xa, ha), (b, xb, hb) in zip(ref, outs):
        bits = lambda u, v: (u.view(np.int64) == v.view(np.int64)).all(axis=1)  # noqa: E731 (bit for bit)
        same = (a.outcome == b.outcome) & (a.steps == b.steps) & bits(a.terms, b.terms) & bits(xa, xb) & bits(ha, hb)
        total += same.size
        bad += int((~same).sum())
    return total, bad


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("kernels", nargs="+", help="engine files or the package directory; the first is the reference")
    ap.add_argument("--rounds", type=int, default=int(os.environ.get("ROUNDS", "7")))
    ap.add_argument("--edges", type=int, default=60)
    ap.add_argument("--particles", type=int, default=200)
    ap.add_argument("--cases", nargs="+", default=[f"{n}-{k}" for n, k in CASES],
                    choices=[f"{n}-{k}" for n, k in CASES])
    args = ap.parse_args(argv)
    one_blas_thread()
    tmp = Path(tempfile.mkdtemp(prefix="firmtool-kernel-ab-"))
    try:
        cases = [_case(*c.split("-"), args.edges, args.particles, tmp) for c in args.cases]
        mods = [(path, *_load(path, i, tmp)) for i, path in enumerate(args.kernels)]
        print(f"versions: {', '.join(args.kernels)}; load average before {os.getloadavg()[0]:.2f}")
        identical = True
        for case in cases:  # identity (also the compile / warm-up run)
            for numpy_noise in (False, True):
                runs = [_run(m, acc, case, numpy_noise)[3] for _, m, acc in mods]
                for (path, _, _), outs in zip(mods[1:], runs[1:]):
                    total, bad = _differences(runs[0], outs)
                    identical &= bad == 0
                    print(f"{case['name']:15s} {'numpy noise' if numpy_noise else 'kernel noise':12s} {path}: "
                          f"{total - bad}/{total} particles identical (outcome, steps, cost terms, x, xhat)")
        for case in cases:
            kern = {p: [] for p, _, _ in mods}
            sim = {p: [] for p, _, _ in mods}
            for r in range(args.rounds):
                for path, m, acc in (mods if r % 2 == 0 else mods[::-1]):
                    ps, tk, tt, _ = _run(m, acc, case)
                    kern[path].append(tk / ps * 1e9)
                    sim[path].append(tt / ps * 1e9)
            base = args.kernels[0]
            print(f"{case['name']} ({case['edges'].size} edges x {args.particles} particles, {ps} particle-steps, "
                  f"{args.rounds} rounds), ns per particle-step, median [min, max]:")
            for path in args.kernels:
                kr = [a / b for a, b in zip(kern[path], kern[base])]
                sr = [a / b for a, b in zip(sim[path], sim[base])]
                print(f"  {path:32s} kernel {statistics.median(kern[path]):6.1f} [{min(kern[path]):6.1f}, "
                      f"{max(kern[path]):6.1f}]  simulate {statistics.median(sim[path]):6.1f} [{min(sim[path]):6.1f}, "
                      f"{max(sim[path]):6.1f}]  ratio kernel {statistics.median(kr):.3f} [{min(kr):.3f}, {max(kr):.3f}]"
                      f"  simulate {statistics.median(sr):.3f} [{min(sr):.3f}, {max(sr):.3f}]")
        print(f"load average after {os.getloadavg()[0]:.2f}; every particle identical: {identical}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
