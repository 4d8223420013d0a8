"""The online part of FIRM: the policy as an agent that sees what a robot sees.

- :mod:`firmtool.online.policy`: :class:`Policy` (``reset``, then per control period ``act`` and
  ``observe``): stores its inputs, prepares what every run shares, checks what a robot hands it
  and reports.
- :mod:`firmtool.online.state`: what the policy knows, read from outside: the read-only snapshot
  :class:`~firmtool.online.state.PolicyState` (``policy.state``) and :class:`~firmtool.online.state.PolicyRecord`
  (``policy.record``).
- :mod:`firmtool.online.run`: :class:`~firmtool.online.run.PolicyRun`, one run from a reset, which
  coordinates the collaborators below; :class:`PolicyStatus`.
- :mod:`firmtool.online.belief`: the belief and its Kalman filter on the running controller's gains.
- :mod:`firmtool.online.alarms`: whether the measurements contradict the belief (the innovation
  tests of :mod:`firmtool.online.innovation`), and the corrected belief.
- :mod:`firmtool.online.arrival`: the node the belief entered, and the goal check's wait.
- :mod:`firmtool.online.decision`: keep the running controller or take another; the replan
  decision itself (candidates scored by Monte Carlo, anytime under a deadline) and
  :class:`ReplanSettings` in :mod:`firmtool.online.replanning`.
- :mod:`firmtool.online.probe`: a re-localisation's probe (its Gaussian sum:
  :mod:`firmtool.online.relocalise`).
- :mod:`firmtool.online.running`: a local controller with the per-step arrays execution needs, and
  the policy edges' controllers.
- :mod:`firmtool.online.record`, :mod:`firmtool.online.timing`: what a run did, and its compute.
- :mod:`firmtool.online.world`: a changed world while the policy runs; :mod:`firmtool.online.rollout`: rollout FIRM.

The simulated system the policy runs against in simulation is :mod:`firmtool.sim`.
"""

from firmtool.online.policy import Policy, PolicyStatus
from firmtool.online.replanning import ReplanSettings

__all__ = ["Policy", "PolicyStatus", "ReplanSettings"]
