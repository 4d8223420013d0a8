"""Goal balls in the task space, and the chance constraint under which a belief may declare arrival.

A task may state its goal as a ball ``{t : ||t - c|| < r}`` in the robot's task space (the point
robot's position, the arm's tip: :meth:`firmtool.robots.Robot.task_point`, ``t = T(x)``). The policy
may declare arrival when its belief ``b = (xhat, P)`` satisfies

    ||T(xhat) - c|| < r     and     Pr( ||T(x) - c|| < r  |  x ~ N(xhat, P) ) >= confidence,

the second term with the task point linearised at the mean: ``T(x) ~ N(T(xhat), J P J')``, ``J``
the task Jacobian (:meth:`~firmtool.robots.Robot.task_jacobian`). With perfect measurements the
belief is the state and only the first term counts. The goal region of the roadmap is this set of
beliefs (not the stationary-covariance test of ordinary nodes, :mod:`firmtool.roadmap.nodes`): a belief
that arrives from the light with a small covariance meets it where the stationary belief in the
dark would not.

The probability of a Gaussian in a ball (:func:`ball_probability`, D = 1, 2 or 3) has no closed
form unless the covariance is isotropic (then it is a noncentral chi-square CDF: scipy's ``ncx2``,
which the tests compare against). With ``y = m + L z`` (``L L' = cov``, ``z ~ N(0, I)``) the ball is
an ellipsoid ``E`` in z; along each direction ``u`` the ray from the origin meets ``E`` on an
interval ``[rho_1(u), rho_2(u)]`` (the roots of ``||m + rho L u||^2 = r^2``), and since ``||z||`` and
its direction are independent (``||z||^2 ~ chi2_D``, direction uniform),

    Pr = mean over directions u of  [ F_D(rho_2(u)^2) - F_D(rho_1(u)^2) ],   F_D the chi2_D CDF

(``rho_1 = 0`` when the mean lies in the ball, which the goal test requires). The integrand is a
smooth periodic function of the angle, so the trapezoid rule converges exponentially (2-D; in 3-D a
Gauss-Legendre rule in the polar cosine times the trapezoid rule in the azimuth). It is sharp only
when the mean lies within a small fraction of a standard deviation of the ball's edge (features of
that width): the rule is refined level by level (doubling the directions) until two levels agree
within :data:`PROBABILITY_TOLERANCE` or, for the decision ``Pr >= confidence``, until the gap to the
confidence exceeds four times the change between levels, up to :data:`MAX_LEVEL` doublings. No
maintained library computes this (the generalised chi-square's CDF is in none of numpy/scipy;
Imhof's formula needs a truncated oscillating integral, a worse fit for a decision in the hot loop).

The decision ``Pr >= confidence`` is first taken from two exact bounds (most beliefs are far from
the threshold): by Anderson's theorem the ball of radius ``r - d`` around the mean (``d = ||m - c||``)
holds at least ``chi2_D.cdf((r - d)^2 / lambda_max)``, which accepts; the slab ``|u'(t - c)| < r``
along any unit ``u`` contains the ball, so ``Pr`` is at most the slab's probability (``u`` along the
mean's offset and along the top eigenvector), which rejects. The compiled Monte Carlo engine
reproduces the same test for planar task spaces (:func:`firmtool.estimation.compiled.goal.goal_test`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.special import erf, gammaincinv, ndtr

BASE_DIRECTIONS = 64  # directions of the first level (2-D); each level doubles them
MAX_LEVEL = 7  # at most BASE_DIRECTIONS * 2**MAX_LEVEL directions (2-D)
BASE_POLAR = 12  # 3-D: Gauss-Legendre nodes in the polar cosine at the first level (doubled per level)
MAX_LEVEL_3D = 3
PROBABILITY_TOLERANCE = 1e-10  # ball_probability refines until two levels agree this closely
MIN_STD_FRACTION = 1e-9  # covariances are floored at (this fraction of the radius)^2 I


def chi2_ppf(q: float, df: float) -> float:
    """``scipy.stats.chi2.ppf(q, df)`` for 0 < q < 1, by the special function it calls
    (``2 gammaincinv(df / 2, q)``, the same bits): ``scipy.stats`` costs a command 1.4 s of import."""
    return 2.0 * gammaincinv(df / 2.0, q)


def _chi2_cdf(t: np.ndarray, D: int) -> np.ndarray:
    """The chi-square CDF with D = 1, 2 or 3 degrees of freedom at ``t >= 0`` (closed forms)."""
    if D == 1:
        return erf(np.sqrt(0.5 * t))
    if D == 2:
        return -np.expm1(-0.5 * t)
    return erf(np.sqrt(0.5 * t)) - np.sqrt(2.0 * t / np.pi) * np.exp(-0.5 * t)


def _interval_probability(b, m, s):
    """Pr(|y| < b) for y ~ N(m, s^2), elementwise."""
    return ndtr((b - m) / s) - ndtr((-b - m) / s)


def whitening(cov: np.ndarray, radius: float) -> np.ndarray:
    """Lower Cholesky factors (M, D, D) of the covariances floored at ``(MIN_STD_FRACTION r)^2 I``."""
    D = cov.shape[-1]
    floor = (MIN_STD_FRACTION * radius) ** 2
    sym = 0.5 * (cov + np.swapaxes(cov, -1, -2)) + floor * np.eye(D)
    return np.linalg.cholesky(sym)


def directions(D: int, level: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions (Q, D) and weights (Q,) summing to 1 of the level's rule on the circle or sphere.

    2-D: ``BASE_DIRECTIONS 2^level`` equally spaced angles (each level's odd nodes are the new ones);
    3-D: Gauss-Legendre in the polar cosine (``BASE_POLAR 2^level`` nodes) times twice as many
    equally spaced azimuths; 1-D: the two directions +-1."""
    if D == 1:
        return np.array([[1.0], [-1.0]]), np.array([0.5, 0.5])
    if D == 2:
        N = BASE_DIRECTIONS << level
        phi = 2.0 * np.pi * np.arange(N) / N
        return np.stack([np.cos(phi), np.sin(phi)], axis=1), np.full(N, 1.0 / N)
    nt = BASE_POLAR << level
    t, wt = np.polynomial.legendre.leggauss(nt)
    nphi = 2 * nt
    phi = 2.0 * np.pi * np.arange(nphi) / nphi
    st = np.sqrt(1.0 - t * t)
    u = np.stack([(st[:, None] * np.cos(phi)).ravel(), (st[:, None] * np.sin(phi)).ravel(), np.repeat(t, nphi)],
                 axis=1)
    return u, np.repeat(0.5 * wt, nphi) / nphi


def _ray_rule(mean: np.ndarray, L: np.ndarray, radius: float, u: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The direction rule ``(u, w)`` of Pr(||m + L z|| < r): (M, D), (M, D, D) -> (M,) (module notes)."""
    D = mean.shape[1]
    Lu = np.einsum("mij,qj->mqi", L, u)  # (M, Q, D)
    a = np.einsum("mqi,mqi->mq", Lu, Lu)
    b = np.einsum("mqi,mi->mq", Lu, mean)
    c = (np.einsum("mi,mi->m", mean, mean) - radius * radius)[:, None]
    disc = b * b - a * c
    root = np.sqrt(np.maximum(disc, 0.0))
    far = (-b + root) / a
    near = np.maximum((-b - root) / a, 0.0)
    hit = (disc > 0) & (far > 0)
    g = np.where(hit, _chi2_cdf(far * far, D) - _chi2_cdf(near * near, D), 0.0)
    return g @ w


def _levels(mean: np.ndarray, L: np.ndarray, radius: float, settled) -> np.ndarray:
    """Refine the direction rule level by level for the rows ``settled(p, change)`` does not settle."""
    M, D = mean.shape
    top = 0 if D == 1 else (MAX_LEVEL if D == 2 else MAX_LEVEL_3D)
    p = _ray_rule(mean, L, radius, *directions(D, 0))
    rows = np.arange(M)
    for level in range(1, top + 1):
        if rows.size == 0:
            break
        if D == 2:  # the new (odd) angles of this level; the even ones are the previous level's
            u, w = directions(2, level)
            fresh = _ray_rule(mean[rows], L[rows], radius, u[1::2], 2.0 * w[1::2])
            new = 0.5 * (p[rows] + fresh)
        else:
            new = _ray_rule(mean[rows], L[rows], radius, *directions(D, level))
        change = np.abs(new - p[rows])
        p[rows] = new
        rows = rows[~settled(new, change, rows)]
    return np.clip(p, 0.0, 1.0)


def ball_probability(mean: np.ndarray, cov: np.ndarray, radius: float) -> np.ndarray:
    """Probability that ``y ~ N(mean, cov)`` lies in the ball of ``radius`` about the origin.

    Parameters
    ----------
    mean : (M, D) means relative to the ball's centre, D = 1, 2 or 3.
    cov : (M, D, D) or (D, D) symmetric positive semi-definite covariances (floored at
        ``(1e-9 radius)^2 I``).
    radius : r > 0.

    Returns
    -------
    (M,) probabilities in [0, 1], refined until two levels of the rule agree within
    :data:`PROBABILITY_TOLERANCE` (or the last level). For a mean inside the ball (what the goal
    test evaluates) the result is within 1e-12 of the exact value on the tests' cases; for a mean
    outside, the integrand has kinks where rays graze the ellipsoid and the last level is within
    ~1e-5 (see the module notes).
    """
    mean = np.atleast_2d(np.asarray(mean, dtype=float))
    M, D = mean.shape
    if M == 0:
        return np.zeros(0)
    cov = np.broadcast_to(np.asarray(cov, dtype=float), (M, D, D))
    return _levels(mean, whitening(cov, radius), float(radius), lambda p, change, rows: change < PROBABILITY_TOLERANCE)


def meets_confidence(mean: np.ndarray, cov: np.ndarray, radius: float, confidence: float) -> np.ndarray:
    """``ball_probability(mean, cov, radius) >= confidence`` (M,) bool, from the exact bounds where they
    settle it (:func:`confidence_bounds`) and the rule refined until the gap to ``confidence`` exceeds
    four times the last change (or the last level) elsewhere."""
    mean = np.atleast_2d(np.asarray(mean, dtype=float))
    M, D = mean.shape
    cov = np.broadcast_to(np.asarray(cov, dtype=float), (M, D, D))
    accept, reject = confidence_bounds(mean, cov, radius, confidence)
    out = accept.copy()
    open_ = np.flatnonzero(~(accept | reject))
    if open_.size:
        p = _levels(mean[open_], whitening(cov[open_], radius), float(radius),
                    lambda p, change, rows: np.abs(p - confidence) > 4.0 * change)
        out[open_] = p >= confidence
    return out


def confidence_bounds(mean: np.ndarray, cov: np.ndarray, radius: float, confidence: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact decisions of ``ball_probability(mean, cov, radius) >= confidence`` where cheap bounds
    settle it: ``(accept, reject)`` bool (M,) each (neither: compute the probability).

    Accept: Anderson's theorem on the ball of radius ``r - ||mean||`` around the mean. Reject: the
    slabs ``|u'y| < r`` that contain the ball, ``u`` along the mean and along the top eigenvector.
    In 3-D also the cubes along the covariance's eigenvectors (where the coordinates are independent,
    so a cube's probability is the product of three intervals'): the one of half-side ``r / sqrt(3)``
    lies in the ball (accept), the one of half-side ``r`` holds it (reject). They settle most of the
    beliefs the direction rule would otherwise refine (~15 us per belief at its first level; measured:
    two thirds of the compiled engine's time on arm7_shelf's edges).
    """
    mean = np.atleast_2d(mean)
    M, D = mean.shape
    cov = np.broadcast_to(np.asarray(cov, dtype=float), (M, D, D))
    lam, U = np.linalg.eigh(0.5 * (cov + np.swapaxes(cov, 1, 2)))
    lam = np.maximum(lam, (MIN_STD_FRACTION * radius) ** 2)
    d = np.sqrt(np.einsum("mi,mi->m", mean, mean))
    q = float(chi2_ppf(confidence, D))
    accept = (d < radius) & ((radius - d) ** 2 >= q * lam[:, -1])
    u = np.where(d[:, None] > 0, mean / np.where(d > 0, d, 1.0)[:, None], U[:, :, -1])
    su = np.sqrt(np.maximum(np.einsum("mi,mij,mj->m", u, cov, u), lam[:, 0]))
    slab_mean = _interval_probability(radius, d, su)
    top = U[:, :, -1]
    slab_top = _interval_probability(radius, np.einsum("mi,mi->m", top, mean), np.sqrt(lam[:, -1]))
    if D == 3:
        mu = np.einsum("mji,mj->mi", U, mean)  # the mean in the eigenbasis
        sd = np.sqrt(lam)
        inner = np.prod(_interval_probability(radius / np.sqrt(3.0), mu, sd), axis=1)
        accept |= (d < radius) & (inner >= confidence)
        slab_top = np.minimum(slab_top, np.prod(_interval_probability(radius, mu, sd), axis=1))
    reject = (np.minimum(slab_mean, slab_top) < confidence) & ~accept
    return accept, reject


@dataclass(frozen=True)
class GoalRegion:
    """The goal region of a goal ball: the beliefs that may declare arrival (see the module notes).

    Attributes
    ----------
    center : (D,) the ball's centre in the task space; radius : its radius.
    confidence : the probability under the belief that the true task point is in the ball.
    perfect : perfect measurements (the belief is the state: only the mean counts).
    task_point : states (M, n) -> task points (M, D); task_jacobian : states (M, n) -> (M, D, n).
    compiled_task_point : ``(fn, params, work)`` of the robot's compiled hooks
        (:class:`~firmtool.robots.compiled.CompiledKinematics`: ``fn(xh, params, work) -> (tx, ty)``), or
        None: the prefilter of :meth:`contains` for one belief.
    """

    center: np.ndarray
    radius: float
    confidence: float
    perfect: bool
    task_point: Callable[[np.ndarray], np.ndarray]
    task_jacobian: Callable[[np.ndarray], np.ndarray]
    compiled_task_point: tuple | None = field(default=None, compare=False, repr=False)

    # A mean whose compiled task point lies this far outside the ball (relative to r^2; the compiled
    # forward kinematics agree with the numpy ones to ~1e-15) is outside by the numpy test too.
    PREFILTER_MARGIN = 1e-9

    def surely_outside(self, xhat: np.ndarray) -> bool:
        """Whether the mean ``xhat`` (n,) is outside the ball by the compiled task point with a margin
        (then :meth:`contains` is False; False: ask :meth:`contains`). The online policy asks every
        control period, and the numpy task point was ~90 us of the arm's ~270 us step (issue 39)."""
        fast = self.compiled_task_point
        if fast is None:
            return False
        fn, params, work = fast
        t = fn(xhat, params, work)  # the task point, 2 or 3 coordinates
        c = self.center
        if len(t) == 2 == c.shape[0]:
            dx, dy = t[0] - c[0], t[1] - c[1]
            d2 = dx * dx + dy * dy
        elif len(t) == 3 == c.shape[0]:
            dx, dy, dz = t[0] - c[0], t[1] - c[1], t[2] - c[2]
            d2 = dx * dx + dy * dy + dz * dz
        else:
            return False
        return d2 >= self.radius * self.radius * (1.0 + self.PREFILTER_MARGIN) + 1e-300

    @property
    def dim(self) -> int:
        return int(self.center.shape[0])

    def task_covariance(self, xhat: np.ndarray, P: np.ndarray) -> np.ndarray:
        """The task point's covariance ``J P J'`` (M, D, D) at estimates (M, n) for one covariance P (n, n)."""
        J = self.task_jacobian(xhat)
        return np.einsum("mdi,ij,mej->mde", J, P, J)

    def mean_inside(self, xhat: np.ndarray) -> np.ndarray:
        """Whether each estimate's task point lies in the ball: (M, n) -> bool (M,)."""
        t = self.task_point(np.atleast_2d(xhat)) - self.center
        return np.einsum("md,md->m", t, t) < self.radius * self.radius

    def true_inside(self, x: np.ndarray) -> np.ndarray:
        """Whether each TRUE state's task point lies in the ball (how the environment judges an
        arrival): (M, n) -> bool (M,)."""
        return self.mean_inside(x)

    def probability(self, xhat: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Pr(true task point in the ball) under the beliefs ``(xhat_i, P)``: (M, n), (n, n) -> (M,)."""
        xhat = np.atleast_2d(np.asarray(xhat, dtype=float))
        t = self.task_point(xhat) - self.center
        if self.perfect or not np.any(P):
            return (np.einsum("md,md->m", t, t) < self.radius * self.radius).astype(float)
        return ball_probability(t, self.task_covariance(xhat, P), self.radius)

    def contains(self, xhat: np.ndarray, P: np.ndarray | None) -> np.ndarray:
        """Whether each belief ``(xhat_i, P)`` lies in the goal region: (M, n), (n, n) -> bool (M,)."""
        xhat = np.atleast_2d(np.asarray(xhat, dtype=float))
        if xhat.shape[0] == 1 and self.surely_outside(np.ascontiguousarray(xhat[0])):
            return np.zeros(1, dtype=bool)
        t = self.task_point(xhat) - self.center
        inside = np.einsum("md,md->m", t, t) < self.radius * self.radius
        if self.perfect or P is None or not np.any(P) or not inside.any():
            return inside
        rows = np.flatnonzero(inside)
        ok = meets_confidence(t[rows], self.task_covariance(xhat[rows], P), self.radius, self.confidence)
        out = np.zeros(xhat.shape[0], dtype=bool)
        out[rows] = ok
        return out
