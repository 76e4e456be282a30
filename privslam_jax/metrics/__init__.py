"""privslam_jax.metrics."""

from privslam_jax.metrics.trajectory import ErrorStats, associate, ate, rpe, trajectory_metrics
