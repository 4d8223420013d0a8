"""Robot and system models: linear dynamics, observation noise, kinematics."""
