"""Navigation: the fusion filter (error-state EKF), per-source fault tests and navigation modes."""
