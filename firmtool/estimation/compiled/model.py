"""The compiled kernel's model steps per kind of model: the true states' step (``advance``) and the
filter update (``update``), bound into the kernel by name (:func:`model_functions`).

- a linear model with the robot's sensor (a noise law of a sensing coordinate): the kernel's step
  helpers as they were (:func:`firmtool.estimation.compiled.step.true_step` and
  :func:`~firmtool.estimation.compiled.step.filter_update`), so its results stay bit for bit;
- a nonlinear model (the robot's compiled ``step`` hook, :class:`~firmtool.robots.compiled.CompiledKinematics`:
  the unicycle's) with the robot's sensor: the same update with the hook's prediction;
- either dynamics with landmark sensing (:mod:`firmtool.models.landmarks`): range and bearing to each
  landmark seen from the TRUE state (range, field of view, the compiled ray march of
  :func:`firmtool.models.landmarks.occluded`), NaN-free: a landmark not seen gives a zero innovation.

Each function's docstring names the numpy function it reproduces and the test that pins the two.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from firmtool.jit import KERNEL_OPTIONS, cached_njit, importable, numba, specialise

INLINE = {**KERNEL_OPTIONS, "inline": "always"}
LANDMARKS = "landmarks"
# names bound per specialisation (specialise): the robot's step hook, the prediction
model_step = predict = None


def landmark_group(model) -> tuple:
    """The kernel's sensor group of a landmark model: ``(landmarks (L, 2), consts (5,), grid, occlusion,
    heading)`` (:class:`firmtool.models.landmarks.LandmarkModel`)."""
    occ = bool(model.noise.occlusion and model.grid is not None)
    return (np.ascontiguousarray(model.noise.landmarks, dtype=float), np.ascontiguousarray(model.consts, dtype=float),
            model.grid_group(), occ, int(model.heading))


if numba is not None:
    from firmtool.control.linalg import mat_rows
    from firmtool.estimation.compiled.step import filter_update, linear_step, measurement_variance, true_step
    from firmtool.models.landmarks import MIN_RANGE, occluded

    step = cached_njit(**INLINE)

    @step
    def linear_advance(A, B, F, params, X, U, W, XN, TMP, na):
        """The linear model's step with process noise (:func:`~firmtool.estimation.compiled.step.true_step`)."""
        true_step(A, B, F, X, U, W, XN, TMP, na)

    @step
    def linear_update(A, B, H, L_k, X, XH, U, W, rows, sensor, sensing, params, PRED, HZ, INN, TMP, na):
        """The linear model's update (:func:`~firmtool.estimation.compiled.step.filter_update`)."""
        filter_update(A, B, H, L_k, X, XH, U, W, rows, sensor, sensing, PRED, HZ, INN, TMP, na)

    @step
    def predict_linear(A, B, params, XH, U, PRED, TMP, na):
        """``PRED = A XH + B U``."""
        linear_step(A, B, XH, U, PRED, TMP, na)

    def predict_nonlinear(A, B, params, XH, U, PRED, TMP, na):
        """``PRED = f(XH, U)`` by the robot's ``step`` hook (bound as ``model_step``)."""
        model_step(XH, U, params, PRED, na)

    def nonlinear_advance(A, B, F, params, X, U, W, XN, TMP, na):
        """``XN = f(X, U) + F W[:r]``: the robot's ``step`` hook and the process noise. Twin of
        :func:`firmtool.estimation.edges.control_and_move`'s ``model.f(x, u) + w F'``; pinned by
        tests/test_landmarks.py's same-outcomes tests of the unicycle."""
        model_step(X, U, params, XN, na)
        n = F.shape[0]
        mat_rows(F, W, TMP, n, na)
        for j in range(n):
            for a in range(na):
                XN[j, a] += TMP[j, a]

    def position_update(A, B, H, L_k, X, XH, U, W, rows, sensor, sensing, params, PRED, HZ, INN, TMP, na):
        """:func:`~firmtool.estimation.compiled.step.filter_update` with the bound ``predict`` (a
        nonlinear model's) in place of ``A XH + B U``: twin of :func:`firmtool.estimation.edges.filter_update`."""
        n, nz, r = PRED.shape[0], H.shape[0], W.shape[0] - H.shape[0]
        predict(A, B, params, XH, U, PRED, TMP, na)
        mat_rows(H, X, HZ, nz, na)
        mat_rows(H, PRED, INN, nz, na)
        for j in range(nz):
            prow = rows[sensing[j]]
            for a in range(na):
                var = measurement_variance(sensor, prow[a])
                INN[j, a] = (HZ[j, a] + np.sqrt(var) * W[r + j, a]) - INN[j, a]
        mat_rows(L_k, INN, TMP, n, na)
        for j in range(n):
            for a in range(na):
                XH[j, a] = PRED[j, a] + TMP[j, a]

    @step
    def wrap_pi(b):
        """``b`` modulo a turn in ``(-pi, pi]`` (:func:`firmtool.models.landmarks.wrap_pi`)."""
        return np.pi - (np.pi - b) % (2.0 * np.pi)

    @step
    def landmark_innovation(X, PRED, W, r, sensor, INN, na):
        """``INN[2i:2i + 2, a]``: the range and bearing innovation of landmark i for particle a, the
        measurement taken at the TRUE state ``X`` (std at the true range, bearing wrapped), predicted at
        ``PRED``, the bearing residual wrapped to ``(-pi, pi]``; 0 where the true state does not see the
        landmark. Twin of :meth:`firmtool.models.landmarks.LandmarkModel.innovation` of its
        :meth:`~firmtool.models.landmarks.LandmarkModel.measure`; pinned by
        tests/test_landmarks.py::test_landmark_update_is_the_numpy_update."""
        landmarks, consts, grid, occlusion, heading = sensor
        max_range, half_fov, rstd, growth, bstd = consts[0], consts[1], consts[2], consts[3], consts[4]
        occ, res, x0, y0, gc, gs = grid
        for a in range(na):
            px, py = X[0, a], X[1, a]
            th = X[heading, a] if heading >= 0 else 0.0
            qx, qy = PRED[0, a], PRED[1, a]
            qth = PRED[heading, a] if heading >= 0 else 0.0
            for i in range(landmarks.shape[0]):
                lx, ly = landmarks[i, 0], landmarks[i, 1]
                dx, dy = lx - px, ly - py
                rr = np.sqrt(dx * dx + dy * dy)
                seen = rr > MIN_RANGE and rr <= max_range
                b = 0.0
                if seen:  # the bearing only where the range lets the landmark be seen
                    b = wrap_pi(np.arctan2(dy, dx) - th)
                    if half_fov < np.pi:
                        seen = abs(b) <= half_fov
                if seen and occlusion:
                    seen = not occluded(px, py, lx, ly, occ, res, x0, y0, gc, gs)
                if not seen:
                    INN[2 * i, a] = 0.0
                    INN[2 * i + 1, a] = 0.0
                    continue
                zr = rr + (rstd + growth * rr) * W[r + 2 * i, a]
                zb = wrap_pi(b + bstd * W[r + 2 * i + 1, a])
                ex, ey = lx - qx, ly - qy
                INN[2 * i, a] = zr - np.sqrt(ex * ex + ey * ey)
                INN[2 * i + 1, a] = wrap_pi(zb - wrap_pi(np.arctan2(ey, ex) - qth))

    def landmark_update(A, B, H, L_k, X, XH, U, W, rows, sensor, sensing, params, PRED, HZ, INN, TMP, na):
        """The estimates' update with landmark sensing: the bound ``predict``, the innovations of
        :func:`landmark_innovation`, the precomputed gain. Twin of
        :func:`firmtool.estimation.edges.filter_update` with a landmark model."""
        n, nz = PRED.shape[0], H.shape[0]
        predict(A, B, params, XH, U, PRED, TMP, na)
        landmark_innovation(X, PRED, W, W.shape[0] - nz, sensor, INN, na)
        mat_rows(L_k, INN, TMP, n, na)
        for j in range(n):
            for a in range(na):
                XH[j, a] = PRED[j, a] + TMP[j, a]


_specialised: dict[tuple, dict[str, Callable]] = {}


def model_functions(hook_step: Callable | None, sensor: str) -> dict[str, Callable]:
    """``{"advance": ..., "update": ...}`` for a model whose step is ``hook_step`` (None: linear) and whose
    sensor is ``sensor`` (:data:`LANDMARKS`, else the robot's own with a noise law), specialised once
    per process (cached on disk where the hook is importable)."""
    key = (hook_step, sensor == LANDMARKS)
    hit = _specialised.get(key)
    if hit is not None:
        return hit
    cache = hook_step is None or importable(hook_step)
    if hook_step is None:
        advance, pred = linear_advance, predict_linear
    else:
        advance = specialise(nonlinear_advance, {"model_step": hook_step}, INLINE, cache=cache)
        pred = specialise(predict_nonlinear, {"model_step": hook_step}, INLINE, cache=cache)
    if sensor == LANDMARKS:
        update = specialise(landmark_update, {"predict": pred}, INLINE, cache=cache)
    elif hook_step is None:
        update = linear_update
    else:
        update = specialise(position_update, {"predict": pred}, INLINE, cache=cache)
    hit = _specialised[key] = {"advance": advance, "update": update}
    return hit
