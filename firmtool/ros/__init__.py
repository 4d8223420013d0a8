"""FIRM on ROS 2 (the ``ros`` extra: ``pip install 'firmtool[ros]'``): the policy of a solved roadmap
as a ROS 2 node, and firmtool's simulated robot as another (docs/tutorials/ros.md).

- :mod:`firmtool.ros.node`: the ``firmtool`` node (``firmtool ros ROADMAP``): measurements in, controls
  out at the control period, belief, plan and events for RViz and logs, goals as new queries, map
  changes as world updates.
- :mod:`firmtool.ros.sim`: the ``firmtool_sim`` node (``firmtool ros-sim SCENARIO_OR_ROADMAP``): the
  simulated system on the other side of the messages, episodes as ``ft.simulate`` plays them, in
  lock-step or timed.
- :mod:`firmtool.ros.interfaces`: the client library and messages (imported only here; a missing
  extra is one line naming it), the QoS of every topic, array/message conversions.
- :mod:`firmtool.ros.checks`: message checks, requests and events as JSON, the belief and plan in
  the task space (no ROS import).
- :mod:`firmtool.ros.confine`: the private network namespace tests, benchmarks and CI run the nodes
  in (no ROS import).
- :mod:`firmtool.ros.spin`: what the two commands call.

Importing this package imports no ROS module; ``import firmtool`` never imports this package.
"""
