"""The graph's dynamic programmes, which know nothing of robots: the DP with constraints and the
success probabilities (:mod:`firmtool.graph.dp`, paper eq. 12 and Sec. III-E), and the DP over node
and steps left for a task with a deadline (:mod:`firmtool.graph.deadline`)."""
