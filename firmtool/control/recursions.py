"""The forward recursions of a local controller, compiled: the Kalman filter's covariances and gains
along the controller, and the closed-loop spread of the decision state.

Both run in steps (``[k0, k1)``) so that :class:`firmtool.control.local.LocalController` computes
them lazily, as far as a caller reads; running ``[0, a)`` then ``[a, b)`` does exactly what
``[0, b)`` does. The per-step products are :mod:`firmtool.control.linalg`'s loops (this loop of
small products dominated the time per edge in Python).
"""

from __future__ import annotations

import numpy as np

from firmtool.control.linalg import cholesky_solve, mat_mul, sandwich, symmetric_part, transpose
from firmtool.errors import NumericalError
from firmtool.jit import cached_njit

# compiled, cached on disk by a key that covers the compiled functions each calls (firmtool.jit)
njit = cached_njit()


@njit
def filter_recursion(A_steps, H_steps, index, variances, Qd, L, P, innovation, k0, k1):
    """Steps ``k0 <= k < k1`` of the Kalman covariance recursion, from ``P[k0]``.

    Step ``k`` uses ``A_steps[index[k]]`` and ``H_steps[index[k]]`` and R = diag(``variances[k]``);
    fills ``L[k]`` (n, nz), ``P[k + 1]`` and ``innovation[k]`` (nz, nz) in place. Running ``[0, a)``
    then ``[a, b)`` does exactly what ``[0, b)`` does.

    The products are plain loops over preallocated work arrays (no temporaries per step) that skip
    the models' zeros. The Joseph form ``(I - L H) P- (I - L H)' + L R L'`` is evaluated as its
    expansion ``P- - G - G' + L S L'`` with ``G = L H P-`` and ``S = H P- H' + R`` (equal for any
    gain, but as a sum it lacks the product form's guarantee of a positive semi-definite result: P is
    symmetrised, and its negative eigenvalues are of the rounding size the product form gave, ~1e-16
    relative). ``S`` is inverted through its Cholesky factor; an ``S`` that is not positive definite
    (cannot happen with R > 0 but for rounding) raises NumericalError.
    """
    n = Qd.shape[0]
    nz = H_steps.shape[1]
    X1, X2, X3, prior = np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    G, LSL = np.empty((n, n)), np.empty((n, n))
    HP, Lt = np.empty((nz, n)), np.empty((nz, n))
    S, Ssym, C = np.empty((nz, nz)), np.empty((nz, nz)), np.empty((nz, nz))
    Lk, LS, HPt = np.empty((n, nz)), np.empty((n, nz)), np.empty((n, nz))
    for k in range(k0, k1):
        j = index[k]
        A, H = A_steps[j], H_steps[j]
        sandwich(A, P[k], Qd, X1, X3, X2, prior)  # P- = A P A' + Q
        mat_mul(H, prior, HP)  # S = H P- H' + R
        transpose(HP, HPt)
        mat_mul(H, HPt, S)
        for i in range(nz):
            S[i, i] += variances[k, i]
        symmetric_part(S, Ssym)
        innovation[k] = Ssym
        if not cholesky_solve(Ssym, HP, C, Lt):  # L' = S^-1 H P-
            raise NumericalError("Kalman filter: the innovation covariance H P- H' + R is not positive definite")
        transpose(Lt, Lk)
        mat_mul(Lk, HP, G)
        mat_mul(Lk, Ssym, LS)
        mat_mul(LS, Lt, LSL)
        for a in range(n):
            for b in range(n):
                X1[a, b] = prior[a, b] - G[a, b] - G[b, a] + LSL[a, b]
        symmetric_part(X1, P[k + 1])
        L[k] = Lk


@njit
def spread_recursion(A_steps, B_steps, index, K, Qd, perfect, L, innovation, spread, Sigma, k0, k1):
    """Steps ``k0 <= k < k1`` of the closed-loop spread of the decision state: ``Sigma_{k+1} = Acl
    Sigma Acl' + D`` with ``Acl = A - B K[k]`` and ``D = Qd`` (perfect measurements) or the
    innovations through the gain, ``L[k] S_k L[k]'`` (imperfect; ``L`` and ``innovation`` must be
    computed through step k). ``Sigma`` (n, n) is advanced in place; fills ``spread[k + 1]``."""
    n = Qd.shape[0]
    nz = L.shape[2]
    X1, X2, X3, D = np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    Acl, BK = np.empty((n, n)), np.empty((n, n))
    LS, Lt = np.empty((n, nz)), np.empty((nz, n))
    for k in range(k0, k1):
        j = index[k]
        A = A_steps[j]
        if perfect:
            for a in range(n):
                for b in range(n):
                    D[a, b] = Qd[a, b]
        else:
            transpose(L[k], Lt)
            mat_mul(L[k], innovation[k], LS)
            mat_mul(LS, Lt, D)
        mat_mul(B_steps[j], K[k], BK)  # Acl = A - B K
        for a in range(n):
            for b in range(n):
                Acl[a, b] = A[a, b] - BK[a, b]
        sandwich(Acl, Sigma, D, X1, X3, X2, Sigma)
        for i in range(n):
            spread[k + 1, i] = np.sqrt(max(Sigma[i, i], 0.0))


@njit
def filter_recursions(A_steps, H_steps, index, variances, Qd, L, P, innovation, start, k_end):
    """:func:`filter_recursion` of a batch of edges, each from its step 0 to ``k_end[e]``.

    Edge ``e`` owns rows ``start[e]:start[e + 1]`` of ``variances``, ``L`` and ``innovation`` and rows
    ``start[e] + e : start[e + 1] + e + 1`` of ``P`` (one more: ``P[0]`` is its start covariance); the
    models' matrices and the step index are shared. Each edge runs exactly the single-edge recursion."""
    for e in range(k_end.shape[0]):
        a, b = start[e], start[e + 1]
        filter_recursion(A_steps, H_steps, index, variances[a:b], Qd, L[a:b], P[a + e:b + e + 1],
                          innovation[a:b], 0, k_end[e])
