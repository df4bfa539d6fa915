"""Moving targets: measurement noise, prediction (constant velocity, Kalman), and the pure
per-frame follower that turns a tracked target into joint setpoints."""
