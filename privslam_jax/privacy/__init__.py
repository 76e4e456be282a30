"""privslam_jax.privacy."""

from privslam_jax.privacy.lift import (
    entropy_key,
    fixed_key,
    paired_lift,
    paired_lift_core,
    pairing,
    random_directions,
    random_lift,
    random_lift_core,
)
