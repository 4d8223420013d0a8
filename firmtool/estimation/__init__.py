"""Edge estimation: Monte Carlo engines, edge table and keys, executors, adaptive rounds, budgets."""
