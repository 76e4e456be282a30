"""The least-squares core under pose refinement and bundle adjustment (issue 17).

* :mod:`~privslam_jax.solvers.lm` — Levenberg–Marquardt with Nielsen's damping, one loop for every
  problem, returning a :class:`~privslam_jax.solvers.lm.SolveSummary` (why it stopped) as a value;
* :mod:`~privslam_jax.solvers.robust` — the Huber loss and its IRLS weight;
* :mod:`~privslam_jax.solvers.linear` — dense damped normal equations (one pose);
* :mod:`~privslam_jax.solvers.schur` — the Schur complement on the points (bundle adjustment);
* :mod:`~privslam_jax.solvers.implicit` — exact derivatives of a minimiser by the implicit-function
  theorem (``custom_jvp``: forward and reverse mode).
"""

from privslam_jax.solvers.implicit import implicit_argmin
from privslam_jax.solvers.linear import DenseSystem, dense_damped_solve
from privslam_jax.solvers.lm import STATUS_NAMES, LMParams, SolveSummary, levenberg_marquardt
from privslam_jax.solvers.robust import huber_rho, huber_weight
from privslam_jax.solvers.schur import BlockSystem, SchurStructure, analyze, schur_damped_solve

__all__ = [
    "BlockSystem", "DenseSystem", "LMParams", "STATUS_NAMES", "SchurStructure", "SolveSummary", "analyze",
    "dense_damped_solve", "huber_rho", "huber_weight", "implicit_argmin", "levenberg_marquardt", "schur_damped_solve",
]
