"""firmtool: FIRM (graph-based stochastic control with constraints) in state and belief space."""

__version__ = "0.1.0"
