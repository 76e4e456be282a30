"""privslam_jax.privacy."""

from privslam_jax.privacy.lift import (
    axial_lift,
    axial_lift_core,
    entropy_key,
    fixed_key,
    paired_lift,
    paired_lift_core,
    pairing,
    random_directions,
    random_lift,
    random_lift_core,
    ray_anchors,
    ray_lift,
    ray_lift_core,
    sphere_lift,
    sphere_lift_core,
)
from privslam_jax.privacy.road import keyframe_up, road_parallel
