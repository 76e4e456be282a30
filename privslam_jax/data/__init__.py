"""privslam_jax.data."""
