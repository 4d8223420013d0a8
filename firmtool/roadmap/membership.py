"""Node membership compiled: :meth:`NodeRegions.locate <firmtool.roadmap.nodes.NodeRegions.locate>`'s
decision for one estimate, without its k-d tree.

The nodes whose covariance test passes (few, and sorted once per regions object by their centre's
first coordinate) are scanned inside a window of that coordinate outside of which the exact test
cannot pass; the nearest passing node in the outer metric is kept only if fewer than ``k = 8`` nodes
(all nodes, as in the tree query) are nearer in that metric. The same decision as the tree's, in
~5 us a call instead of ~30: the online policy's membership test
(:meth:`NodeRegions.locate_one <firmtool.roadmap.nodes.NodeRegions.locate_one>`) and the compiled
Monte Carlo kernel's (:mod:`firmtool.estimation.compiled`), which passes each step's candidates.
"""

from __future__ import annotations

import numpy as np

from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba

LOCATE_K = 8  # neighbours the k-d tree query of NodeRegions.locate considers

_order_cache: dict[int, tuple[object, np.ndarray]] = {}


def first_coordinate_order(regions) -> np.ndarray:
    """The nodes sorted by their centre's first coordinate (stable), once per regions object."""
    hit = _order_cache.get(id(regions))
    if hit is not None and hit[0] is regions:
        return hit[1]
    order = np.argsort(regions.centers[:, 0], kind="stable")
    if len(_order_cache) > 8:
        _order_cache.clear()
    _order_cache[id(regions)] = (regions, order)
    return order


_locate_cache: dict[int, tuple[object, tuple]] = {}


def locate_data(regions) -> tuple:
    """The membership test's constant arguments for ``regions`` (once per regions object): centres,
    scales, 1 / outer spread, radius squared, the window of the first coordinate outside which the
    exact test cannot pass, and the k of the tree query."""
    hit = _locate_cache.get(id(regions))
    if hit is not None and hit[0] is regions:
        return hit[1]
    outer = np.asarray(regions._outer, dtype=float)
    radius, n = float(regions.radius), regions.centers.shape[1]
    # the exact test needs |xhat_0 - c_0| < radius sqrt(n) scale_c0 <= radius sqrt(n) outer_0
    window = radius * np.sqrt(n) * float(outer[0]) * (1.0 + 1e-9)
    data = (np.ascontiguousarray(regions.centers, dtype=float), np.ascontiguousarray(regions.scale, dtype=float),
            1.0 / outer, radius * radius, window, min(LOCATE_K, regions.count))
    if len(_locate_cache) > 8:
        _locate_cache.clear()
    _locate_cache[id(regions)] = (regions, data)
    return data


def locate_one(regions, xhat: np.ndarray, candidates: np.ndarray) -> int:
    """:meth:`NodeRegions.locate` for one estimate ``xhat`` (n,) through the compiled membership test
    (the same decision without a tree query), or -1. ``candidates`` (N,) bool: the nodes whose
    covariance test passes."""
    order = first_coordinate_order(regions)
    idx = order[candidates[order]]
    data = locate_data(regions)
    return int(locate(np.ascontiguousarray(xhat, dtype=float), 0, idx.size, idx, np.ascontiguousarray(data[0][idx, 0]),
                      data))


if numba is not None:
    njit = cached_njit(**KERNEL_OPTIONS)

    @njit
    def locate(xh, lo_ptr, hi_ptr, cand_idx, cand_key, regions):
        """The node estimate ``xh`` (n,) lands in among the candidates ``cand_idx[lo_ptr:hi_ptr]``
        (sorted by ``cand_key``, their centres' first coordinate): the nearest (outer metric) passing
        candidate among the ``knn`` nearest nodes, or -1. ``regions``: :func:`locate_data`'s tuple
        ``(centers, scale, inv_outer, radius2, window, knn)``. Twin of
        :meth:`firmtool.roadmap.nodes.NodeRegions.locate` (without its k-d tree); pinned by
        tests/test_execute.py::test_executor_membership_is_the_node_regions_one (through
        :meth:`~firmtool.roadmap.nodes.NodeRegions.locate_one`) and the whole-step tests of
        tests/test_kernels.py."""
        centers, scale, inv_outer, radius2, window, knn = regions
        n = xh.shape[0]
        x0 = xh[0]
        # first candidate whose key >= x0 - window (binary search)
        a, b = lo_ptr, hi_ptr
        lo_key = x0 - window
        while a < b:
            mid = (a + b) // 2
            if cand_key[mid] < lo_key:
                a = mid + 1
            else:
                b = mid
        hi_key = x0 + window
        limit = radius2 * n
        best, best_d = -1, np.inf
        for q in range(a, hi_ptr):
            if cand_key[q] > hi_key:
                break
            c = cand_idx[q]
            s = 0.0
            for i in range(n):
                z = (xh[i] - centers[c, i]) / scale[c, i]
                s += z * z
                if s >= limit:
                    break
            if s / n < radius2:
                d = 0.0
                for i in range(n):
                    e = xh[i] * inv_outer[i] - centers[c, i] * inv_outer[i]
                    d += e * e
                if d < best_d:
                    best, best_d = c, d
        if best < 0:
            return -1
        nearer = 0
        for j in range(centers.shape[0]):
            d = 0.0
            for i in range(n):
                e = xh[i] * inv_outer[i] - centers[j, i] * inv_outer[i]
                d += e * e
                if d >= best_d:
                    break
            if d < best_d:
                nearer += 1
                if nearer >= knn:
                    return -1
        return best
