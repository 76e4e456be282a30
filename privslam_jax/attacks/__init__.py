"""privslam_jax.attacks."""
