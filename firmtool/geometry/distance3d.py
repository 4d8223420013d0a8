"""Exact squared distances from segments to solid axis-aligned boxes and to points in 3-D, vectorised
by broadcasting: the narrow phase of capsules with a radius each (a URDF arm's links) against a world
of boxes and spheres, without a Python loop over configurations.

Why not python-fcl here: fcl answers one pair of objects per call, and building a capsule object per
link and configuration costs ~25 us in Python (``fcl_backend.axis_rotation``, measured: 150 of 167 s
of an arm's roadmap connection stage), where this module answers a whole ensemble in numpy.
python-fcl stays the reference (tests/test_urdf.py compares them) and the backend of every other
obstacle kind.

The segment ``p(t) = a + t (b - a)``, ``t in [0, 1]``, and a box ``[lo, hi]``: the squared distance
``f(t) = sum_c excess_c(t)^2`` (``excess_c`` the amount coordinate ``c`` lies outside the box's slab)
is convex and piecewise quadratic, with breaks where the segment crosses a slab's face. Between two
breaks each coordinate is below, inside or above its slab throughout, so ``f`` is one quadratic there
and its minimum over the piece is at the stationary point clipped to the piece. The minimum over the
candidates (every break, both ends, every piece's clipped stationary point) is therefore exact.
"""

from __future__ import annotations

import numpy as np


def segment_box_distance_sq(a: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Squared distance from segments ``[a, b]`` to solid boxes ``[lo, hi]`` (0 where they meet).

    Parameters
    ----------
    a, b : (..., 3) the segments' ends.
    lo, hi : (..., 3) the boxes' corners, broadcast against ``a``.

    Returns
    -------
    (...) squared distances.
    """
    a, b, lo, hi = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (a, b, lo, hi)))
    d = b - a
    with np.errstate(divide="ignore", invalid="ignore"):
        t_lo, t_hi = (lo - a) / d, (hi - a) / d  # where each coordinate crosses its slab's faces
    breaks = np.concatenate([t_lo, t_hi], axis=-1)
    breaks = np.where(np.isfinite(breaks), np.clip(breaks, 0.0, 1.0), 0.0)
    knots = np.sort(np.concatenate([np.zeros(a.shape[:-1] + (1,)), breaks, np.ones(a.shape[:-1] + (1,))],
                                   axis=-1), axis=-1)  # (..., 8)
    left, right = knots[..., :-1], knots[..., 1:]  # the 7 pieces
    mid = 0.5 * (left + right)
    p_mid = a[..., None, :] + mid[..., None] * d[..., None, :]  # (..., 7, 3)
    bound = np.where(p_mid < lo[..., None, :], lo[..., None, :], hi[..., None, :])
    outside = (p_mid < lo[..., None, :]) | (p_mid > hi[..., None, :])
    w = outside.astype(float)
    num = -(w * d[..., None, :] * (a[..., None, :] - bound)).sum(-1)
    den = (w * d[..., None, :] ** 2).sum(-1)
    t_star = np.where(den > 0.0, num / np.where(den > 0.0, den, 1.0), mid)
    t_star = np.clip(t_star, left, right)
    candidates = np.concatenate([knots, t_star], axis=-1)  # (..., 15)
    p = a[..., None, :] + candidates[..., None] * d[..., None, :]
    excess = np.maximum(lo[..., None, :] - p, 0.0) + np.maximum(p - hi[..., None, :], 0.0)
    return (excess * excess).sum(-1).min(-1)


def segment_point_distance_sq(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Squared distance from segments ``[a, b]`` (..., 3) to points ``c`` (..., 3), broadcast."""
    a, b, c = (np.asarray(v, dtype=float) for v in (a, b, c))
    d = b - a
    dd = (d * d).sum(-1)
    t = np.where(dd > 0.0, ((c - a) * d).sum(-1) / np.where(dd > 0.0, dd, 1.0), 0.0)
    e = a + np.clip(t, 0.0, 1.0)[..., None] * d - c
    return (e * e).sum(-1)


def segment_segment_distance_sq_3d(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """Squared distance between the segments ``[a0, a1]`` and ``[b0, b1]`` in 3-D (broadcast, last
    axis 3): the closest points' parameters ``s, t`` in [0, 1] of the convex quadratic
    ``|a0 + s d1 - b0 - t d2|^2``, minimised over the square (Ericson, *Real-Time Collision
    Detection*, 5.1.9: ``s`` from the unconstrained minimum clamped, ``t`` from ``s``, then ``s``
    again from the clamped ``t``); degenerate segments (points) and parallel ones included. The
    capsules of a URDF arm's links meet where it is below the sum of their radii squared."""
    d1, d2, r = a1 - a0, b1 - b0, a0 - b0
    a = np.einsum("...i,...i->...", d1, d1)
    e = np.einsum("...i,...i->...", d2, d2)
    f = np.einsum("...i,...i->...", d2, r)
    c = np.einsum("...i,...i->...", d1, r)
    b = np.einsum("...i,...i->...", d1, d2)
    denom = a * e - b * b
    tiny = 1e-300
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denom > 1e-12 * np.maximum(a * e, tiny), np.clip((b * f - c * e) / denom, 0.0, 1.0), 0.0)
        s = np.where(a > tiny, s, 0.0)
        t = np.where(e > tiny, (b * s + f) / np.where(e > tiny, e, 1.0), 0.0)
        t_clamped = np.clip(t, 0.0, 1.0)
        s = np.where((t != t_clamped) & (a > tiny), np.clip((b * t_clamped - c) / np.where(a > tiny, a, 1.0), 0.0, 1.0),
                     s)
    diff = r + s[..., None] * d1 - t_clamped[..., None] * d2
    return np.einsum("...i,...i->...", diff, diff)
