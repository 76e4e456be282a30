"""privslam_jax.metrics."""

from privslam_jax.metrics.detection import DetectionMetrics, ImageEval, detection_metrics, evaluate_yolo_folder
from privslam_jax.metrics.privacy import METRIC_KEYS, baseline_points, nn_distances, point_recovery_metrics
from privslam_jax.metrics.image import edge_precision_recall, l1, psnr, ssim, ssim_map
from privslam_jax.metrics.trajectory import ErrorStats, associate, ate, rpe, trajectory_metrics
