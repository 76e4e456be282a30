"""privslam_jax.metrics."""
