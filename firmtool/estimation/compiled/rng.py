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

Stream 2 (a roadmap's ``estimation_stream``, :func:`firmtool.scenario.stream_of`) draws every
particle's normals from a counter-based generator instead: Philox4x64-10 (Salmon et al. 2011,
"Parallel random numbers: as easy as 1, 2, 3"), word for word numpy's ``np.random.Philox`` (key 2x64,
counter 4x64; numpy increments its counter before use, so ``Philox(counter=c, key=k)``'s first four
raw words are :func:`philox4x64` of ``c + 1``). The key is derived from the chunk's seed sequence (the
scenario seed, the edge's two nodes and the chunk: :func:`philox_key`), the counter is ``(particle
index in the chunk's ensemble, step, block of four normals, 0)``: a particle's normals at a step are a
pure function of those keys, whatever the workers, the kernel's calls and segments, or which other
particles are still alive. Four words give four normals by Box-Muller (53-bit uniforms, the
branch-free :func:`_log` below and :func:`firmtool.models.angles.sincos`), with no rejection and no
branch, so that the loop over particles vectorises (the ziggurat's rejections keep xoshiro's stream
scalar: its order is the stream). Written here because no library gives compiled (numba) code a keyed
Philox: numpy's bit generators are called per draw through ctypes/cffi interfaces that carry a state,
not a pure function of (key, counter) a vectorised loop can call; Random123 is C++ headers.
"""

from __future__ import annotations

import numpy as np

from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba

if numba is not None:
    from firmtool.models.angles import sincos


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

    _M0, _M1 = np.uint64(0xD2E7470EE14C6C93), np.uint64(0xCA5A826395121157)  # Philox4x64's multipliers
    _W0, _W1 = np.uint64(0x9E3779B97F4A7C15), np.uint64(0xBB67AE8584CAA73B)  # and its key increments (Weyl)
    _LO32, _S32 = np.uint64(0xFFFFFFFF), np.uint64(32)
    _S11 = np.uint64(11)
    _K2, _K3, _K4, _K5, _K6, _K7, _K8, _K9 = (np.uint64(i) for i in range(2, 10))  # the rounds' key bumps
    _MANT, _EXP1 = np.int64(0x000FFFFFFFFFFFFF), np.int64(0x3FF0000000000000)

    @step
    def _mulhilo(a, b):
        """(high, low) 64-bit words of the 128-bit product ``a b`` (uint64): four 32-bit products
        (numba has no 128-bit integer; vectorised as vpmuludq / vpmullq)."""
        a0, a1, b0, b1 = a & _LO32, a >> _S32, b & _LO32, b >> _S32
        t = a1 * b0 + ((a0 * b0) >> _S32)
        u = (t & _LO32) + a0 * b1
        return a1 * b1 + (t >> _S32) + (u >> _S32), a * b

    @step
    def _round(c0, c1, c2, c3, k0, k1):
        """One Philox4x64 round (Random123's ``philox4x64round``)."""
        hi0, lo0 = _mulhilo(_M0, c0)
        hi1, lo1 = _mulhilo(_M1, c2)
        return hi1 ^ c1 ^ k0, lo1, hi0 ^ c3 ^ k1, lo0

    @step
    def philox4x64(c0, c1, c2, c3, k0, k1):
        """Philox4x64-10 of the counter ``(c0, c1, c2, c3)`` under the key ``(k0, k1)`` (uint64 each):
        ten rounds of Random123's ``philox4x64round``, the key bumped by the Weyl increments between
        rounds. Twin of numpy's ``np.random.Philox``; pinned word for word by
        tests/test_stream2.py::test_philox_words_are_numpys. The rounds are written out: LLVM vectorises
        innermost loops only, and a loop of ten rounds inside the loop over particles was left rolled
        (and the particle loop scalar)."""
        c0, c1, c2, c3 = _round(c0, c1, c2, c3, k0, k1)
        c0, c1, c2, c3 = _round(c0, c1, c2, c3, k0 + _W0, k1 + _W1)
        c0, c1, c2, c3 = _round(c0, c1, c2, c3, k0 + _W0 * _K2, k1 + _W1 * _K2)
        c0, c1, c2, c3 = _round(c0, c1, c2, c3, k0 + _W0 * _K3, k1 + _W1 * _K3)
        c0, c1, c2, c3 = _round(c0, c1, c2, c3, k0 + _W0 * _K4, k1 + _W1 * _K4)
        c0, c1, c2, c3 = _round(c0, c1, c2, c3, k0 + _W0 * _K5, k1 + _W1 * _K5)
        c0, c1, c2, c3 = _round(c0, c1, c2, c3, k0 + _W0 * _K6, k1 + _W1 * _K6)
        c0, c1, c2, c3 = _round(c0, c1, c2, c3, k0 + _W0 * _K7, k1 + _W1 * _K7)
        c0, c1, c2, c3 = _round(c0, c1, c2, c3, k0 + _W0 * _K8, k1 + _W1 * _K8)
        return _round(c0, c1, c2, c3, k0 + _W0 * _K9, k1 + _W1 * _K9)

    @step
    def _log(x):
        """``log(x)`` of a positive normal float, branch-free (fdlibm's ``e_log.c``: ``x = 2^e m`` with
        ``m`` in [sqrt(2)/2, sqrt(2)), ``log(1 + f)`` by its minimax polynomial in ``s = f / (2 + f)``;
        within an ulp of libm), so that a loop over particles that calls it vectorises (numba calls
        libm's scalar ``log`` otherwise). Pinned against ``np.log`` by
        tests/test_stream2.py::test_branch_free_log_is_numpys."""
        bits = np.float64(x).view(np.int64)
        e = (bits >> np.int64(52)) - np.int64(1023)
        m = np.int64((bits & _MANT) | _EXP1).view(np.float64)  # in [1, 2)
        big = m > 1.4142135623730951
        m = m * 0.5 if big else m
        e = e + np.int64(1) if big else e
        f = m - 1.0
        s = f / (2.0 + f)
        z = s * s
        w = z * z
        t1 = w * (3.999999999940941908e-01 + w * (2.222219843214978396e-01 + w * 1.531383769920937332e-01))
        t2 = z * (6.666666666666735130e-01 + w * (2.857142874366239149e-01 + w * (
            1.818357216161805012e-01 + w * 1.479819860511658591e-01)))
        hfsq = 0.5 * f * f
        k = float(e)
        return k * 6.93147180369123816490e-01 - ((hfsq - (s * (hfsq + t1 + t2) + k * 1.90821492927058770002e-10)) - f)

    @step
    def box_muller(w0, w1):
        """Two standard normals from two raw words (uint64): the uniforms ``(i + 1/2) 2^-53`` of their
        53 high bits (never 0 or 1), radius ``sqrt(-2 log u0)``, angle ``2 pi u1``. Exact in law up to
        the uniforms' resolution (the radius's largest value: 8.6)."""
        u0 = (float(np.int64(w0 >> _S11)) + 0.5) * 1.1102230246251565e-16
        u1 = (float(np.int64(w1 >> _S11)) + 0.5) * 1.1102230246251565e-16
        r = np.sqrt(-2.0 * _log(u0))
        s_, c_ = sincos(6.283185307179586 * u1)
        return r * c_, r * s_

    @njit
    def draw_philox(key, k, alive, W, Z, d, na):
        """``W[:d, :na]`` standard normals of stream 2 for step ``k`` (module notes): particle
        ``alive[a]``'s normals ``4 b .. 4 b + 3`` are the four words of Philox at the counter
        ``(alive[a], k, b, 0)`` under ``key`` (2 uint64), by :func:`box_muller` (``Z``: (4, N) work
        array). A function of (key, particle, step) only. Compiled on its own and called by the kernel
        once a step (not inlined into it as the step's helpers are): its unrolled, vectorised rounds
        inlined made the kernel's cold compile 1.33x main's (benchmarks/README.md, "Issue 55, stream 2")."""
        k0, k1 = key[0], key[1]
        ck = np.uint64(k)
        zero = np.uint64(0)
        for b in range((d + 3) // 4):
            cb = np.uint64(b)
            for a in range(na):  # vectorised: no branch, no state carried from one particle to the next
                w0, w1, w2, w3 = philox4x64(np.uint64(alive[a]), ck, cb, zero, k0, k1)
                z0, z1 = box_muller(w0, w1)
                z2, z3 = box_muller(w2, w3)
                Z[0, a], Z[1, a], Z[2, a], Z[3, a] = z0, z1, z2, z3
            for j in range(min(4, d - 4 * b)):
                for a in range(na):
                    W[4 * b + j, a] = Z[j, a]

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


def philox_key(rng: np.random.Generator) -> np.ndarray:
    """(2,) uint64: stream 2's Philox key of a chunk whose draws come from ``rng`` (made from
    :func:`firmtool.estimation.outcomes.edge_seed_sequence`): two words of a child of its seed sequence
    (spawn key 2), a function of the scenario seed, the edge's nodes and the chunk alone (not of what
    ``rng`` drew before). A generator without a seed sequence gives two of its raw words."""
    seq = getattr(rng.bit_generator, "seed_seq", None)
    if isinstance(seq, np.random.SeedSequence):
        child = np.random.SeedSequence(seq.entropy, spawn_key=tuple(seq.spawn_key) + (2,), pool_size=seq.pool_size)
        return child.generate_state(2, np.uint64)
    return np.asarray(rng.bit_generator.random_raw(2), dtype=np.uint64)
