"""privslam_jax.slam."""

from privslam_jax.slam.ba import BAConfig, BAResult, BAStructure, analyze, ba_bucket, bundle_adjust, bundle_adjust_padded
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
