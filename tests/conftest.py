"""Strict test settings (in the manner of optimistix/equinox).

* XLA flags as the CLI sets them, before jax is imported.
* ``jax_numpy_rank_promotion = "raise"``: implicit rank broadcasting is a bug here.
* warnings are errors (pyproject ``filterwarnings``); jaxtyping + beartype check every
  annotated function of the package (pyproject ``--jaxtyping-packages``).
* ``shared`` fixture: the ``../shared`` folder, or a skip with the reason.
"""

from __future__ import annotations

from privslam_jax._xla import configure_xla

configure_xla()

import jax  # noqa: E402
import pytest  # noqa: E402

from privslam_jax._shared import shared_dir  # noqa: E402

jax.config.update("jax_numpy_rank_promotion", "raise")


@pytest.fixture(scope="session")
def shared():
    """Path to ``../shared``; skips the test when it is absent."""
    path = shared_dir()
    if path is None:
        pytest.skip("../shared is absent (set PRIVSLAM_SHARED to its location)")
    return path
