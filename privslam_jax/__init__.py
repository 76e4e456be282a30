"""privslam_jax: privacy-preserving edge-assisted visual SLAM in JAX."""

from privslam_jax.types import Camera, Detections, LineCloud, PointCloud, Trajectory

__all__ = ["Camera", "Detections", "LineCloud", "PointCloud", "Trajectory"]
__version__ = "0.1.0"
