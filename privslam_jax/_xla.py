"""XLA settings applied before JAX is imported by the command-line entry points.

Measured on a 2-core CPU (DESIGN §6): this jaxlib hands most convolutions to YNNPACK, which
splits work poorly over two threads; disabling YNN fusion makes the YOLOv8n forward 20-25 %
faster.  A user-set ``XLA_FLAGS`` is left untouched.
"""

from __future__ import annotations

import os

_DEFAULT_XLA_FLAGS = "--xla_cpu_experimental_ynn_fusion_type="


def configure_xla() -> None:
    """Set ``XLA_FLAGS`` to the project default unless the user set it (call before importing jax)."""
    os.environ.setdefault("XLA_FLAGS", _DEFAULT_XLA_FLAGS)
