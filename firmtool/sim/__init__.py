"""The simulated side of execution: the true system (environment) and episodes over it.

- :mod:`firmtool.sim.environment`: :class:`SimulatedSystem` (true state, measurements with the true
  state's noise, collisions, disturbances).
- :mod:`firmtool.sim.episodes`: one episode as a loop of the policy against the system, many
  summarised as :class:`firmtool.results.Results`, and the random streams of each episode.
"""

from firmtool.sim.environment import SimulatedSystem
from firmtool.sim.episodes import EpisodeSeeds, episode_seeds, run_episode, run_episodes

__all__ = ["EpisodeSeeds", "SimulatedSystem", "episode_seeds", "run_episode", "run_episodes"]
