"""System models: the Model interface (base), linear models (incl. python-control StateSpace), the
unicycle, planar arm kinematics, and the measurement noise registry (noise)."""

# the landmark sensing form registers itself with the noise registry (firmtool.models.landmarks)
from firmtool.models import landmarks as _landmarks  # noqa: E402,F401
