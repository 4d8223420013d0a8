"""An edge estimate's integer summaries in one compiled pass (issue 55 item 3): the step histogram, the
outcome counts and the particle-steps, which numpy computed in ~10 calls per edge (two sorts among
them), ~40 us of a 200-particle edge's ~1 ms on the point robot.

:func:`outcome_histogram` gives exactly :func:`firmtool.estimation.edges.step_histogram`'s table (the same
int64 key per (outcome, steps) pair, sorted), ``np.unique(outcome, return_counts=True)`` and
``steps.sum()``: integers, so any order of the work gives the same values
(tests/test_batched_setup.py pins them against numpy).
"""

from __future__ import annotations

import numpy as np

from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba

STEPS_SPAN = 1 << 32  # a pair's key: outcome * span + steps, for 0 <= steps < span (edges.step_histogram's)
outcome_histogram = None  # compiled below where numba is installed

if numba is not None:
    njit = cached_njit(**KERNEL_OPTIONS)

    @njit
    def outcome_histogram(outcome, steps):
        """``(ok, histogram (3, H), values (K,), counts (K,), total)`` of particles' ``outcome`` and ``steps``
        (M,) int64: the (outcome, steps) pairs with their particle counts sorted by outcome then steps,
        the distinct outcomes with their counts, the steps summed. ``ok`` False (and the rest empty) where
        a step count is outside ``[0, STEPS_SPAN)``: then numpy's path computes them."""
        M = outcome.shape[0]
        keys = np.empty(M, dtype=np.int64)
        total = 0
        for i in range(M):
            s = steps[i]
            if s < 0 or s >= STEPS_SPAN:
                return False, np.zeros((3, 0), dtype=np.int64), np.zeros(0, dtype=np.int64), \
                    np.zeros(0, dtype=np.int64), 0
            keys[i] = outcome[i] * STEPS_SPAN + s
            total += s
        keys.sort()
        H, K = 0, 0
        for i in range(M):
            if i == 0 or keys[i] != keys[i - 1]:
                H += 1
                if i == 0 or (keys[i] >> 32) != (keys[i - 1] >> 32):
                    K += 1
        hist = np.zeros((3, H), dtype=np.int64)
        values, counts = np.zeros(K, dtype=np.int64), np.zeros(K, dtype=np.int64)
        h, k = -1, -1
        for i in range(M):
            code = keys[i] >> 32
            if i == 0 or keys[i] != keys[i - 1]:
                h += 1
                hist[0, h] = code
                hist[1, h] = keys[i] & (STEPS_SPAN - 1)
                if i == 0 or code != (keys[i - 1] >> 32):
                    k += 1
                    values[k] = code
            hist[2, h] += 1
            counts[k] += 1
        return True, hist, values, counts, total
