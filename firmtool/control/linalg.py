"""Small dense matrix products as compiled plain loops: the arithmetic of the local controllers'
forward recursions (:mod:`firmtool.control.recursions`) and of the Monte Carlo kernel
(:mod:`firmtool.estimation.compiled`, which calls :func:`mat_rows` with the particles as columns).

Plain loops over preallocated arrays, no temporaries: the recursions run thousands of products of
n <= 16 matrices per edge, where a numpy call's overhead exceeds its arithmetic. Each function fixes
the order in which every entry's terms are added, so that its results are the same bit for bit
wherever it is called (tests/test_controllers.py pins :func:`cholesky_solve` against the textbook loop).
"""

from __future__ import annotations

import numpy as np

from firmtool.jit import cached_njit

# compiled, cached on disk by a key that covers the compiled functions each calls (firmtool.jit)
njit = cached_njit()


@njit
def mat_rows(A, B, out, n_out, nc):
    """``out[:n_out, :nc] = A[:n_out] @ B[:, :nc]`` as row updates (``out[i] += A[i, l] B[l]``: the inner
    loop runs along a row of B, so it vectorises), skipping exact zeros of ``A`` (the models' A, B, H
    are mostly zeros). Per output entry the terms are added in column order: the dense row
    product's value. Shared with the Monte Carlo kernel, where B's columns are the particles."""
    for i in range(n_out):
        for c in range(nc):
            out[i, c] = 0.0
        for l in range(A.shape[1]):
            a = A[i, l]
            if a != 0.0:
                for c in range(nc):
                    out[i, c] += a * B[l, c]


@njit
def mat_mul(A, B, out):
    """``out = A @ B`` (:func:`mat_rows` over the whole matrices)."""
    mat_rows(A, B, out, A.shape[0], B.shape[1])


@njit
def transpose(X, out):
    """``out = X'``."""
    for i in range(X.shape[0]):
        for j in range(X.shape[1]):
            out[j, i] = X[i, j]


@njit
def symmetric_part(X, out):
    """``out = (X + X') / 2`` (``out`` must not be ``X``)."""
    for i in range(X.shape[0]):
        for j in range(X.shape[1]):
            out[i, j] = 0.5 * (X[i, j] + X[j, i])


@njit
def sandwich(M, X, D, W1, W2, W3, out):
    """``out`` = the symmetric part of ``M X M' + D`` (``W1..W3``: (n, n) work arrays; ``out`` may be
    ``X``). ``M X M'`` is computed as its transpose ``M (M X)'``: equal for a symmetric X."""
    mat_mul(M, X, W1)
    transpose(W1, W2)
    mat_mul(M, W2, W3)
    n = W3.shape[0]
    for a in range(n):
        for b in range(n):
            W3[a, b] += D[a, b]
    symmetric_part(W3, out)


@njit
def cholesky_solve(S, B, C, out):
    """``out = S^-1 B`` for a symmetric positive definite ``S`` (Cholesky factor in ``C``); returns
    False if ``S`` is not numerically positive definite.

    The substitutions run row by row with the columns of ``B`` as the inner loop (so they vectorise);
    every entry still gets its terms subtracted in the order of the textbook column-by-column loop
    (``s = b_i; s -= C[i, l] x_l for l < i; x_i = s / C[i, i]``), hence the same value bit for bit."""
    q = S.shape[0]
    nc = B.shape[1]
    for i in range(q):
        for j in range(i + 1):
            s = S[i, j]
            for l in range(j):
                s -= C[i, l] * C[j, l]
            if i == j:
                if not s > 0.0:
                    return False
                C[i, i] = np.sqrt(s)
            else:
                C[i, j] = s / C[j, j]
    for i in range(q):  # C y = b
        for c in range(nc):
            out[i, c] = B[i, c]
        for l in range(i):
            a = C[i, l]
            for c in range(nc):
                out[i, c] -= a * out[l, c]
        d = C[i, i]
        for c in range(nc):
            out[i, c] = out[i, c] / d
    for i in range(q - 1, -1, -1):  # C' x = y
        for l in range(i + 1, q):
            a = C[l, i]
            for c in range(nc):
                out[i, c] -= a * out[l, c]
        d = C[i, i]
        for c in range(nc):
            out[i, c] = out[i, c] / d
    return True
