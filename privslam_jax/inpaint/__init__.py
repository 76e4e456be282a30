"""privslam_jax.inpaint."""
