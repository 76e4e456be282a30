"""The privacy/accuracy trade-off (issue 18): objectives as pure, differentiable JAX functions.

* :mod:`~privslam_jax.tradeoff.objectives` — :func:`privacy_loss` (detector confidence inside the
  masks), :func:`accuracy_loss` (pose error of photometric alignment on the filtered frame),
  :func:`fidelity_loss` (L1 to the object-free render);
* :mod:`~privslam_jax.tradeoff.photometric` — direct two-frame photometric alignment on the
  least-squares core, differentiable by the implicit-function theorem.

``docs/tradeoff.md`` states the equations and the tests.
"""

from privslam_jax.tradeoff.objectives import (
    DetectorModel,
    accuracy_loss,
    anchor_mask_coverage,
    fidelity_loss,
    geodesic_distance,
    privacy_loss,
)
from privslam_jax.tradeoff.photometric import PhotometricConfig, align_photometric

__all__ = ["DetectorModel", "PhotometricConfig", "accuracy_loss", "align_photometric", "anchor_mask_coverage",
           "fidelity_loss", "geodesic_distance", "privacy_loss"]
