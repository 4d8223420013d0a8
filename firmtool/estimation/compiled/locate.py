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
"""

from __future__ import annotations

import numpy as np

from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba
from firmtool.roadmap.membership import first_coordinate_order

if numba is not None:
    njit = cached_njit(**KERNEL_OPTIONS)


def candidate_lists(regions, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per step, the candidate nodes sorted by their centre's first coordinate (CSR: ptr (T+1,), idx, key)
    from ``cand`` (T, N) bool (:meth:`~firmtool.roadmap.nodes.NodeRegions.covariance_candidates`): the numpy
    reference of :func:`segment_candidates`, which the driver calls (tests/test_batched_setup.py)."""
    order = first_coordinate_order(regions)
    sorted_cand = cand[:, order]
    counts = sorted_cand.sum(axis=1)
    ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    t, j = np.nonzero(sorted_cand)
    idx = order[j].astype(np.int64)
    return ptr, idx, np.ascontiguousarray(regions.centers[idx, 0])


_segment_cache: dict[int, tuple[object, tuple]] = {}


def segment_data(regions) -> tuple:
    """The constant arguments of :func:`segment_candidates`' compiled pass, once per regions object:
    ``(by_norm, rank, keep, key)``, the nodes in the order of their ``||P_j||``
    (:meth:`~firmtool.roadmap.nodes.NodeRegions.covariance_window`'s), with their position in the
    first-coordinate order, whether they are not excluded, and their centre's first coordinate."""
    hit = _segment_cache.get(id(regions))
    if hit is not None and hit[0] is regions:
        return hit[1]
    by_norm = np.ascontiguousarray(regions._by_norm, dtype=np.int64)
    order = first_coordinate_order(regions)
    rank = np.empty(regions.count, dtype=np.int64)
    rank[order] = np.arange(regions.count)
    keep = np.ones(regions.count, dtype=np.bool_) if regions.excluded is None else ~np.asarray(regions.excluded, bool)
    data = (by_norm, rank[by_norm], keep[by_norm], np.ascontiguousarray(regions.centers[by_norm, 0], dtype=float))
    if len(_segment_cache) > 8:
        _segment_cache.clear()
    _segment_cache[id(regions)] = (regions, data)
    return data


def segment_candidates(regions, P_steps: np.ndarray, lo_t: int, k_end: int,
                       cand_ptr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The kernel's candidates group ``(cand_ptr, cand_idx, cand_key)`` of steps ``lo_t`` to ``k_end - 1``
    from the filter covariances ``P_steps`` (step k's: ``P_steps[k + 1]``; ``cand_ptr`` (T + 1,) filled
    in place, 0 up to ``lo_t``, its last value after ``k_end``): what :func:`candidate_lists` of
    :meth:`~firmtool.roadmap.nodes.NodeRegions.covariance_candidates` gives, the covariance tests
    the same arithmetic (:meth:`~firmtool.roadmap.nodes.NodeRegions.covariance_window`), the rest
    (the (T, N) table, its columns in the first-coordinate order, the excluded nodes, the CSR lists)
    one compiled pass instead of ~10 numpy calls per segment of every edge (issue 55).
    Pinned against that pair on the shipped scenarios' edges (tests/test_batched_setup.py)."""
    by_norm, rank, keep, key = segment_data(regions)
    steps = P_steps[1 + lo_t:1 + k_end]
    if regions.perfect:  # every node passes
        a, b, passed = 0, regions.count, np.ones((steps.shape[0], regions.count), dtype=np.bool_)
    else:
        a, b, passed = regions.covariance_window(steps)
    return _segment_lists(passed, a, int(lo_t), int(k_end), cand_ptr, by_norm, rank, keep, key)


if numba is not None:
    @njit
    def _segment_lists(passed, a, lo_t, k_end, cand_ptr, by_norm, rank, keep, key):
        """:func:`segment_candidates`' pass: per step the passing nodes ``a + q`` (``passed[t, q]``) that are
        not excluded, sorted by ``rank``, as CSR lists."""
        T1 = cand_ptr.shape[0]
        W = passed.shape[1]
        total = 0
        for t in range(passed.shape[0]):
            for q in range(W):
                if passed[t, q] and keep[a + q]:
                    total += 1
        idx, keys = np.empty(total, dtype=np.int64), np.empty(total)
        got, got_rank = np.empty(W, dtype=np.int64), np.empty(W, dtype=np.int64)
        for k in range(min(lo_t + 1, T1)):
            cand_ptr[k] = 0
        total = 0
        for t in range(k_end - lo_t):
            cnt = 0
            for q in range(W):
                if passed[t, q] and keep[a + q]:
                    got[cnt], got_rank[cnt] = a + q, rank[a + q]
                    cnt += 1
            # in the first-coordinate order (insertion sort: a step has few candidates)
            for p in range(1, cnt):
                g, r = got[p], got_rank[p]
                s = p - 1
                while s >= 0 and got_rank[s] > r:
                    got[s + 1], got_rank[s + 1] = got[s], got_rank[s]
                    s -= 1
                got[s + 1], got_rank[s + 1] = g, r
            for p in range(cnt):
                idx[total + p] = by_norm[got[p]]
                keys[total + p] = key[got[p]]
            total += cnt
            cand_ptr[lo_t + t + 1] = total
        for k in range(k_end + 1, T1):
            cand_ptr[k] = total
        return cand_ptr, idx, keys
