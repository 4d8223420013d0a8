"""Optional numba kernel for :class:`NumbaCollisionBackend`: the numpy geometry, scalar, one
configuration at a time with early exit. The numpy backend stays the reference; the tests check
that both agree. The distance primitives and the test of a capsule against the boxes
(:func:`capsule_meets_boxes`) are shared with the Monte Carlo kernel (:mod:`firmtool.estimation.compiled.collide`).
Module-level and cached on disk by numba (compiled once, ~1-2 s; later processes load them in well
under a second).
"""

from __future__ import annotations

import numpy as np

from firmtool.errors import InputError
from firmtool.geometry.backends import NumpyCollisionBackend, _check_capsules

try:  # numba is optional
    import numba
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None

# Module-level functions (not a closure): numba caches them on disk (a closure recompiled in every
# process). firmtool.estimation.compiled compiles these distances into its step kernel; firmtool.jit's cache key
# covers this file, so the kernel is recompiled after an edit here, not loaded stale.
if numba is not None:
    from firmtool.jit import KERNEL_OPTIONS, cached_njit

    njit = cached_njit(**KERNEL_OPTIONS)
    # inlined into its callers at numba's IR level: no compile of its own (the kernels' cold compile)
    inline = cached_njit(**KERNEL_OPTIONS, inline="always")

    @njit
    def pseg_d2(px, py, ax, ay, bx, by):
        dx, dy = bx - ax, by - ay
        dd = dx * dx + dy * dy
        t = 0.0
        if dd > 0.0:
            t = ((px - ax) * dx + (py - ay) * dy) / dd
            t = min(max(t, 0.0), 1.0)
        ex, ey = ax + t * dx - px, ay + t * dy - py
        return ex * ex + ey * ey

    @njit
    def pbox_d2(px, py, hx, hy):
        ex = max(abs(px) - hx, 0.0)
        ey = max(abs(py) - hy, 0.0)
        return ex * ex + ey * ey

    @njit
    def seg_box_d2(ax, ay, bx, by, hx, hy):
        # separating axis test on x, y and the segment normal (closed sets)
        sep = (min(ax, bx) > hx) or (max(ax, bx) < -hx) or (min(ay, by) > hy) or (max(ay, by) < -hy)
        if not sep:
            nx, ny = ay - by, bx - ax
            mx, my = 0.5 * (ax + bx), 0.5 * (ay + by)
            sep = abs(nx * mx + ny * my) > abs(nx) * hx + abs(ny) * hy
        if not sep:
            return 0.0
        d = min(pbox_d2(ax, ay, hx, hy), pbox_d2(bx, by, hx, hy))
        d = min(d, pseg_d2(hx, hy, ax, ay, bx, by))
        d = min(d, pseg_d2(hx, -hy, ax, ay, bx, by))
        d = min(d, pseg_d2(-hx, hy, ax, ay, bx, by))
        d = min(d, pseg_d2(-hx, -hy, ax, ay, bx, by))
        return d

    @njit
    def seg_seg_d2(a0x, a0y, a1x, a1y, b0x, b0y, b1x, b1y):
        dax, day = a1x - a0x, a1y - a0y
        dbx, dby = b1x - b0x, b1y - b0y
        o1 = dax * (b0y - a0y) - day * (b0x - a0x)
        o2 = dax * (b1y - a0y) - day * (b1x - a0x)
        o3 = dbx * (a0y - b0y) - dby * (a0x - b0x)
        o4 = dbx * (a1y - b0y) - dby * (a1x - b0x)
        if o1 * o2 < 0.0 and o3 * o4 < 0.0:
            return 0.0
        d = min(pseg_d2(a0x, a0y, b0x, b0y, b1x, b1y), pseg_d2(a1x, a1y, b0x, b0y, b1x, b1y))
        d = min(d, pseg_d2(b0x, b0y, a0x, a0y, a1x, a1y))
        return min(d, pseg_d2(b1x, b1y, a0x, a0y, a1x, a1y))

    @inline
    def capsule_meets_boxes(ax, ay, bx, by, r, r2, C, H, cs, sn, blo, bhi):
        """Whether the capsule from ``(ax, ay)`` to ``(bx, by)`` of radius ``r`` (``r2 = r * r``) meets a
        box: box k has centre ``C[k]``, half sizes ``H[k]``, rotation ``(cs[k], sn[k])`` (cos and sin;
        1 and 0 when axis-aligned) and bounding box ``[blo[k], bhi[k]]``. The capsule's bounding box
        against each box's first, then the segment in the box's frame (:func:`seg_box_d2`). The loop
        of both the numba backend and the Monte Carlo kernel (tests/test_geometry.py and
        tests/test_kernels.py pin each against the numpy backend)."""
        lox, hix = min(ax, bx) - r, max(ax, bx) + r
        loy, hiy = min(ay, by) - r, max(ay, by) + r
        for k in range(C.shape[0]):
            if lox > bhi[k, 0] or hix < blo[k, 0] or loy > bhi[k, 1] or hiy < blo[k, 1]:
                continue
            qax, qay = ax - C[k, 0], ay - C[k, 1]
            qbx, qby = bx - C[k, 0], by - C[k, 1]
            c_, s_ = cs[k], sn[k]
            if s_ != 0.0 or c_ != 1.0:
                qax, qay = c_ * qax + s_ * qay, -s_ * qax + c_ * qay
                qbx, qby = c_ * qbx + s_ * qby, -s_ * qbx + c_ * qby
            if seg_box_d2(qax, qay, qbx, qby, H[k, 0], H[k, 1]) < r2:
                return True
        return False

    @njit
    def kernel(S, E, r, lo, hi, C, H, cs, sn, blo, bhi, self_collision, out):
        M, L = S.shape[0], S.shape[1]
        r2, lim = r * r, 4.0 * r * r
        for m in range(M):
            hit = False
            # workspace (same comparisons as outside_workspace; NaN fails them)
            for l in range(L):
                for c in range(2):
                    lr, hr = lo[c] + r, hi[c] - r
                    if not (S[m, l, c] >= lr and S[m, l, c] <= hr and E[m, l, c] >= lr and E[m, l, c] <= hr):
                        hit = True
            # obstacles
            for l in range(L):
                if hit:
                    break
                hit = capsule_meets_boxes(S[m, l, 0], S[m, l, 1], E[m, l, 0], E[m, l, 1], r, r2, C, H, cs, sn, blo, bhi)
            # self-collision, non-adjacent pairs
            if self_collision and not hit:
                for a in range(L):
                    if hit:
                        break
                    for b in range(a + 2, L):
                        if seg_seg_d2(S[m, a, 0], S[m, a, 1], E[m, a, 0], E[m, a, 1],
                                      S[m, b, 0], S[m, b, 1], E[m, b, 0], E[m, b, 1]) < lim:
                            hit = True
                            break
            out[m] = hit


class NumbaCollisionBackend(NumpyCollisionBackend):
    """Same constructor and semantics as :class:`NumpyCollisionBackend`; a compiled scalar loop
    over configurations with early exit. Requires numba."""

    def __init__(self, *args, **kwargs) -> None:
        if numba is None:  # pragma: no cover
            raise InputError("collision backend 'numba': numba is not installed")
        kwargs.pop("prefilter", None)
        super().__init__(*args, **kwargs)

    def capsules_collide(self, starts: np.ndarray, ends: np.ndarray, radius: float) -> np.ndarray:
        starts, ends, r = _check_capsules(starts, ends, radius)
        out = np.zeros(starts.shape[0], dtype=np.bool_)
        if starts.shape[0] == 0 or starts.shape[1] == 0:
            return out
        cs = np.where(self._rotated, self._cos, 1.0)
        sn = np.where(self._rotated, self._sin, 0.0)
        kernel(np.ascontiguousarray(starts), np.ascontiguousarray(ends), r, self.lo, self.hi,
                self.centers, self.half_sizes, cs, sn, self._box_lo, self._box_hi,
                self.self_collision, out)
        return out
