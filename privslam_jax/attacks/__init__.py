"""privslam_jax.attacks."""

from privslam_jax.attacks.gradient import (
    GradientAttackConfig,
    GradientAttackResult,
    consistency_energy,
    gradient_attack,
    gradient_attack_core,
    line_neighbours,
)
from privslam_jax.attacks.line2point import (
    Line2PointConfig,
    get_peak,
    line2point,
    line2point_core,
    line2point_offsets,
    num_coarse_neighbours,
    select_smallest,
    sort_values,
)
from privslam_jax.attacks.centred import find_centres, ray_cloud_attack
from privslam_jax.attacks.two_peaks import TwoPeakResult, assign_pairs, line_pairs, two_peak_attack, two_peaks
from privslam_jax.attacks.plane import ground_plane_attack, road_surface_attack
