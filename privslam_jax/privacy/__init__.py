"""privslam_jax.privacy."""

from privslam_jax.privacy.lift import (
    entropy_key,
    fixed_key,
    paired_lift,
    pairing,
    random_directions,
    random_lift,
)
