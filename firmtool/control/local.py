"""Time-varying LQG local controllers: an edge controller along a nominal trajectory, then the
target node's stabiliser.

All gains and covariances of one local controller are computed once, by :func:`plan_local_controller`
(or, for a batch of edges, :func:`plan_local_controllers`, the same arrays bit for bit), and are the
same for every particle. The backward Riccati recursion runs at design time; the forward ones (the
Kalman filter's, the decision state's spread) run lazily, as far as a caller reads
(:class:`LocalController`, :mod:`firmtool.control.recursions`). With perfect measurements the
estimator is the identity (``P = 0``): the same code path, with no Kalman gains.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from firmtool.control.recursions import filter_recursion, filter_recursions, spread_recursion
from firmtool.control.stabilisers import NodeController
from firmtool.models.base import Model
from firmtool.models.linear import LinearGaussianModel


class _ForwardRecursion:
    """The inputs of the forward recursions of one local controller, and how far each has run: the
    filter's (:func:`~firmtool.control.recursions.filter_recursion`: L, P, innovation covariances),
    which a Monte Carlo needs, and the spread's (:func:`~firmtool.control.recursions.spread_recursion`),
    which only execution reads."""

    def __init__(self, A_steps, B_steps, H_steps, index, K, variances, Qd, perfect, L, P, innovation, spread):
        self.filter_args = (A_steps, H_steps, index, variances, Qd, L, P, innovation)
        self.spread_args = (A_steps, B_steps, index, K, Qd, perfect, L, innovation, spread)
        self.L, self.P, self.innovation, self.spread = L, P, innovation, spread  # the buffers they fill
        self.perfect = perfect
        self.Sigma = np.zeros((Qd.shape[0], Qd.shape[0]))
        self.done = 0
        self.spread_done = 0

    def run(self, k: int) -> None:
        """The filter recursion through step ``k``."""
        if k > self.done:
            if not self.perfect:  # perfect measurements: no filter (P = 0, no L)
                filter_recursion(*self.filter_args, self.done, k)
            self.done = k

    def run_spread(self, k: int) -> None:
        """The spread recursion (and the filter's, which drives it) through step ``k``."""
        if k > self.spread_done:
            self.run(k)
            spread_recursion(*self.spread_args, self.Sigma, self.spread_done, k)
            self.spread_done = k


class LocalController:
    """Edge controller followed by the target's stabiliser, unrolled over ``steps`` steps.

    Step ``k`` (0-based) applies ``u = u_ref[k] - K[k] (xhat - x_ref[k])``; the filter update
    after it uses ``L[k]`` and yields covariance ``P[k + 1]`` (``P[0]`` is the start covariance).
    Node membership is tested only from step ``edge_steps`` on (the stabiliser's phase).

    Attributes
    ----------
    x_ref (T, n), u_ref (T, m), K (T, m, n), edge_steps : the reference and the LQR gains.
    L (T, n, nz), P (T + 1, n, n) : Kalman update gains and a-posteriori covariances.
    innovation_cov : (T, nz, nz) innovation covariance ``H_k P-_k H_k' + R_k`` of every step as
        designed (None with perfect measurements), for consistency tests of the filter during execution.
    spread : (T + 1, n) standard deviation of the decision state around the reference, from a start
        on the nominal: how far an undisturbed estimate is expected to stray at each step (replanning scale).

    The filter side (``L``, ``P``, ``innovation_cov``) and the ``spread`` come from forward recursions
    over all ``T = edge_steps + stabiliser steps`` steps, which run lazily: :meth:`compute` runs the
    filter's only as far as asked (a Monte Carlo needs only the steps its particles live, usually a
    few past ``edge_steps`` of ~``edge_steps + 200``, and never the spread), :meth:`head` both, and
    reading one of these attributes runs its recursion to the end. Every step is computed by the same
    code in the same order either way, so the values do not depend on how far, or in how many pieces,
    the recursion ran.
    """

    def __init__(self, x_ref: np.ndarray, u_ref: np.ndarray, K: np.ndarray, L: np.ndarray, P: np.ndarray,
                 edge_steps: int, innovation_cov: np.ndarray | None = None, spread: np.ndarray | None = None,
                 *, forward: _ForwardRecursion | None = None) -> None:
        self.x_ref, self.u_ref, self.K, self.edge_steps = x_ref, u_ref, K, edge_steps
        self._L, self._P, self._innovation, self._spread = L, P, innovation_cov, spread
        self._forward = forward

    @property
    def steps(self) -> int:
        return self.x_ref.shape[0]

    def compute(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Run the filter recursion through step ``k`` (at most ``steps``): ``L[:k]``, ``P[:k + 1]``
        and ``innovation_cov[:k]`` are then final (the spread is not: :meth:`head`, :attr:`spread`).

        Returns the full-length buffers ``(L, P)``; their rows past ``k`` may not be computed yet."""
        fw = self._forward
        if fw is not None:
            fw.run(min(k, self.steps))
        return self._L, self._P

    def _compute_spread(self, k: int) -> None:
        fw = self._forward
        if fw is not None:
            fw.run_spread(min(k, self.steps))
            if fw.spread_done >= self.steps:
                self._forward = None

    def head(self, k: int) -> "LocalController":
        """The first ``k`` steps of this controller (views), every array computed only that far."""
        k = max(0, min(k, self.steps))
        self._compute_spread(k)
        return LocalController(self.x_ref[:k], self.u_ref[:k], self.K[:k], self._L[:k], self._P[:k + 1],
                               self.edge_steps, None if self._innovation is None else self._innovation[:k],
                               None if self._spread is None else self._spread[:k + 1])

    def _filter_done(self) -> bool:
        fw = self._forward
        return fw is None or fw.done >= self.steps

    # the online policy reads L[k] and P[k + 1] every control period: once the recursion is complete,
    # no call into compute (its chain was ~2 us of the point robot's ~80 us step)
    @property
    def L(self) -> np.ndarray:
        return self._L if self._filter_done() else self.compute(self.steps)[0]

    @property
    def P(self) -> np.ndarray:
        return self._P if self._filter_done() else self.compute(self.steps)[1]

    @property
    def innovation_cov(self) -> np.ndarray | None:
        self.compute(self.steps)
        return self._innovation

    @property
    def spread(self) -> np.ndarray | None:
        self._compute_spread(self.steps)
        return self._spread


# Relative change of the LQR Riccati solution S over one backward step below which S counts as
# stationary (time-invariant linearisation only): the gains of the remaining steps are then the
# current one. Near the stationary solution the backward map contracts, so the gains differ from the
# full recursion's by O(BACKWARD_RTOL) relative (tests/test_controllers.py checks 1e-9).
BACKWARD_RTOL = 1e-12


def _same_matrices(jacobians: list[tuple[np.ndarray, ...]]) -> bool:
    """Whether every step's matrices are the first step's (the same objects, or equal arrays)."""
    if not jacobians:
        return False
    first = jacobians[0]
    return all(all(a is b or np.array_equal(a, b) for a, b in zip(first, j)) for j in jacobians[1:])


def plan_local_controller(model: Model, x_nominal: np.ndarray, u_nominal: np.ndarray,
                          P0: np.ndarray, target: NodeController, Wx: np.ndarray, Wu: np.ndarray,
                          stabiliser_steps: int, perfect: bool) -> LocalController:
    """Time-varying LQG along a nominal trajectory, then the target's stabiliser.

    The model is linearised about the nominal at every step (``A_k, B_k = df/dx, df/du`` at
    ``(x_k, u_k)``, ``H_k = dh/dx`` at the state the step lands on); for a linear model these are
    its constant matrices. LQR gains come from the backward Riccati recursion with terminal cost
    ``target.S`` (for a time-invariant model this reproduces the stationary gain; for linearised
    models it does not). Kalman gains come from the forward covariance recursion with R at the
    NOMINAL states. During the stabiliser phase the reference, gains and linearisation are the
    target's: constant (centre, ``u_eq``, ``K``; R at the centre) for a stationary stabiliser, so
    ``P`` converges to ``target.P``; the orbit's at phase ``k mod T`` for a periodic one
    (``target.periodic``), so ``P`` converges to the periodic ``P_k`` and the stabiliser starts at
    phase 0 when the edge ends at the centre (the edge arrives in phase).

    Parameters
    ----------
    x_nominal : (iota + 1, n) nominal states, ``x_nominal[-1]`` the target centre.
    u_nominal : (iota, m) nominal inputs.
    P0 : (n, n) covariance at the start (the start node's P_s).
    stabiliser_steps : steps the stabiliser may run before the controller times out.
    """
    n, m = model.n, model.m
    iota = u_nominal.shape[0]
    T = iota + stabiliser_steps
    sx, su, sK, phase = _stabiliser_phases(target, T - iota)
    x_ref = np.empty((T, n))
    u_ref = np.empty((T, m))
    x_ref[:iota], u_ref[:iota] = x_nominal[:-1], u_nominal
    x_ref[iota:], u_ref[iota:] = sx[phase], su[phase]

    # Linearisation per step: along the nominal, then the stabiliser's (once per phase).
    edge_jac = [model.dynamics_jacobians(x_nominal[k], u_nominal[k]) for k in range(iota)]
    stab_jac = [model.dynamics_jacobians(sx[p], su[p]) for p in range(su.shape[0])]

    K = np.empty((T, m, n))
    K[iota:] = sK[phase]
    # A model whose linearisation is the same at every step (a linear one): once S is stationary
    # within BACKWARD_RTOL, every earlier gain is the current one (within that tolerance; for a
    # linear model the terminal S is the stationary solution, so the recursion stops at once).
    uniform = _same_matrices(edge_jac)
    _backward_riccati(edge_jac, target.S, Wx, Wu, uniform, K)
    forward = _forward_recursion(model, x_nominal, sx, phase, edge_jac, stab_jac, uniform, K, P0, perfect)
    return LocalController(x_ref=x_ref, u_ref=u_ref, K=K, L=forward.L, P=forward.P, edge_steps=iota,
                           innovation_cov=None if perfect else forward.innovation, spread=forward.spread,
                           forward=forward)


def _stabiliser_phases(target: NodeController, steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The target's stabiliser as an orbit, ``(x (period + 1, n), u (period, m), K (period, m, n))``,
    and the phase (steps,) of each of its ``steps`` steps: a stationary stabiliser is the period-1
    case (the centre, ``u_eq``, ``K``), a periodic one (``target.periodic``) its orbit from phase 0."""
    orbit = target.periodic
    if orbit is None:  # a stationary stabiliser is the period-1 case
        sx, su, sK = np.stack([target.center, target.center]), target.u_eq[None], target.K[None]
    else:
        sx, su, sK = orbit.x, orbit.u, orbit.K
    return sx, su, sK, np.arange(steps) % su.shape[0]


def _backward_riccati(edge_jac: list[tuple[np.ndarray, np.ndarray]], S: np.ndarray, Wx: np.ndarray,
                      Wu: np.ndarray, uniform: bool, K: np.ndarray) -> None:
    """The backward Riccati recursion along the edge (its ``iota`` linearisations ``(A_k, B_k)``) from
    the terminal cost ``S`` (n, n): fills the edge's gains ``K[:iota]`` of ``K`` (T, m, n) in place.
    With ``uniform`` (the same matrices at every step) it stops once S is stationary within
    :data:`BACKWARD_RTOL`, and the earlier gains are the current one."""
    for k in range(len(edge_jac) - 1, -1, -1):  # backward Riccati along the edge
        A, B = edge_jac[k]
        BS = B.T @ S
        K[k] = np.linalg.solve(Wu + BS @ B, BS @ A)
        S_prev = S
        S = Wx + A.T @ S @ (A - B @ K[k])
        S = 0.5 * (S + S.T)
        if uniform and np.linalg.norm(S - S_prev) <= BACKWARD_RTOL * np.linalg.norm(S_prev):
            K[:k] = K[k]
            break


def _forward_recursion(model: Model, x_nominal: np.ndarray, sx: np.ndarray, phase: np.ndarray,
                       edge_jac: list[tuple[np.ndarray, np.ndarray]], stab_jac: list[tuple[np.ndarray, np.ndarray]],
                       uniform: bool, K: np.ndarray, P0: np.ndarray, perfect: bool) -> _ForwardRecursion:
    """The forward recursions of :func:`plan_local_controller`, ready to run, with the buffers they
    fill: per-step matrices (an index into the few distinct ones), R at the NOMINAL states the steps
    land on, ``P[0] = P0``."""
    n = model.n
    iota, period = len(edge_jac), len(stab_jac)
    T = iota + phase.size
    L = np.zeros((T, n, model.nz))
    P = np.zeros((T + 1, n, n))
    if not perfect:
        # R and H at the state the step lands on: the nominal during the edge, the orbit after it.
        # (each distinct state once: the stabiliser's repeat with its period)
        landing = model.measurement_variance(np.concatenate([x_nominal[1:], sx[1:period + 1]]))
        variances = landing[np.concatenate([np.arange(iota), iota + phase])]
        edge_H = [model.observation_jacobian(x) for x in x_nominal[1:]]
        stab_H = [model.observation_jacobian(sx[p + 1]) for p in range(period)]
        P[0] = P0
    # Per-step matrices (indexing of the few distinct ones), then both forward recursions compiled
    # (this loop of small products dominated the time per edge in Python), run lazily.
    H_all = [] if perfect else edge_H + stab_H
    if uniform and _same_matrices(edge_jac[:1] + stab_jac) and _same_matrices([(h,) for h in H_all] or [()]):
        # the same matrices at every step (a linear model): one copy, every step indexes it
        A_steps, B_steps = edge_jac[0][0][None], edge_jac[0][1][None]
        index = np.zeros(T, dtype=np.int64)
        H_all = H_all[:1]
    else:
        A_steps = np.stack([edge_jac[k][0] for k in range(iota)] + [stab_jac[p][0] for p in range(period)])
        B_steps = np.stack([edge_jac[k][1] for k in range(iota)] + [stab_jac[p][1] for p in range(period)])
        index = np.concatenate([np.arange(iota), iota + phase])
    if perfect:
        H_steps = np.zeros((A_steps.shape[0], 0, n))
        variances = np.zeros((T, 0))
    else:
        H_steps = np.stack(H_all)
    spread = np.zeros((T + 1, n))
    innovation_buf = np.zeros((T, H_steps.shape[1], H_steps.shape[1]))
    return _ForwardRecursion(A_steps, B_steps, H_steps, index, K, np.asarray(variances, dtype=float),
                             model.process_cov, perfect, L, P, innovation_buf, spread)


def _stationary_batchable(model: Model, targets: list[NodeController], nominals: list) -> bool:
    """Whether :func:`plan_local_controllers` may take its batched path: a linear model (the same
    matrices at every state) and stationary targets, as the single-edge function then uses."""
    return (type(model) is LinearGaussianModel and all(t.periodic is None for t in targets)
            and all(u.shape[0] >= 1 for _, u in nominals))


def _backward_gains(A: np.ndarray, B: np.ndarray, S: np.ndarray, Wx: np.ndarray, Wu: np.ndarray,
                    steps: int) -> tuple[list[np.ndarray], int | None]:
    """The backward Riccati recursion of :func:`plan_local_controller` for a linear model from the
    terminal cost ``S``: the gains ``K[iota - 1 - j]`` for ``j = 0, 1, ...`` (at most ``steps``), and the
    ``j`` at which S became stationary (the single-edge loop's break), or None. They depend on the
    target only, so a batch computes them once per target."""
    gains: list[np.ndarray] = []
    for j in range(steps):
        BS = B.T @ S
        K = np.linalg.solve(Wu + BS @ B, BS @ A)
        gains.append(K)
        S_prev = S
        S = Wx + A.T @ S @ (A - B @ K)
        S = 0.5 * (S + S.T)
        if np.linalg.norm(S - S_prev) <= BACKWARD_RTOL * np.linalg.norm(S_prev):
            return gains, j
    return gains, None


@dataclass
class _Batch:
    """The buffers a batch of edges shares (:func:`plan_local_controllers`): edge ``e`` owns rows
    ``start[e]:start[e + 1]`` of the per-step ones and, of ``P`` and ``spread``, one row more
    (``start[e] + e : start[e + 1] + e + 1``); the model's matrices and the step index are shared."""

    start: np.ndarray  # (E + 1,) first step row of each edge
    L: np.ndarray  # (total, n, nz)
    P: np.ndarray  # (total + E, n, n)
    innovation: np.ndarray  # (total, nz, nz)
    spread: np.ndarray  # (total + E, n)
    variances: np.ndarray  # (total, nz) R's diagonal per step
    landing: np.ndarray | None  # (sum of iota + 1, nz): R at each edge's landing states, edge after edge
    A_steps: np.ndarray  # (1, n, n)
    B_steps: np.ndarray  # (1, n, m)
    H_steps: np.ndarray  # (1, nz, n)
    index: np.ndarray  # (longest T,) zeros: every step indexes the one copy
    Qd: np.ndarray  # (n, n)


def _batch_buffers(model: Model, nominals: list[tuple[np.ndarray, np.ndarray]], targets: list[NodeController],
                   Ts: np.ndarray, perfect: bool) -> _Batch:
    """The shared buffers of :func:`plan_local_controllers` for edges of ``Ts`` (E,) steps."""
    n, nz = model.n, model.nz
    E = len(nominals)
    start = np.concatenate([[0], np.cumsum(Ts)]).astype(np.int64)
    total = int(start[-1])
    # Shared buffers. The filter's (L, P, innovation) are left uninitialised where it will run: the
    # recursion writes each row before anything reads it (compute(k) first), and zeroing ~0.5 MB per
    # edge of rows that are mostly never reached cost more than the rest of the design. With
    # perfect measurements no filter runs, and they are zeros as in the single-edge function.
    alloc = np.zeros if perfect else np.empty
    L_all = alloc((total, n, nz))
    P_all = alloc((total + E, n, n))
    innovation_all = alloc((total, nz, nz))
    spread_all = np.zeros((total + E, n))
    if not perfect:
        landing_states = np.concatenate([np.concatenate([x[1:], t.center[None]])
                                         for (x, _), t in zip(nominals, targets)])
        landing_all = model.measurement_variance(landing_states)  # row by row: the same values as per edge
        variances_all = np.empty((total, nz))
        H_steps = np.stack([model.observation_jacobian(nominals[0][0][1])])
    else:
        landing_all = None
        variances_all = np.zeros((total, 0))
        H_steps = np.zeros((1, 0, n))
    return _Batch(start=start, L=L_all, P=P_all, innovation=innovation_all, spread=spread_all,
                  variances=variances_all, landing=landing_all, A_steps=model.A[None], B_steps=model.B[None],
                  H_steps=H_steps, index=np.zeros(int(Ts.max()), dtype=np.int64), Qd=model.process_cov)


def _batch_gains(target: NodeController, iota: int, T: int, gains: list[np.ndarray], stop: int | None) -> np.ndarray:
    """The gains (T, m, n) of one edge of a batch from its target's backward recursion
    (:func:`_backward_gains`: the gains from the end, and where S became stationary), as the
    single-edge recursion leaves them."""
    K = np.empty((T,) + target.K.shape)
    K[iota:] = target.K
    if stop is not None and stop < iota:
        for j in range(stop + 1):
            K[iota - 1 - j] = gains[j]
        K[:iota - 1 - stop] = gains[stop]
    else:
        for j in range(iota):
            K[iota - 1 - j] = gains[j]
    return K


def _batch_controller(batch: _Batch, e: int, nominal: tuple[np.ndarray, np.ndarray], P0: np.ndarray,
                      target: NodeController, K: np.ndarray, landing_row: int, perfect: bool) -> LocalController:
    """Edge ``e`` of a batch: its reference, its slices of the shared buffers, its lazy recursions."""
    x_nom, u_nom = nominal
    iota, T = u_nom.shape[0], K.shape[0]
    a, b = int(batch.start[e]), int(batch.start[e + 1])
    x_ref = np.empty((T, x_nom.shape[1]))
    u_ref = np.empty((T, u_nom.shape[1]))
    x_ref[:iota], u_ref[:iota] = x_nom[:-1], u_nom
    x_ref[iota:], u_ref[iota:] = target.center, target.u_eq
    P = batch.P[a + e:b + e + 1]
    variances = batch.variances[a:b]
    if not perfect:
        landing = batch.landing[landing_row:landing_row + iota + 1]
        variances[:iota] = landing[:iota]
        variances[iota:] = landing[iota]
        P[0] = P0
    L, innovation, spread = batch.L[a:b], batch.innovation[a:b], batch.spread[a + e:b + e + 1]
    forward = _ForwardRecursion(batch.A_steps, batch.B_steps, batch.H_steps, batch.index[:T], K, variances, batch.Qd,
                                perfect, L, P, innovation, spread)
    return LocalController(x_ref=x_ref, u_ref=u_ref, K=K, L=L, P=P, edge_steps=iota,
                           innovation_cov=None if perfect else innovation, spread=spread, forward=forward)


def plan_local_controllers(model: Model, nominals: list[tuple[np.ndarray, np.ndarray]], P0s: list[np.ndarray],
                           targets: list[NodeController], Wx: np.ndarray, Wu: np.ndarray, stabiliser_steps: int,
                           perfect: bool, filter_steps_past_edge: int | None = None) -> list[LocalController]:
    """:func:`plan_local_controller` for a batch of edges: the same controllers, bit for bit.

    For a linear model with stationary stabilisers (the arm, the point robot) the per-step Python of
    the single-edge function goes: the backward Riccati recursion runs once per target (it depends on
    nothing else), the measurement variances along every nominal come from one call, the per-step
    arrays of all edges are slices of a few shared buffers, and with ``filter_steps_past_edge`` the
    forward Kalman recursion of every edge runs through ``edge_steps + filter_steps_past_edge`` in one
    compiled call (the Monte Carlo's first segment; the rest stays lazy). Other models and periodic
    stabilisers take the single-edge function per edge.

    Parameters
    ----------
    nominals : per edge ``(x (iota + 1, n), u (iota, m))``.
    P0s : per edge the start covariance (n, n); targets : per edge the target's stabiliser.
    filter_steps_past_edge : run the filter recursion this far past each edge now (None: not at all).

    Returns
    -------
    One :class:`LocalController` per edge, equal to :func:`plan_local_controller`'s in every array
    (tests/test_controllers.py).
    """
    if not _stationary_batchable(model, targets, nominals):
        out = [plan_local_controller(model, x, u, P0, t, Wx, Wu, stabiliser_steps, perfect)
               for (x, u), P0, t in zip(nominals, P0s, targets)]
        if filter_steps_past_edge is not None:
            for lc in out:
                lc.compute(lc.edge_steps + filter_steps_past_edge)
        return out
    iotas = np.array([u.shape[0] for _, u in nominals], dtype=np.int64)
    Ts = iotas + stabiliser_steps
    batch = _batch_buffers(model, nominals, targets, Ts, perfect)
    backward: dict[bytes, tuple[list[np.ndarray], int | None]] = {}
    longest = int(iotas.max())
    out = []
    landing_row = 0  # the edge's first row of batch.landing (iota + 1 rows each)
    for e, (nominal, P0, target) in enumerate(zip(nominals, P0s, targets)):
        key = target.S.tobytes()
        if key not in backward:  # the backward recursion depends on the target only
            backward[key] = _backward_gains(model.A, model.B, target.S, Wx, Wu, longest)
        K = _batch_gains(target, int(iotas[e]), int(Ts[e]), *backward[key])
        out.append(_batch_controller(batch, e, nominal, P0, target, K, landing_row, perfect))
        landing_row += int(iotas[e]) + 1
    if filter_steps_past_edge is not None and not perfect:
        k_end = np.minimum(Ts, np.maximum(1, iotas + filter_steps_past_edge)).astype(np.int64)
        filter_recursions(batch.A_steps, batch.H_steps, batch.index, batch.variances, batch.Qd, batch.L, batch.P,
                          batch.innovation, batch.start, k_end)
        for lc, k in zip(out, k_end):
            lc._forward.done = int(k)
    elif filter_steps_past_edge is not None:
        for lc in out:
            lc.compute(lc.edge_steps + filter_steps_past_edge)
    return out
