"""The online part of FIRM: the policy as an agent that sees what a robot sees.

- :mod:`firmtool.online.policy`: :class:`Policy` (``reset``, then per control period ``act`` and
  ``observe``), its state and events.
- :mod:`firmtool.online.replanning`: :class:`ReplanSettings` and the replan decision (candidates
  scored by Monte Carlo, anytime under a deadline).
- :mod:`firmtool.online.innovation`: the windowed innovation test and the belief reset.
- :mod:`firmtool.online.running`: a local controller with the per-step arrays execution needs.

The simulated system the policy runs against in simulation is :mod:`firmtool.sim`.
"""

from firmtool.online.policy import Policy, PolicyStatus
from firmtool.online.replanning import ReplanSettings

__all__ = ["Policy", "PolicyStatus", "ReplanSettings"]
