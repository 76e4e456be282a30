"""XLA settings applied before JAX is imported by the command-line entry points.

Measured on a 2-core CPU (DESIGN §6): this jaxlib hands most convolutions to YNNPACK, which
splits work poorly over two threads; disabling YNN fusion makes the YOLOv8n forward 20-25 %
faster.  XLA's CPU Cholesky calls into the OpenBLAS that scipy ships, whose extra threads made a
306×306 factorisation take 20-500 ms instead of ~1 ms on a busy 2-core machine
(docs/slam_solvers.md), so OpenBLAS runs single-threaded.  User-set values are left untouched.
"""

from __future__ import annotations

import os

_DEFAULT_XLA_FLAGS = "--xla_cpu_experimental_ynn_fusion_type="


def configure_xla() -> None:
    """Set ``XLA_FLAGS`` and ``OPENBLAS_NUM_THREADS`` to the project defaults unless set (call before importing jax)."""
    os.environ.setdefault("XLA_FLAGS", _DEFAULT_XLA_FLAGS)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
