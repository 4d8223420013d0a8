"""Is the compiled engine of this tree bit-identical to another tree's? Dump, then compare.

    git archive MAIN | tar -x -C /tmp/base
    PYTHONPATH=/tmp/base python benchmarks/engine_identity.py dump /tmp/main.npz
    python benchmarks/engine_identity.py dump /tmp/new.npz
    python benchmarks/engine_identity.py compare /tmp/main.npz /tmp/new.npz

``dump`` runs the compiled engine on 30 fixed edges of the shipped arm and point scenarios x 200
particles, with the kernel's own noise and with numpy's stream, and saves every particle's outcome,
stopping step, cost terms, final true state and estimate, and the swept region. ``compare`` says
which arrays differ bit for bit (issue 39 used it where tests/test_tables_unchanged.py cannot tell:
on a machine whose design stage already differs from the recorded digests).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def dump(path: str, edges_count: int = 30, particles: int = 200) -> None:
    from _common import load, one_blas_thread
    one_blas_thread()
    from firmtool.estimation.edges import initial_ensemble, simulate
    from firmtool.roadmap.design import local_controller
    out = {}
    for name in ("arm", "point"):
        problem, d, regions = load(name)
        edges = np.sort(np.random.default_rng(0).choice(d.edge_source.size, edges_count, replace=False))
        for e in edges:
            lc = local_controller(problem, d, int(d.edge_source[e]), int(d.edge_target[e]))
            for numpy_noise in (False, True):
                x, xh = initial_ensemble(problem, d, int(d.edge_source[e]), particles, np.random.default_rng([1, e]))
                o = simulate(problem, lc, regions, x, xh, np.random.default_rng([2, e]), "numba", numpy_noise)
                key = f"{name}_{e}_{int(numpy_noise)}"
                for part, value in (("outcome", o.outcome), ("steps", o.steps), ("terms", o.terms), ("x", x),
                                    ("xhat", xh), ("swept", o.swept)):
                    out[f"{key}_{part}"] = value
    np.savez(path, **out)


def compare(a_path: str, b_path: str) -> int:
    a, b = np.load(a_path), np.load(b_path)
    bad = [k for k in a.files if k not in b.files or a[k].tobytes() != b[k].tobytes()]
    print(f"{len(a.files)} arrays; {len(bad)} differ bit for bit{': ' + ', '.join(bad[:10]) if bad else ''}")
    return 1 if bad else 0


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "dump":
        dump(sys.argv[2])
    elif len(sys.argv) == 4 and sys.argv[1] == "compare":
        sys.exit(compare(sys.argv[2], sys.argv[3]))
    else:
        sys.exit(__doc__)
