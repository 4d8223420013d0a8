"""Random numbers inside the compiled kernel: xoshiro256++ and a 256-layer ziggurat, and the two noise
sources of a step (drawn here, or read from numpy's stream).

By default the noise is drawn inside the kernel: xoshiro256++ (Blackman & Vigna) seeded with four
words of the caller's ``np.random.Generator`` (whose seed comes from the scenario seed and the edge,
:func:`firmtool.estimation.outcomes.edge_seed_sequence`), normals by the ziggurat (Marsaglia & Tsang,
256 layers), ~2.4 ns a normal against ~10 ns for ``Generator.standard_normal``. Results are a
function of the seed only (not of workers or executor); the numpy path draws other numbers, so the
two engines agree in distribution (tests: the normal law of the draws, probabilities within
confidence intervals). With ``numpy_noise=True`` the kernel instead consumes
``rng.standard_normal`` in the numpy path's order (per step ``(alive, r + nz)`` row-major, the live
particles in their original order), drawn a few steps ahead; both engines then simulate the same
particles, and their outcomes agree particle by particle (up to summation order, which can flip a
decision only on a knife edge): the tests' check of the kernel's arithmetic.
"""

from __future__ import annotations

import numpy as np

from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba


def _ziggurat_tables(layers: int = 256, r: float = 3.6541528853610088, v: float = 0.00492867323399):
    """Layer tables of the normal ziggurat (Marsaglia & Tsang 2000, Sec. 3's recipe, 52-bit abscissae):
    ``K[i]`` the integer bound below which a draw in layer i is accepted at once, ``W[i]`` the scale
    from integer to abscissa, ``F[i]`` the density at the layer's edge. ``r`` is the base layer's
    right edge and ``v`` every layer's area for 256 layers."""
    m = 2.0 ** 52
    K, W, F = np.zeros(layers, dtype=np.uint64), np.zeros(layers), np.zeros(layers)
    dn = tn = r
    q = v / np.exp(-0.5 * dn * dn)
    K[0], K[1] = np.uint64(dn / q * m), np.uint64(0)
    W[0], W[-1] = q / m, dn / m
    F[0], F[-1] = 1.0, np.exp(-0.5 * dn * dn)
    for i in range(layers - 2, 0, -1):
        dn = np.sqrt(-2.0 * np.log(v / dn + np.exp(-0.5 * dn * dn)))
        K[i + 1] = np.uint64(dn / tn * m)
        tn = dn
        F[i], W[i] = np.exp(-0.5 * dn * dn), dn / m
    return K, W, F


ZIG_K, ZIG_W, ZIG_F = _ziggurat_tables()
ZIG_R = 3.6541528853610088
ZIG_INV_R = 1.0 / ZIG_R

if numba is not None:
    njit = cached_njit(**KERNEL_OPTIONS)
    # inlined into the kernel at numba's IR level (cold compile: see firmtool.estimation.compiled.step)
    step = cached_njit(**KERNEL_OPTIONS, inline="always")

    @njit
    def _rotl(x, k):
        return (x << np.uint64(k)) | (x >> np.uint64(64 - k))

    @njit
    def _next(s0, s1, s2, s3):
        """One xoshiro256++ output and the advanced state (Blackman & Vigna)."""
        out = _rotl(s0 + s3, 23) + s0
        t = s1 << np.uint64(17)
        s2 ^= s0
        s3 ^= s1
        s1 ^= s2
        s0 ^= s3
        s2 ^= t
        s3 = _rotl(s3, 45)
        return out, s0, s1, s2, s3

    @njit
    def fill_normals(state, out, count):
        """``out[:count]`` = standard normals (ziggurat of Marsaglia & Tsang, numpy's 256-layer
        variant: 8 bits pick the layer, 1 the sign, 52 the abscissa); ``state`` (4 uint64) advances.
        Not a twin of numpy's draws (other numbers, the same law); pinned by
        tests/test_kernels.py::test_kernel_normals_are_standard_normal."""
        s0, s1, s2, s3 = state[0], state[1], state[2], state[3]
        i = 0
        while i < count:
            r, s0, s1, s2, s3 = _next(s0, s1, s2, s3)
            idx = np.int64(r & np.uint64(0xFF))
            r >>= np.uint64(8)
            rabs = (r >> np.uint64(1)) & np.uint64(0x000FFFFFFFFFFFFF)
            x = float(rabs) * ZIG_W[idx]
            if r & np.uint64(1):
                x = -x
            if rabs < ZIG_K[idx]:  # ~99% of draws: inside a layer's rectangle
                out[i] = x
                i += 1
                continue
            if idx == 0:  # the tail beyond ZIG_R (Marsaglia's exponential-majorant method)
                while True:
                    a, s0, s1, s2, s3 = _next(s0, s1, s2, s3)
                    b, s0, s1, s2, s3 = _next(s0, s1, s2, s3)
                    xx = -ZIG_INV_R * np.log1p(-float(a >> np.uint64(11)) * 1.1102230246251565e-16)
                    yy = -np.log1p(-float(b >> np.uint64(11)) * 1.1102230246251565e-16)
                    if yy + yy > xx * xx:
                        out[i] = -(ZIG_R + xx) if (rabs >> np.uint64(8)) & np.uint64(1) else ZIG_R + xx
                        i += 1
                        break
            else:  # the wedge between the rectangle and the density
                a, s0, s1, s2, s3 = _next(s0, s1, s2, s3)
                u = float(a >> np.uint64(11)) * 1.1102230246251565e-16
                if (ZIG_F[idx - 1] - ZIG_F[idx]) * u + ZIG_F[idx] < np.exp(-0.5 * x * x):
                    out[i] = x
                    i += 1
        state[0], state[1], state[2], state[3] = s0, s1, s2, s3

    @step
    def take_noise(noise, pos, W, d, na):
        """``W[:d, :na]`` from numpy's stream at ``pos`` (``(particle, d)`` row-major, as the numpy path
        draws a step's noise); returns the new position."""
        for a in range(na):
            for j in range(d):
                W[j, a] = noise[pos + a * d + j]
        return pos + na * d

    @step
    def draw_noise(rng_state, W, d, na):
        """``W[:d, :na]`` standard normals drawn here, row by row (:func:`fill_normals`)."""
        for j in range(d):
            fill_normals(rng_state, W[j], na)
