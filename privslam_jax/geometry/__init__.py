"""privslam_jax.geometry."""

from privslam_jax.geometry.plucker import (
    closest_approach,
    closest_point_to_origin,
    line_line_distance,
    lines_from_points_directions,
    point_line_distance,
)
from privslam_jax.geometry.align import apply_similarity, umeyama, umeyama_np
from privslam_jax.geometry.projection import (
    pinhole,
    pinhole_stereo,
    project_points,
    reprojection_jacobians,
    reprojection_residual,
    reprojection_residuals,
    stereo_jacobians,
    stereo_residual,
    world_to_camera,
    world_to_camera_from_pose,
)
