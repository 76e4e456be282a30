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
from privslam_jax.data.images import read_image, write_rgb, write_uint16
from privslam_jax.data.kitti import KittiFrame, KittiSequence, read_calib
from privslam_jax.data.yolo import (
    YoloDataset,
    YoloSample,
    cxcywhn_to_xyxy,
    read_yolo_labels,
    write_yolo_labels,
    xyxy_to_cxcywhn,
)
from privslam_jax.data.bal import BALProblem, bal_cost, bal_residuals, bal_to_opencv, opencv_to_bal_cameras, read_bal
from privslam_jax.data.synthetic import (
    COCO_PRIVACY_CLASSES,
    SynthConfig,
    SynthFrame,
    SyntheticSequence,
    make_sequence,
)
