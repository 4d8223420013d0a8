"""Controllers: LQR/LQG gains and Kalman filters (:mod:`~firmtool.control.gains`), nominal
trajectories (:mod:`~firmtool.control.trajectories`), node stabilisers, stationary and periodic
(:mod:`~firmtool.control.stabilisers`), time-varying local controllers (:mod:`~firmtool.control.local`)
and their compiled recursions (:mod:`~firmtool.control.recursions`, :mod:`~firmtool.control.linalg`)."""
