"""Vision: the downward camera model and the visual odometry pipeline."""
