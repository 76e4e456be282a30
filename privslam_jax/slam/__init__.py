"""privslam_jax.slam."""

from privslam_jax.slam.refine import (
    DEFAULT_BUCKETS,
    RefineConfig,
    RefineResult,
    bucket_size,
    camera_params,
    pad_to_bucket,
    refine_pose,
    refine_pose_padded,
)
