"""``configure_xla``: the persistent compilation cache of the command-line entry points.

Each case runs in a fresh interpreter (the settings must be made before JAX starts), with
``XDG_CACHE_HOME`` pointed into ``tmp_path`` and warnings as errors."""

from __future__ import annotations

import os
import subprocess
import sys

_SNIPPET = (
    "from privslam_jax._xla import configure_xla; configure_xla()\n"
    "import os, jax, jax.numpy as jnp\n"
    "print(repr(os.environ.get('JAX_COMPILATION_CACHE_DIR')))\n"
    "print(float(jax.jit(lambda x: (x * 2.0).sum())(jnp.ones(3))))\n"
)


def _run(tmp_path, **env):
    base = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    base.update(XDG_CACHE_HOME=str(tmp_path / "xdg"), JAX_PLATFORMS="cpu", **env)
    proc = subprocess.run([sys.executable, "-W", "error", "-c", _SNIPPET], capture_output=True, text=True,
                          env=base, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stderr == "", proc.stderr[-2000:]
    lines = proc.stdout.splitlines()
    assert lines[1] == "6.0"
    return lines[0]


def test_programs_are_cached_under_the_user_cache_folder(tmp_path):
    cache = tmp_path / "xdg" / "privslam_jax" / "xla"
    assert _run(tmp_path) == repr(str(cache))
    entries = sorted(p.name for p in cache.iterdir())
    assert any(name.startswith("jit_") for name in entries), entries
    assert _run(tmp_path) == repr(str(cache))  # the second process finds its program there
    assert sorted(p.name for p in cache.iterdir()) == entries


def test_the_cache_can_be_moved_or_turned_off_and_an_unwritable_one_is_skipped(tmp_path):
    other = tmp_path / "other"
    assert _run(tmp_path, JAX_COMPILATION_CACHE_DIR=str(other)) == repr(str(other))
    assert any(other.iterdir())
    assert _run(tmp_path, JAX_COMPILATION_CACHE_DIR="") == "''"
    assert not (tmp_path / "xdg").exists()
    (tmp_path / "xdg").write_text("a file where the cache folder would go")
    assert _run(tmp_path) == "None"  # no cache, and no warning on every compilation
