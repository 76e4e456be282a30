"""``type=`` functions for argparse options that take counts, sizes, probabilities and thresholds.

A bad value is refused while the command line is parsed, before any work or any output folder is
claimed: argparse prints ``PROG: error: argument --OPTION: must be …, got 'VALUE'`` and exits with
status 2. Used by the ``privslam`` subcommands and the ``train/`` scripts; no JAX import here
(``privslam --help`` stays fast; :func:`seed_list` imports the renderer when it is used).
"""

from __future__ import annotations

import argparse
import math

__all__ = ["positive_int", "nonnegative_int", "positive_float", "positive_or_inf", "nonnegative_float", "unit_interval",
           "open_unit_interval", "multiple_of_32", "seed_list", "plane", "intrinsics"]


def _int(text: str, what: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}") from None


def _float(text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}")
    return value


def positive_int(text: str) -> int:
    """An integer ≥ 1 (a count or a size)."""
    value = _int(text, "a positive integer")
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}")
    return value


def nonnegative_int(text: str) -> int:
    """An integer ≥ 0 (a seed, a window, a number of rounds)."""
    value = _int(text, "an integer >= 0")
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text!r}")
    return value


def multiple_of_32(text: str) -> int:
    """A positive multiple of 32 (a YOLO input size)."""
    value = _int(text, "a positive multiple of 32")
    if value < 32 or value % 32:
        raise argparse.ArgumentTypeError(f"must be a positive multiple of 32, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """A finite number > 0 (a learning rate)."""
    value = _float(text, "a finite number > 0")
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return value


def positive_or_inf(text: str) -> float:
    """A number > 0, or ``inf`` for no limit (a depth limit)."""
    if text.strip().lower() in ("inf", "infinity"):
        return math.inf
    try:
        return positive_float(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"must be a finite number > 0 or inf, got {text!r}") from None


def nonnegative_float(text: str) -> float:
    """A finite number ≥ 0 (a loss weight, a number of epochs)."""
    value = _float(text, "a finite number >= 0")
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}")
    return value


def unit_interval(text: str) -> float:
    """A number in [0, 1] (a confidence or IoU threshold, a probability, a share)."""
    value = _float(text, "a number in [0, 1]")
    if not 0 <= value <= 1:
        raise argparse.ArgumentTypeError(f"must be a number in [0, 1], got {text!r}")
    return value


def seed_list(text: str) -> str:
    """A non-empty list of world seeds and inclusive ranges, ``"0-3,7"``
    (:func:`privslam_jax.data.synthetic.parse_seeds`); returned as given."""
    from privslam_jax.data.synthetic import parse_seeds

    try:
        seeds = parse_seeds(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None
    if not seeds:
        raise argparse.ArgumentTypeError(f"no seeds in {text!r}: a range A-B needs A <= B")
    return text


def open_unit_interval(text: str) -> float:
    """A number in [0, 1) (an Adam β1 or a momentum)."""
    value = _float(text, "a number in [0, 1)")
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(f"must be a number in [0, 1), got {text!r}")
    return value


def plane(text: str) -> tuple[tuple[float, float, float], float]:
    """A plane ``NX,NY,NZ,H`` (``n · x = H``, ``n`` finite and non-zero): ``((nx, ny, nz), h)``."""
    parts = text.split(",")
    what = "four numbers NX,NY,NZ,H with a non-zero normal"
    if len(parts) != 4:
        raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}")
    nx, ny, nz, h = (_float(v, what) for v in parts)
    if nx == ny == nz == 0:
        raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}")
    return (nx, ny, nz), h


def intrinsics(text: str) -> tuple[float, float, float, float]:
    """Pinhole intrinsics ``FX,FY,CX,CY`` in pixels (finite; ``FX, FY > 0``)."""
    parts = text.split(",")
    what = "four numbers FX,FY,CX,CY (pixels; FX, FY > 0)"
    if len(parts) != 4:
        raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}")
    fx, fy, cx, cy = (_float(v, what) for v in parts)
    if fx <= 0 or fy <= 0:
        raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}")
    return fx, fy, cx, cy
