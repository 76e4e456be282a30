"""privslam_jax.detect."""
