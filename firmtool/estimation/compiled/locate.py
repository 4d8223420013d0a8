"""Node membership in the compiled kernel: each step's candidate nodes, and the membership test's data.

:meth:`firmtool.roadmap.nodes.NodeRegions.locate` is reproduced exactly without its k-d tree by the
roadmap's compiled test (:func:`firmtool.roadmap.membership.locate`), which the kernel calls per
particle from the stabiliser phase on. The candidates of a step are the nodes whose covariance test
passes at that step's filter covariance (few), sorted once per regions object by their centre's
first coordinate, so that the test scans only a window of that coordinate.

The kernel's groups: candidates ``(cand_ptr, cand_idx, cand_key)``, per step the candidate nodes
(CSR: step k's are ``cand_idx[cand_ptr[k]:cand_ptr[k + 1]]``, their keys the centres' first
coordinate); regions ``(centers, scale, inv_outer, radius2, window, knn)``
(:func:`firmtool.roadmap.membership.locate_data`).

The lists are built per segment of every edge, so in one compiled pass (:func:`candidate_lists`: 39
-> 5 us per arm segment, issue 39; the same integers).
"""

from __future__ import annotations

import numpy as np

from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba
from firmtool.roadmap.membership import first_coordinate_order


def candidate_lists(regions, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per step, the candidate nodes sorted by their centre's first coordinate (CSR: ptr (T+1,), idx, key)
    from ``cand`` (T, N) bool (:meth:`~firmtool.roadmap.nodes.NodeRegions.covariance_candidates`).

    One compiled pass (:func:`_csr`) instead of a fancy index, a sum, a cumsum and a nonzero: ~40 us of
    numpy calls per segment of every edge (issue 39); the same integers and keys."""
    order = first_coordinate_order(regions)
    return _csr(np.ascontiguousarray(cand), order.astype(np.int64, copy=False), _first_coordinates(regions))


_keys_cache: dict[int, tuple[object, np.ndarray]] = {}


def _first_coordinates(regions) -> np.ndarray:
    """The centres' first coordinates (N,), contiguous, once per regions object."""
    hit = _keys_cache.get(id(regions))
    if hit is not None and hit[0] is regions:
        return hit[1]
    keys = np.ascontiguousarray(regions.centers[:, 0], dtype=float)
    if len(_keys_cache) > 8:
        _keys_cache.clear()
    _keys_cache[id(regions)] = (regions, keys)
    return keys


def _csr_py(cand, order, keys):
    """The CSR lists of :func:`candidate_lists`: step t's candidates ``order[j]`` for the ``j`` (in order)
    where ``cand[t, order[j]]``."""
    T, N = cand.shape
    ptr = np.zeros(T + 1, dtype=np.int64)
    for t in range(T):
        c = 0
        for j in range(N):
            if cand[t, order[j]]:
                c += 1
        ptr[t + 1] = ptr[t] + c
    idx = np.empty(ptr[T], dtype=np.int64)
    key = np.empty(ptr[T])
    q = 0
    for t in range(T):
        for j in range(N):
            o = order[j]
            if cand[t, o]:
                idx[q] = o
                key[q] = keys[o]
                q += 1
    return ptr, idx, key


_csr = cached_njit(**KERNEL_OPTIONS)(_csr_py) if numba is not None else _csr_py
