"""The Pareto front of privacy filters (issue 18, item 4): the pure pieces of ``experiments/pareto_tradeoff.py``.

Every filter configuration ``f`` becomes a point ``(r_f, a_f)``, both minimised:

* ``r_f`` — the re-detection rate in %, ``100 · Σ re-detected / Σ objects`` over the evaluated frames
  of every world (objects and matching: :mod:`privslam_jax.metrics.redetection`);
* ``a_f`` — the median over the (world ``w``, RANSAC seed ``s``) pairs of the paired ATE change
  ``Δ_f(w, s) = 100 · (ATE_f(w, s) − ATE_none(w, s)) / ATE_none(w, s)`` (%), the filtered run against
  the unfiltered run of the same world with the same RANSAC seed
  (:func:`~privslam_jax.tradeoff.proxy.paired_changes` with ``(w, s)`` as its "world").

Dominance (both minimised): ``p ≻ q  ⇔  r_p ≤ r_q ∧ a_p ≤ a_q ∧ (r_p < r_q ∨ a_p < a_q)``; the
front is the set of points no other point dominates.  A non-finite coordinate (no measurement, or
SLAM failed on every pair) counts as ``+∞``, the worst value.

The goal of issue 18 item 4 for a trained point ``t``: ``r_t ≤ 1 %``, ``a_t ≤ +5 %`` (monocular,
synthetic worlds) and ``t ≻ f`` for every fixed filter ``f`` (:func:`goal_check`).

The RANSAC noise floor: the same unfiltered frames with two RANSAC seeds ``s₀, s₁``,
``100 · (ATE_none(w, s₁) − ATE_none(w, s₀)) / ATE_none(w, s₀)`` per world (:func:`noise_floor`);
filter changes of that size are not distinguishable from the RANSAC order.

Records (one per (world, filter) unit of the experiment) are dicts with ``world``, ``filter`` and,
per SLAM mode ``m`` (``"mono"``, ``"stereo"``), ``r[m] = {"seeds": [s, …], "ate": [ATE (m), …]}``;
with a judge ``r["redetection"] = {"refound": k, "objects": n}``; ``psnr``/``ssim`` with the number
of frames they average over, ``psnr_frames``; ``filter_s`` and ``frames`` (filter time).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

from privslam_jax.tradeoff.proxy import paired_changes, summarize_changes

__all__ = ["Goal", "dominates", "goal_check", "noise_floor", "pareto_front", "per_filter_mean", "redetection_rates",
           "seed_changes", "seed_records", "summarize_seed_changes"]


# --- paired ATE changes per RANSAC seed ---------------------------------------------------------------


def seed_records(records: Sequence[Mapping[str, Any]], mode: str) -> list[dict]:
    """One record per (filter, world, RANSAC seed) of ``mode``: ``{"filter", "world": (world, seed), "ate"}``
    (records without ``mode`` are skipped; a ``None`` ATE becomes NaN)."""
    out = []
    for r in records:
        if mode not in r:
            continue
        m = r[mode]
        for s, a in zip(m["seeds"], m["ate"], strict=True):
            out.append({"filter": r["filter"], "world": (r["world"], int(s)),
                        "ate": math.nan if a is None else float(a)})
    return out


def seed_changes(records: Sequence[Mapping[str, Any]], mode: str) -> list[dict]:
    """Per (filter ≠ none, world, seed) whose world has a ``none`` run with that seed: ``{"filter", "world",
    "seed", "d_ate" (m), "d_ate_pct"}`` — :func:`~privslam_jax.tradeoff.proxy.paired_changes` over
    :func:`seed_records` (NaN when either ATE is not finite)."""
    return [{"filter": c["filter"], "world": c["world"][0], "seed": c["world"][1], "d_ate": c["d_ate"],
             "d_ate_pct": c["d_ate_pct"]}
            for c in paired_changes(seed_records(records, mode), ate="ate", proxy="ate")]


def summarize_seed_changes(records: Sequence[Mapping[str, Any]], mode: str) -> dict[str, dict[str, Any]]:
    """Per filter: median, min and max of ``d_ate`` and ``d_ate_pct`` over its finite (world, seed) pairs
    (:func:`~privslam_jax.tradeoff.proxy.summarize_changes`; ``worlds`` counts the pairs, ``n`` the finite ones)."""
    return summarize_changes(seed_changes(records, mode), keys=("d_ate", "d_ate_pct"))


def noise_floor(records: Sequence[Mapping[str, Any]], mode: str, seeds: tuple[int, int] = (0, 1)) -> list[dict]:
    """Per world with an unfiltered (``none``) ``mode`` run for both ``seeds = (s₀, s₁)``: ``{"world",
    "ate0", "ate1", "d" (m), "pct"}`` with ``d = ATE(s₁) − ATE(s₀)``, ``pct = 100 · d / ATE(s₀)``."""
    out = []
    for r in records:
        if r["filter"] != "none" or mode not in r:
            continue
        by_seed = {int(s): (math.nan if a is None else float(a)) for s, a in zip(r[mode]["seeds"], r[mode]["ate"],
                                                                                 strict=True)}
        if seeds[0] not in by_seed or seeds[1] not in by_seed:
            continue
        a0, a1 = by_seed[seeds[0]], by_seed[seeds[1]]
        out.append({"world": r["world"], "ate0": a0, "ate1": a1, "d": a1 - a0,
                    "pct": 100.0 * (a1 - a0) / a0 if a0 != 0 else math.nan})
    return out


# --- re-detection and the image measures ------------------------------------------------------------


def redetection_rates(records: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, int | float]]:
    """Per filter (first-seen order) over its records with a ``redetection`` entry: ``refound`` and
    ``objects`` summed, and ``pct = 100 · refound / objects`` (NaN without objects)."""
    out: dict[str, dict[str, int | float]] = {}
    for r in records:
        if "redetection" not in r:
            continue
        row = out.setdefault(r["filter"], {"refound": 0, "objects": 0})
        row["refound"] += int(r["redetection"]["refound"])
        row["objects"] += int(r["redetection"]["objects"])
    for row in out.values():
        row["pct"] = 100.0 * row["refound"] / row["objects"] if row["objects"] else math.nan
    return out


def per_filter_mean(records: Sequence[Mapping[str, Any]], key: str, weight: str) -> dict[str, float]:
    """Per filter: ``Σ_w r[key]·r[weight] / Σ_w r[weight]`` over its records where both are finite and the
    weight is positive (a per-world mean made a mean over all frames); NaN when none is."""
    num: dict[str, float] = {}
    den: dict[str, float] = {}
    for r in records:
        num.setdefault(r["filter"], 0.0)
        den.setdefault(r["filter"], 0.0)
        v, w = r.get(key), r.get(weight)
        if v is None or w is None or not (math.isfinite(float(v)) and math.isfinite(float(w))) or float(w) <= 0:
            continue
        num[r["filter"]] += float(v) * float(w)
        den[r["filter"]] += float(w)
    return {f: num[f] / den[f] if den[f] > 0 else math.nan for f in num}


# --- dominance and the goal ---------------------------------------------------------------------------


def _worst(x: float) -> float:
    return float(x) if math.isfinite(float(x)) else math.inf


def dominates(p: Sequence[float], q: Sequence[float]) -> bool:
    """``p ≻ q`` for minimised coordinates (module docstring): no worse in every coordinate and strictly
    better in one; non-finite coordinates count as ``+∞``."""
    if len(p) != len(q):
        raise ValueError(f"points differ in dimension: {len(p)} vs {len(q)}")
    a = [_worst(x) for x in p]
    b = [_worst(x) for x in q]
    return all(x <= y for x, y in zip(a, b)) and any(x < y for x, y in zip(a, b))


def pareto_front(points: Mapping[str, Sequence[float]]) -> list[str]:
    """The names of the points no other point dominates (in the order of ``points``)."""
    return [n for n, p in points.items() if not any(dominates(q, p) for m, q in points.items() if m != n)]


@dataclasses.dataclass(frozen=True)
class Goal:
    """The goal check of one trained point (:func:`goal_check`)."""

    redetection_ok: bool
    """Re-detection ≤ the limit (1 %)."""
    ate_ok: bool
    """Median monocular ΔATE ≤ the limit (+5 %)."""
    dominated: tuple[str, ...]
    """The fixed filters the point dominates."""
    not_dominated: tuple[str, ...]
    """The fixed filters it does not dominate."""
    defined: bool
    """Every coordinate of the point and of the fixed filters is finite (otherwise the check treats the
    missing ones as the worst value and says so)."""

    @property
    def dominates_all(self) -> bool:
        """The point dominates every fixed filter (true when there is none)."""
        return not self.not_dominated

    @property
    def met(self) -> bool:
        """All three conditions hold."""
        return self.redetection_ok and self.ate_ok and self.dominates_all


def goal_check(point: Sequence[float], fixed: Mapping[str, Sequence[float]], max_redetection: float = 1.0,
               max_d_ate: float = 5.0) -> Goal:
    """Issue 18 item 4 for a trained point ``(re-detection %, median mono ΔATE %)``: ``r ≤ max_redetection``,
    ``a ≤ max_d_ate`` and ``point ≻ f`` for every ``(r_f, a_f)`` in ``fixed`` (:func:`dominates`)."""
    r, a = float(point[0]), float(point[1])
    dom = tuple(n for n, q in fixed.items() if dominates(point, q))
    rest = tuple(n for n in fixed if n not in dom)
    finite = all(math.isfinite(float(x)) for q in [point, *fixed.values()] for x in q)
    return Goal(redetection_ok=math.isfinite(r) and r <= max_redetection,
                ate_ok=math.isfinite(a) and a <= max_d_ate, dominated=dom, not_dominated=rest, defined=finite)
