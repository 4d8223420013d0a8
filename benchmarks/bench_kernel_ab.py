"""A/B of two versions of firmtool/kernels.py in one process: time inside the step kernel and in
``kernels.simulate`` per particle-step, on the same 60 arm edges x 200 particles (gains designed and
their recursion run beforehand), rounds alternating the versions; checks that every particle ends
the same way (outcome, stopping step) in every version.

    cp /old/firmtool/kernels.py /tmp/k_old.py; cp firmtool/kernels.py /tmp/k_new.py
    sed -i 's/cache=True/cache=False/' /tmp/k_old.py /tmp/k_new.py   # loaded under other names
    ROUNDS=15 python benchmarks/bench_kernel_ab.py /tmp/k_old.py /tmp/k_new.py

Kernel time is thread CPU time (less sensitive to other jobs on the cores than wall time).
"""
import sys, time, importlib.util, numpy as np, statistics
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
from _common import load, one_blas_thread
one_blas_thread()
from firmtool.design import local_controller
from firmtool.edges import initial_ensemble
problem, d, regions = load("arm")
edges = np.sort(np.random.default_rng(0).choice(d.edge_source.size, 60, replace=False))
lcs = [local_controller(problem, d, int(d.edge_source[e]), int(d.edge_target[e])) for e in edges]
for lc in lcs: lc.P
starts = [initial_ensemble(problem, d, int(d.edge_source[e]), 200, np.random.default_rng([1, e])) for e in edges]
mods = []
for i, path in enumerate(sys.argv[1:]):
    spec = importlib.util.spec_from_file_location(f"kvar{i}", path)
    m = importlib.util.module_from_spec(spec); spec.loader.exec_module(m)
    inner = m.kernel()
    acc = [0.0]
    def wrapped(*a, inner=inner, acc=acc):
        t = time.thread_time(); r = inner(*a); acc[0] += time.thread_time() - t; return r
    m._kernel = wrapped
    mods.append((path, m, acc))
def run(m, acc):
    acc[0] = 0.0; ps = 0; t0 = time.perf_counter()
    outs = []
    for e, lc, (x, xh) in zip(edges, lcs, starts):
        o = m.simulate(problem, lc, regions, x.copy(), xh.copy(), np.random.default_rng([2, e]))
        ps += int(o.steps.sum()); outs.append(o)
    return ps, acc[0], time.perf_counter() - t0, outs
for path, m, acc in mods: run(m, acc)
res = {p: ([], []) for p, _, _ in mods}
ref = None
for r in range(int(__import__("os").environ.get("ROUNDS", "7"))):
    for path, m, acc in (mods if r % 2 == 0 else mods[::-1]):
        ps, tk, tt, outs = run(m, acc)
        res[path][0].append(tk / ps * 1e9); res[path][1].append(tt / ps * 1e9)
        if ref is None: ref = outs
        else:
            same = sum(int(((a.outcome == b.outcome) & (a.steps == b.steps)).sum()) for a, b in zip(ref, outs))
            tot = sum(a.outcome.size for a in ref)
            if same != tot: print("DIFF", path, tot - same)
base = statistics.median(res[mods[0][0]][0])
for path, (k, t) in res.items():
    print(f"{path:40s} kernel {statistics.median(k):6.1f} ns/ps  simulate {statistics.median(t):6.1f} ns/ps  kernel ratio {statistics.median(k)/base:.3f}  ({ps} ps)")
