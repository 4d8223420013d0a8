"""System models: the Model interface (base), linear models (incl. python-control StateSpace), the
unicycle, planar arm kinematics, and the measurement noise registry (noise)."""
