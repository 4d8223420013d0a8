"""Angles kept continuous along a run (a unicycle's heading is not wrapped: differences along a run
are never off by a turn), compared and re-expressed modulo a turn where two of them meet.

Two operations, one place: :func:`wrap` (a difference to ``[-pi, pi)``) and :func:`on_turn_of` (an
angle moved by whole turns to the turn of a reference). numpy has ``unwrap`` for sequences, not these.
And the compiled code's sine and cosine of one angle at once (:func:`sincos`): numba's ``np.sin`` and
``np.cos`` call libm twice, ~40 ns per angle where the planar and URDF arms' kinematics need one per
joint and particle; one range reduction and two polynomials cost about half (measured on the arms'
key points).
"""

from __future__ import annotations

import numpy as np

from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba

TURN = 2.0 * np.pi


def wrap(angle: np.ndarray | float) -> np.ndarray | float:
    """``angle`` (any shape) modulo a turn, in ``[-pi, pi)``."""
    return (angle + np.pi) % TURN - np.pi


def on_turn_of(angle: np.ndarray | float, reference: np.ndarray | float) -> np.ndarray | float:
    """``angle`` moved by whole turns to within half a turn of ``reference`` (the same direction)."""
    return angle + TURN * np.round((reference - angle) / TURN)


if numba is not None:
    # inlined into its callers (numba IR): the kinematics' loops over particles that call it vectorise
    hook = cached_njit(**KERNEL_OPTIONS, inline="always")

    @hook
    def sincos(a):
        """(sin a, cos a): Cody-Waite reduction by pi/2 and fdlibm's minimax polynomials on
        [-pi/4, pi/4] (within an ulp or two of libm), branch-free: the quadrant picks the polynomials
        and their signs by selects and exact sign flips, so that a loop over particles that calls it
        vectorises (issue 55 item 2, from the reverted bb0473e; the same operations on every value as
        the quadrant's branches did, so the same bits; rate and cold compile: benchmarks/README.md,
        "Issue 55"). Twin of ``np.sin``, ``np.cos``; pinned by
        tests/test_kernels.py::test_kinematics_are_the_robots_points."""
        q = np.floor(a * 0.6366197723675814 + 0.5)
        y = (a - q * 1.57079632673412561417e+00) - q * 6.07710050650619224932e-11
        z = y * y
        sp = y + y * z * (-1.66666666666666324348e-01 + z * (8.33333333332248946124e-03 + z * (
            -1.98412698298579493134e-04 + z * (2.75573137070700676789e-06 + z * (
                -2.50507602534068634195e-08 + z * 1.58969099521155010221e-10)))))
        cp = 1.0 - 0.5 * z + z * z * (4.16666666666666019037e-02 + z * (-1.38888888888741095749e-03 + z * (
            2.48015872894767294178e-05 + z * (-2.75573143513906633035e-07 + z * (
                2.08757232129817482790e-09 + z * -1.13596475577881948265e-11)))))
        k = np.int64(q) & 3
        odd = (k & 1) == 1
        s_ = cp if odd else sp  # quadrants 1, 3: the polynomials swap
        c_ = sp if odd else cp
        s_sign = -1.0 if k >= 2 else 1.0  # sin < 0 in quadrants 2, 3; cos < 0 in 1, 2
        c_sign = -1.0 if (k == 1 or k == 2) else 1.0
        return s_sign * s_, c_sign * c_
