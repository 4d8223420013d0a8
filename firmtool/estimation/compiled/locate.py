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

from firmtool.roadmap.membership import first_coordinate_order


def candidate_lists(regions, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per step, the candidate nodes sorted by their centre's first coordinate (CSR: ptr (T+1,), idx, key)
    from ``cand`` (T, N) bool (:meth:`~firmtool.roadmap.nodes.NodeRegions.covariance_candidates`)."""
    order = first_coordinate_order(regions)
    sorted_cand = cand[:, order]
    counts = sorted_cand.sum(axis=1)
    ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    t, j = np.nonzero(sorted_cand)
    idx = order[j].astype(np.int64)
    return ptr, idx, np.ascontiguousarray(regions.centers[idx, 0])
