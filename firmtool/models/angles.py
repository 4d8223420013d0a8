"""Angles kept continuous along a run (a unicycle's heading is not wrapped: differences along a run
are never off by a turn), compared and re-expressed modulo a turn where two of them meet.

Two operations, one place: :func:`wrap` (a difference to ``[-pi, pi)``) and :func:`on_turn_of` (an
angle moved by whole turns to the turn of a reference). numpy has ``unwrap`` for sequences, not these.
"""

from __future__ import annotations

import numpy as np

TURN = 2.0 * np.pi


def wrap(angle: np.ndarray | float) -> np.ndarray | float:
    """``angle`` (any shape) modulo a turn, in ``[-pi, pi)``."""
    return (angle + np.pi) % TURN - np.pi


def on_turn_of(angle: np.ndarray | float, reference: np.ndarray | float) -> np.ndarray | float:
    """``angle`` moved by whole turns to within half a turn of ``reference`` (the same direction)."""
    return angle + TURN * np.round((reference - angle) / TURN)
