"""Issue 55, stream 2: the cost of a standard normal in the compiled kernel, per stream and per part.

    python benchmarks/bench_stream2.py [--particles 1000] [--steps 1000] [--repeat 5]

Loops over ``--particles`` lanes for ``--steps`` steps, compiled with the kernel's options
(``firmtool.jit.KERNEL_OPTIONS``, as the kernel inlines them), each part alone: Philox4x64-10 words
(stream 2's generator, per 64-bit word), Box-Muller from two words (per normal: the branch-free log, the
square root, the branch-free sincos), the log alone and the sincos alone (per call), stream 2's whole draw
of a step's normals (``rng.draw_philox``, 24 normals per particle as the arm's step draws; per normal), and
stream 1's xoshiro256++ ziggurat (``rng.fill_normals``, per normal, scalar). Best of ``--repeat`` runs of the
thread's CPU time (``time.thread_time``). Prints ``RESULT`` tokens for benchmarks/compare.py.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from firmtool.estimation.compiled import rng
from firmtool.jit import KERNEL_OPTIONS, numba
from firmtool.models.angles import sincos

njit = numba.njit(**KERNEL_OPTIONS)


@njit
def _philox(k0, k1, steps, na, Z):
    for k in range(steps):
        ck = np.uint64(k)
        for a in range(na):
            w0, w1, w2, w3 = rng.philox4x64(np.uint64(a), ck, np.uint64(0), np.uint64(0), k0, k1)
            Z[0, a], Z[1, a], Z[2, a], Z[3, a] = w0, w1, w2, w3


@njit
def _box_muller(steps, na, Z, Y):
    for _ in range(steps):
        for a in range(na):
            Y[0, a], Y[1, a] = rng.box_muller(Z[0, a], Z[1, a])


@njit
def _log(steps, na, X, Y):
    for _ in range(steps):
        for a in range(na):
            Y[0, a] = rng._log(X[0, a])


@njit
def _sincos(steps, na, X, Y):
    for _ in range(steps):
        for a in range(na):
            Y[0, a], Y[1, a] = sincos(X[0, a])


@njit
def _draw(key, steps, alive, W, Z, d):
    for k in range(steps):
        rng.draw_philox(key, k, alive, W, Z, d, alive.shape[0])


@njit
def _ziggurat(state, steps, na, W, d):
    for _ in range(steps):
        rng.draw_noise(state, W, d, na)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--particles", type=int, default=1000)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    na, steps, d = args.particles, args.steps, 24
    Z = np.empty((4, na), dtype=np.uint64)
    _philox(np.uint64(1), np.uint64(2), 1, na, Z)
    Y, X, W = np.empty((4, na)), np.random.default_rng(0).random((4, na)), np.empty((d, na))
    alive = np.arange(na, dtype=np.int64)
    key, state = np.array([1, 2], dtype=np.uint64), np.array([1, 2, 3, 4], dtype=np.uint64)
    cases = [("philox_word", _philox, (np.uint64(1), np.uint64(2), steps, na, Z), 4 * steps * na),
             ("box_muller_normal", _box_muller, (steps, na, Z, Y), 2 * steps * na),
             ("log_call", _log, (steps, na, X, Y), steps * na),
             ("sincos_call", _sincos, (steps, na, X, Y), steps * na),
             ("stream2_normal", _draw, (key, steps, alive, W, np.empty((4, na)), d), d * steps * na),
             ("stream1_normal", _ziggurat, (state, steps, na, W, d), d * steps * na)]
    out = {}
    for name, fn, fargs, count in cases:
        fn(*fargs)  # compiled, untimed
        best = np.inf
        for _ in range(args.repeat):
            t0 = time.thread_time()
            fn(*fargs)
            best = min(best, time.thread_time() - t0)
        out[name] = best / count * 1e9
    print("RESULT " + " ".join(f"{k}_ns={v:.3f}" for k, v in out.items()))
    return out


if __name__ == "__main__":
    main()
