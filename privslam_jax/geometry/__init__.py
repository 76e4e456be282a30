"""privslam_jax.geometry."""
