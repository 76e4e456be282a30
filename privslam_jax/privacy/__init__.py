"""privslam_jax.privacy."""
