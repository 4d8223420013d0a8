"""The compiled kernel's step helpers, all particles at once: the particles as columns, the control
from the estimates, the true states' step, the filter update with the measurement noise at the true
state, the control effort.

The live particles' states are columns of (state, particle) arrays, so that the linear algebra is
loops over particles (SIMD lanes) with the matrices' entries as loop constants; products add their
terms in column order and skip exact zeros (:func:`firmtool.control.linalg.mat_rows`), which per
particle is the value of the dense row product. Each helper's docstring names the numpy function it
reproduces and the test that pins the two together.
"""

from __future__ import annotations

import numpy as np

from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba

#: the compiled twins of the measurement noise laws (a law's ``compiled`` name -> its code in
#: :func:`measurement_variance`); a law without one runs the numpy engine
NOISE_FORMS = {"lightdark_std": 0, "lightdark_variance": 1, "constant": 2}


def sensor_group(noise) -> tuple:
    """The kernel's sensor group ``(form, light_x, eta, sigma_b, a, c, std)`` of a noise law with a
    compiled twin (:data:`NOISE_FORMS`; the constants it does not have are 0)."""
    p = noise.compiled_params()
    return (NOISE_FORMS[noise.compiled],
            *(float(p.get(k, 0.0)) for k in ("light_x", "eta", "sigma_b", "a", "c", "std")))


if numba is not None:
    from firmtool.control.linalg import mat_rows

    # The step's helpers are inlined into the kernel at numba's IR level: compiled separately (and
    # then inlined by LLVM), they ran at the same speed but made the kernel's cold compile ~15% longer
    # (each separately compiled function costs its own typing and optimisation passes). Called from
    # Python (the tests) they compile as usual.
    step = cached_njit(**KERNEL_OPTIONS, inline="always")

    @step
    def linear_step(A, B, X, U, out, TMP, na):
        """``out = A X + B U`` over the first ``na`` particle columns (``TMP``: work array): the
        noise-free dynamics. Twin of :meth:`firmtool.models.linear.LinearGaussianModel.f`; pinned by
        tests/test_kernels.py::test_control_and_true_step_are_the_numpy_step."""
        n = A.shape[0]
        mat_rows(A, X, out, n, na)
        mat_rows(B, U, TMP, n, na)
        for j in range(n):
            for a in range(na):
                out[j, a] += TMP[j, a]

    @step
    def gather_columns(rows, alive, cols, na):
        """``cols[:, a] = rows[alive[a]]`` for ``a < na``: particles (rows) to the kernel's columns."""
        for a in range(na):
            i = alive[a]
            for j in range(rows.shape[1]):
                cols[j, a] = rows[i, j]

    @step
    def scatter_columns(cols, alive, rows, na):
        """``rows[alive[a]] = cols[:, a]`` for ``a < na``: back to the caller's (particle, state) rows."""
        for a in range(na):
            i = alive[a]
            for j in range(rows.shape[1]):
                rows[i, j] = cols[j, a]

    @step
    def control(XH, x_ref_k, u_ref_k, K_k, DX, U, na):
        """``U = u_ref - K (XH - x_ref)``: the step's controls from the estimates (``DX``: work array).
        Twin of the control line of :func:`firmtool.estimation.edges.control_and_move`; pinned by
        tests/test_kernels.py::test_control_and_true_step_are_the_numpy_step."""
        n, m = XH.shape[0], U.shape[0]
        for j in range(n):
            xr = x_ref_k[j]
            for a in range(na):
                DX[j, a] = XH[j, a] - xr
        mat_rows(K_k, DX, U, m, na)
        for j in range(m):
            ur = u_ref_k[j]
            for a in range(na):
                U[j, a] = ur - U[j, a]

    @step
    def true_step(A, B, F, X, U, W, XN, TMP, na):
        """``XN = (A X + B U) + F W[:r]``: the true states' step with process noise (``W``'s first ``r =
        F.shape[1]`` rows). Twin of :func:`firmtool.estimation.edges.control_and_move`'s ``model.f(x, u) + w F'``;
        pinned by tests/test_kernels.py::test_control_and_true_step_are_the_numpy_step."""
        n = A.shape[0]
        linear_step(A, B, X, U, XN, TMP, na)
        mat_rows(F, W, TMP, n, na)
        for j in range(n):
            for a in range(na):
                XN[j, a] += TMP[j, a]

    @step
    def measurement_variance(sensor, sensing_x):
        """The measurement noise variance for a sensing point at x-coordinate ``sensing_x``, per form:
        light-dark standard deviation (paper eq. 14), light-dark variance (Platt et al.), constant.
        Twin of :meth:`firmtool.models.linear.LightDarkNoise.variance`; pinned by
        tests/test_kernels.py::test_measurement_variance_is_the_noise_models."""
        form, light_x, eta, sigma_b, na_, nc, nstd = sensor
        dd = sensing_x - light_x
        if form == 0:
            s_ = eta * abs(dd) + sigma_b
            return s_ * s_
        if form == 1:
            return na_ * dd * dd + nc
        return nstd * nstd

    @step
    def filter_update(A, B, H, L_k, X, XH, U, W, PX, sensor, sensing, PRED, HZ, INN, TMP, na):
        """The estimates' update in place: prediction ``A XH + B U``, measurement of the true states
        ``H X`` with noise ``W[r:]`` scaled by the standard deviation at the TRUE state (its sensing
        points' x in ``PX[sensing]``), innovation against ``H`` of the prediction, correction by the
        precomputed gain ``L_k``. Twin of :func:`firmtool.estimation.edges.filter_update` (the variance as
        ``model.noise.variance(problem.geometry.sensing_from_points(points))``); pinned by
        tests/test_kernels.py::test_filter_update_is_the_numpy_update."""
        n, nz, r = A.shape[0], H.shape[0], W.shape[0] - H.shape[0]
        linear_step(A, B, XH, U, PRED, TMP, na)
        mat_rows(H, X, HZ, nz, na)
        mat_rows(H, PRED, INN, nz, na)
        for j in range(nz):
            prow = PX[sensing[j]]
            for a in range(na):
                var = measurement_variance(sensor, prow[a])
                INN[j, a] = (HZ[j, a] + np.sqrt(var) * W[r + j, a]) - INN[j, a]
        mat_rows(L_k, INN, TMP, n, na)
        for j in range(n):
            for a in range(na):
                XH[j, a] = PRED[j, a] + TMP[j, a]

    @step
    def control_effort(U, E, na):
        """``E[a] = |U[:, a]|^2``: the step's control effort per particle. Twin of
        :func:`firmtool.estimation.edges.simulate`'s ``einsum("ij,ij->i", u, u)``; pinned by the cost terms of
        tests/test_kernels.py::test_point_robot_same_noise_same_outcomes."""
        for a in range(na):
            E[a] = 0.0
        for j in range(U.shape[0]):
            for a in range(na):
                E[a] += U[j, a] * U[j, a]
