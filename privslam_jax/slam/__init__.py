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
from privslam_jax.slam.frontend import Features, OrbConfig, extract_orb, match_descriptors, search_by_projection
from privslam_jax.slam.initializer import InitConfig
from privslam_jax.slam.mapping import Map, MappingConfig
from privslam_jax.slam.system import MODES, Slam, SlamConfig, SlamResult, run_slam
from privslam_jax.slam.tracking import TrackingConfig
