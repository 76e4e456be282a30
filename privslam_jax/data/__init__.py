"""privslam_jax.data."""

from privslam_jax.data.ply import (
    load_line_cloud,
    load_point_cloud,
    read_ply,
    save_line_cloud,
    save_point_cloud,
    write_ply,
)

from privslam_jax.data.trajectory_io import (
    load_kitti,
    load_tum,
    read_kitti_matrices,
    read_tum_matrices,
    save_kitti,
    save_tum,
    write_kitti_matrices,
    write_tum_matrices,
)
