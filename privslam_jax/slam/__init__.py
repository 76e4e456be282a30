"""privslam_jax.slam."""
