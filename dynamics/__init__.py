"""Robot models, kinematics, the inverse-dynamics regressor and base parameters."""
