"""The jump test's per-step recursion compiled: every kept onset's error propagation, evidence sums
and statistic in one call, in buffers allocated once.

:meth:`firmtool.online.innovation.JumpTest.add` ran the recursion of Willsky and Jones over all kept
onsets as a dozen numpy calls on stacks of small matrices (concatenations to drop the oldest onset and
add the newest, stacked products, a stacked ``solve``, and whenever one onset's ``C`` was singular (the
newest onsets of the state family every step: a velocity is not seen by one measurement) a stacked
``pinv`` of all the window's onsets). That was 60% of the point robot's online step (pyinstrument,
issue 39). Here, per onset ``i`` and step (``w = S^-1 gamma`` once per step)::

    A Phi_i -> G_i = H A Phi_i -> d_i += G_i' w,  C_i += G_i' S^-1 G_i,  Phi_i <- A Phi_i - L G_i
    l_i = d_i' C_i^+ d_i   (pivoted Cholesky of C_i)

The statistic is solved per onset by a Cholesky factorisation with symmetric pivoting that stops at
the first remaining pivot below ``p eps max(diag C_i)``: on a regular ``C_i`` it is ``d' C^-1 d``
(main's ``solve``), on a singular one ``d' C^+ d`` for ``d`` in ``C``'s range, as it is by
construction (``d`` and ``C`` are sums over the same ``G``): main's least-squares fallback (``pinv``
with the cutoff ``p eps max|eig|``). Products add in another order than numpy's stacked matmul, so
results agree with main's to rounding (the reference episodes, rtol 1e-9, pass unchanged), not bit
for bit; each onset's arithmetic depends only on its own data, so a test that keeps more onsets
gives the window's onsets the same bits.

The onsets live in buffers of twice the kept count, oldest first from ``start``: dropping the oldest
is ``start += 1``, and once the newest reaches the end the live ones move back to the front (one copy
every ``kept`` steps), so the public arrays (``JumpTest.Phi``, ``d``, ``C``, ``onset``, ``statistics``)
are contiguous views, oldest first, as before.
"""

from __future__ import annotations

import numpy as np

from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba

EPS = float(np.finfo(float).eps)


def _glr_add(A, H, L, S_inv, gamma, basis, Phi, d, C, stats, lo, hi, older, work, wv):
    """Advance the onsets ``lo:hi`` of the buffers by one step, the onset ``hi - 1`` new (``Phi`` set to
    ``basis``, ``d`` and ``C`` to zero first), and write their statistics ``stats[lo:hi]``.

    Parameters
    ----------
    A : (n, n); H : (nz, n); L : (n, nz); S_inv : (nz, nz); gamma : (nz,) the step's innovation.
    basis : (n, p) the family's jump directions.
    Phi : (K, n, p); d : (K, p); C : (K, p, p); stats : (K,): the buffers, updated in place.
    work : (2 n + 2 nz + p, p) and wv : (nz + p,) scratch (no allocation per step).
    """
    n, p = basis.shape
    nz = H.shape[0]
    new = hi - 1
    for r in range(n):
        for c in range(p):
            Phi[new, r, c] = basis[r, c]
    for a in range(p):
        d[new, a] = 0.0
        for b in range(p):
            C[new, a, b] = 0.0
    w = wv[:nz]
    for r in range(nz):
        acc = 0.0
        for c in range(nz):
            acc += S_inv[r, c] * gamma[c]
        w[r] = acc
    AP, G, SG, LG = work[:n], work[n:n + nz], work[n + nz:n + 2 * nz], work[n + 2 * nz:2 * n + 2 * nz]
    chol = work[2 * n + 2 * nz:]
    y = wv[nz:nz + p]
    for i in range(lo, hi):
        P, Ci, di = Phi[i], C[i], d[i]
        _product(A, P, AP, n, n, p)  # the jump's part of the predicted error
        _product(H, AP, G, nz, n, p)  # its part of this innovation
        _product(S_inv, G, SG, nz, nz, p)
        _product(L, G, LG, n, nz, p)
        # d += G' w and C += G' S^-1 G as row updates (contiguous inner loops: they vectorise)
        for r in range(nz):
            wr = w[r]
            for a in range(p):
                g = G[r, a]
                di[a] += g * wr
                if g != 0.0:
                    for b in range(p):
                        Ci[a, b] += g * SG[r, b]
        for r in range(n):
            for c in range(p):
                P[r, c] = AP[r, c] - LG[r, c]  # (I - L H) A Phi: its part of the error after the update
        stats[i] = _statistic(Ci, di, chol, y, p)
    best = older
    for i in range(older + 1, hi - lo):
        if stats[lo + i] > stats[lo + best]:
            best = i
    return best


def _product(M, X, out, rows, inner, cols):
    """``out[:rows] = M X`` (``M`` (rows, inner), ``X`` (inner, cols)); exact zeros of ``M`` skipped (a
    double integrator's A and a selection H are mostly zeros; adding 0 x changes no sum)."""
    for r in range(rows):
        for c in range(cols):
            out[r, c] = 0.0
        for k in range(inner):
            m = M[r, k]
            if m != 0.0:
                for c in range(cols):
                    out[r, c] += m * X[k, c]


def _statistic(C, d, W, y, p):
    """``d' C^+ d`` for a symmetric positive semidefinite ``C`` (p, p) and ``d`` in its range: a
    Cholesky factorisation with symmetric pivoting in ``W``, the forward substitution of the permuted
    ``d`` fused in, stopped where the largest remaining pivot is below ``p eps max(diag C)`` (the rank)."""
    top = 0.0
    for a in range(p):
        y[a] = d[a]
        top = max(top, C[a, a])
        for b in range(p):
            W[a, b] = C[a, b]
    if not top > 0.0:
        return 0.0  # no direction seen yet (pinv of zero)
    tol = p * EPS * top
    out = 0.0
    for k in range(p):
        j, best = k, W[k, k]
        for q in range(k + 1, p):
            if W[q, q] > best:
                j, best = q, W[q, q]
        if not best > tol:
            break  # the rest is C's null space (to rounding)
        if j != k:  # symmetric swap of rows and columns k and j
            for q in range(p):
                W[k, q], W[j, q] = W[j, q], W[k, q]
            for q in range(p):
                W[q, k], W[q, j] = W[q, j], W[q, k]
            y[k], y[j] = y[j], y[k]
        piv = np.sqrt(W[k, k])
        z = y[k] / piv
        out += z * z
        for q in range(k + 1, p):
            W[q, k] /= piv
            y[q] -= W[q, k] * z
        for q in range(k + 1, p):
            W[k, q] = W[q, k]  # column k as a contiguous row for the update below
        for q in range(k + 1, p):  # the trailing block, both triangles (row updates: they vectorise)
            lq = W[k, q]
            if lq != 0.0:
                for s in range(k + 1, p):
                    W[q, s] -= lq * W[k, s]
    return out


if numba is not None:
    njit = cached_njit(**KERNEL_OPTIONS)
    _product = njit(_product)
    _statistic = njit(_statistic)
    glr_add = njit(_glr_add)
else:  # pragma: no cover (numba is a dependency; the plain loops stay correct without it)
    glr_add = _glr_add


def work_arrays(n: int, nz: int, p: int) -> tuple[np.ndarray, np.ndarray]:
    """The scratch arrays :func:`glr_add` takes for a family of ``p`` directions in ``n`` states."""
    return np.zeros((2 * n + 2 * nz + p, p)), np.zeros(nz + p)


_warm = False


def warm() -> None:
    """Compile (or load from the disk cache) :func:`glr_add` now, once per process, on arrays of the
    types every call passes: not inside the first control period that runs a jump test."""
    global _warm
    if _warm:
        return
    n, nz, p = 2, 1, 1
    e = np.eye(n)
    glr_add(e, e[:nz].copy(), e[:, :nz].copy(), np.eye(nz), np.zeros(nz), e[:, :p].copy(), np.zeros((2, n, p)),
            np.zeros((2, p)), np.zeros((2, p, p)), np.zeros(2), 0, 1, 0, *work_arrays(n, nz, p))
    _warm = True
