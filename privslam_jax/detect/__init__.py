"""privslam_jax.detect: YOLOv8 and YOLO11 in Flax NNX, ultralytics weight import, decoding and NMS."""

from privslam_jax.detect.decode import box_iou, decode_head, make_anchors, nms, non_max_suppression, scale_boxes
from privslam_jax.detect.loss import LossConfig, detection_loss, task_aligned_assign, targets_to_padded
from privslam_jax.detect.predict import (
    EMBEDDED_REAL_WEIGHTS,
    EMBEDDED_WEIGHTS,
    PRIVACY_CLASSES,
    PRIVACY_PRESET,
    Detector,
    DetectorConfig,
    letterbox,
)
from privslam_jax.detect.weights import (
    UnsafeCheckpointError,
    detect_architecture,
    load_detector,
    load_state_dict,
    load_ultralytics,
    model_state_dict,
    read_torch_checkpoint,
    save_checkpoint,
)
from privslam_jax.detect.yolo11 import YOLO11, YOLO11Config
from privslam_jax.detect.yolov8 import SCALES, YOLOv8, YOLOv8Config, count_parameters, fuse_batchnorm

__all__ = [
    "EMBEDDED_WEIGHTS",
    "EMBEDDED_REAL_WEIGHTS",
    "LossConfig",
    "detection_loss",
    "task_aligned_assign",
    "targets_to_padded",
    "PRIVACY_CLASSES",
    "PRIVACY_PRESET",
    "Detector",
    "DetectorConfig",
    "letterbox",
    "SCALES",
    "UnsafeCheckpointError",
    "YOLOv8",
    "YOLO11",
    "YOLO11Config",
    "YOLOv8Config",
    "box_iou",
    "count_parameters",
    "fuse_batchnorm",
    "decode_head",
    "detect_architecture",
    "load_detector",
    "load_state_dict",
    "load_ultralytics",
    "make_anchors",
    "model_state_dict",
    "nms",
    "non_max_suppression",
    "read_torch_checkpoint",
    "save_checkpoint",
    "scale_boxes",
]
