"""privslam_jax.attacks."""

from privslam_jax.attacks.gradient import GradientAttackConfig, consistency_energy, gradient_attack, line_neighbours
from privslam_jax.attacks.line2point import (
    Line2PointConfig,
    get_peak,
    line2point,
    num_coarse_neighbours,
    select_smallest,
    sort_values,
)
