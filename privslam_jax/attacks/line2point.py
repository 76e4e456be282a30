"""Line2Point: recover points from a random line cloud (Chelani, Kahl & Sattler, CVPR 2021).

Faithful to the authors' code (github.com/kunalchelani/Line2Point, ``Recover.py`` + ``Utils.py``).
Every line ``i`` is anchored at a point ``a_i`` with unit direction ``d_i``; a recovered point is
``a_i + t_i d_i``.  **Departure (deliberate):** the authors anchor each line at the *true* point
(``pts``), so their printed error ``|t_i|`` and the self-neighbour estimate ``0`` refer to the
secret; here the anchor is the line's closest point to the origin ``a = d × m``, the only point
a line cloud reveals.  Everything else follows their code, including the ``1e-6`` guards:

1. **Coarse.**  ``k = int(min(500, 0.05·N))`` nearest lines of line ``i`` by
   ``|(a_j − a_i)·n̂|``, ``n̂ = (d_i × d_j)/(‖d_i × d_j‖ + 1e-6)`` (line ``i`` itself included,
   distance 0).  For each neighbour ``j`` the offset along line ``i`` of its closest approach::

       n  = d_i × d_j / (‖·‖ + 1e-6),   n₂ = n × d_j / (‖·‖ + 1e-6)
       t  = (a_j − a_i)·n₂ / (d_i·n₂ + 1e-6)

2. **Peak** (``get_peak``/``find_peak``): sort the offsets, drop 5 at each end; while more than 5
   remain and the Kuiper statistic ``V > 0.3``: 500-bin histogram over ``[min, max]`` (numpy's
   bins), empirical CDF ``F`` vs the uniform CDF ``U``, ``k₋ = argmin(F − U)`` over the first 450
   bin edges, ``k₊ = argmax(F − U)`` over edges ``k₋..499``, ``V = F[k₊] + U[k₋] − F[k₋] − U[k₊]``,
   keep the offsets strictly between edges ``k₋`` and ``k₊``.  ``t_i`` = median of the survivors
   (of all offsets if none survive).
3. **Refine** (``num_refine_iterations`` rounds, authors: "use 2 or 3"): with the estimates
   ``p̂ = a + t d``, the 100 estimated points nearest line ``i`` (l2p) and the 100 lines nearest
   ``p̂_i`` (p2l), both by the authors' point–line distance; if their intersection has more than
   10 members the offsets come from it, else from the l2p set; then step 2 again.

Ties at the ``k``-th neighbour are broken by the lower index (the authors' ``argpartition``
leaves them unspecified).  The ``--clean_output`` branch of their script (statistical outlier
removal) writes the *original* points (a bug); it is not reproduced.

**Implementation.**  The ``O(N²)`` neighbour search runs in row chunks (``lax.map`` with
``chunk_size`` rows against all ``N`` lines), so memory is ``O(chunk_size · N)``; distances
are written per component so XLA fuses each row into one loop, and the ``k`` nearest come from
``lax.top_k`` (the dominant cost on CPU: XLA-CPU runs it as a serial partial sort on the
calling thread).  Blocks of rows therefore run from one host thread per core
(``num_threads``).  The peak finder sorts values with a bitonic network
(:func:`sort_values`), ~3.5× cheaper than XLA-CPU's comparator sort.  Measured and rejected
(N = 20,000, CPU time per row): masking values above a sampled threshold before ``top_k``
(fewer heap insertions, but the extra passes cost more), ``lax.approx_min_k`` (a full sort on
CPU, 20× slower), radix/binary-search selection and cumsum-based compaction (XLA-CPU
reductions and ``cumsum`` are not vectorised well: slower than ``top_k``).  Refinement ranks
by ``‖v × d‖²``, a strictly
increasing function of the authors' point–line distance (same neighbours).  XLA-CPU rewrites
``x / c`` as ``x·(1/c)`` and contracts ``k·step + lo`` into an FMA; both would move histogram
edges and CDF values by an ulp, and the Kuiper statistic has exact ties (it is piecewise
rational), so both are pinned (``optimization_barrier``, :func:`_materialise`).  With that, the
result equals the numpy reference (``tests/line2point_reference.py``) to 1e-6 in float64.
Ties between equal distances go to the lower index (``top_k`` is stable), as a stable
``argsort``'s first ``k`` in the reference.
Computation runs in the dtype of the lines (``float64`` under ``jax.enable_x64``).

**Differentiable core.**  :func:`line2point` is the host entry point: it checks the input (shape,
NaN/inf, zero directions: ``ValueError``) and runs row blocks from host threads.  Two pure
functions without host checks or threads can be jitted and differentiated:

* :func:`line2point_offsets` — the continuous part: the peak offset of every line from a *given*
  neighbour set (the closest-approach estimates and the Kuiper peak);
* :func:`line2point_core` — the whole attack as ``lax.map`` passes over the rows in one
  traceable function (the numbers of :func:`line2point` up to rounding: 1e-14 in the tests).

The discrete choices are piecewise constant in the lines and are treated as constants
(``lax.stop_gradient``): the coarse and refinement neighbour sets, the l2p ∩ p2l mask, and the
Kuiper interval of the peak finder together with the sorted position of the median.  The
gradient is that of the offsets with those choices frozen, i.e. of the closest-approach
estimates that the median picks (exact almost everywhere; at a tie or a switch of a discrete
choice the result is one of the one-sided derivatives).  ``tests/test_attack_gradients.py``
checks ``jax.jit(jax.grad(...))`` of both against central finite differences.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, Bool, Float, Int

from privslam_jax.geometry.plucker import safe_norm
from privslam_jax.types import LineCloud

__all__ = [
    "Line2PointConfig",
    "line2point",
    "line2point_core",
    "line2point_offsets",
    "get_peak",
    "select_smallest",
    "sort_values",
    "num_coarse_neighbours",
]

_EPS = 1e-6  # the authors' ``10e-7``


@dataclass(frozen=True)
class Line2PointConfig:
    """Parameters of Line2Point (defaults = the authors' code)."""

    max_neighbours: int = 500
    """Upper bound of the coarse neighbour count ``k = int(min(500, 0.05·N))``."""
    neighbour_fraction: float = 0.05
    """Fraction of ``N`` in the coarse neighbour count."""
    num_bins: int = 500
    """Histogram bins of the Kuiper peak finder."""
    num_trim: int = 5
    """Offsets dropped at each end before peak finding."""
    kuiper_threshold: float = 0.3
    """Keep shrinking the interval while the Kuiper statistic exceeds this."""
    num_refine_iterations: int = 2
    """Refinement rounds (authors: 2 or 3)."""
    refine_l2p: int = 100
    """Estimated points nearest each line used in refinement."""
    refine_p2l: int = 100
    """Lines nearest each estimated point used in refinement."""
    min_intersection: int = 10
    """Use the l2p ∩ p2l set when it has more than this many members."""
    chunk_size: int = 64
    """Rows per vectorised block of the neighbour search (memory ∝ chunk_size · N)."""
    rows_per_call: int = 4096
    """Upper bound of the rows per jitted call (progress granularity)."""
    num_threads: int = 0
    """Host threads running row blocks concurrently (``0``: one per CPU this process may use).
    XLA-CPU runs ``top_k`` (the dominant cost) on the calling thread, so one call uses one core."""


def num_coarse_neighbours(n: int, config: Line2PointConfig = Line2PointConfig()) -> int:
    """``int(min(500, 0.05·N))`` as in ``Recover.py`` (at least 1, at most ``N``)."""
    return max(1, min(n, int(min(config.max_neighbours, config.neighbour_fraction * n))))


def _uniform_cdf(num_bins: int) -> np.ndarray:
    """``uni_cs`` of ``find_peak``, computed exactly as numpy does it there."""
    uni = np.ones(num_bins) / num_bins
    cs = np.zeros(num_bins + 1)
    cs[1:] = np.cumsum(uni) / np.sum(uni)
    return cs


def select_smallest(values: Float[Array, " N"], k: int) -> Int[Array, " k"]:
    """Indices of the ``k`` smallest values, ties → lower index (as a stable argsort's first ``k``).

    ``lax.top_k`` on the negated values.  Measured on this CPU, XLA's ``top_k`` costs roughly
    ``∝ k`` per row whatever the row length, so a two-level (group-minimum) exact selection
    was slower and is not used.
    """
    return lax.top_k(-values, k)[1]


def sort_values(x: Float[Array, "*B K"]) -> Float[Array, "*B K2"]:
    """``x`` sorted along the last axis, padded with ``+inf`` to the next power of two ``K2``.

    A bitonic sorting network (``log₂K2·(log₂K2+1)/2`` stages of element-wise min/max on
    reshaped views): XLA fuses and vectorises it, whereas its comparator-based ``sort`` costs
    ~70 µs per row of 500 on this CPU (bitonic: ~20 µs).  Only values are sorted (no indices),
    so the result equals ``jnp.sort`` bit for bit; NaN must not occur (``get_peak`` maps it to
    ``+inf``).
    """
    k = x.shape[-1]
    n = 1 << max(0, (k - 1).bit_length())
    lead = x.shape[:-1]
    if n > k:
        x = jnp.concatenate([x, jnp.full((*lead, n - k), jnp.inf, x.dtype)], axis=-1)
    idx = np.arange(n)
    size = 2
    while size <= n:
        j = size // 2
        while j >= 1:
            y = x.reshape(*lead, n // (2 * j), 2, j)
            lo, hi = jnp.minimum(y[..., 0, :], y[..., 1, :]), jnp.maximum(y[..., 0, :], y[..., 1, :])
            asc = jnp.broadcast_to((idx.reshape(n // (2 * j), 2, j)[:, 0, :] & size) == 0, lo.shape)  # pair's direction
            x = jnp.stack([jnp.where(asc, lo, hi), jnp.where(asc, hi, lo)], axis=-2).reshape(*lead, n)
            j //= 2
        size *= 2
    return x


def _materialise(x: Array, runtime_zero: Array) -> Array:
    """``x`` unchanged, but OR-ed bitwise with a zero the compiler cannot prove, so a following
    add is not contracted with the multiply that produced ``x`` into one fused multiply-add."""
    itype = jnp.int64 if x.dtype.itemsize == 8 else jnp.int32
    bits = lax.bitcast_convert_type(x, itype) | runtime_zero.astype(itype)
    return lax.bitcast_convert_type(bits, x.dtype)


def get_peak(
    estimates: Float[Array, " K"], valid: Bool[Array, " K"], config: Line2PointConfig = Line2PointConfig()
) -> Float[Array, ""]:
    """The authors' ``get_peak`` on the valid entries of ``estimates`` (see module docstring).

    Values are sorted with :func:`sort_values` (fast, not differentiable); the differentiable
    twin used by :func:`line2point_core` is :func:`_peak_differentiable` (same value)."""
    s = sort_values(jnp.where(valid & ~jnp.isnan(estimates), estimates, jnp.inf))
    return _peak_of_sorted(s, jnp.sum(valid.astype(jnp.int32)), config)


def _peak_differentiable(
    estimates: Float[Array, " K"], valid: Bool[Array, " K"], config: Line2PointConfig = Line2PointConfig()
) -> Float[Array, ""]:
    """:func:`get_peak` with a gradient: the values are put in order by a gather with the
    (constant) ``argsort`` permutation, so the median of the surviving interval is differentiable
    in the estimates it picks; the interval itself is constant (module docstring)."""
    x = jnp.where(valid & ~jnp.isnan(estimates), estimates, jnp.inf)
    order = jnp.argsort(lax.stop_gradient(x), stable=True)
    return _peak_of_sorted(x[order], jnp.sum(valid.astype(jnp.int32)), config)


def _peak_of_sorted(s: Float[Array, " K"], n: Int[Array, ""], config: Line2PointConfig) -> Float[Array, ""]:
    """The peak of the ``n`` valid values at the start of ascending ``s`` (``+inf`` after them).

    The Kuiper interval search sees ``lax.stop_gradient(s)`` (piecewise constant: no gradient,
    and ``lax.while_loop`` has no reverse mode); the median of the interval reads ``s`` itself."""
    dt = s.dtype
    nb = config.num_bins
    uni = jnp.asarray(_uniform_cdf(nb), dt)
    sc = lax.stop_gradient(s)
    trim = config.num_trim
    ks = jnp.arange(nb)

    def median(a, b):
        m = b - a
        return (s[a + (m - 1) // 2] + s[a + m // 2]) / 2

    def cond(state):
        start, end, kv, shrunk = state
        return (end - start > 5) & (kv > config.kuiper_threshold) & shrunk

    def body(state):
        start, end, _, _ = state
        m = end - start
        lo, hi = sc[start], sc[end - 1]
        same = lo == hi
        lo, hi = jnp.where(same, lo - 0.5, lo), jnp.where(same, hi + 0.5, hi)
        # optimization_barrier: XLA would turn x / c into x * (1/c), which rounds differently
        # from numpy; Kuiper ties (F − U is piecewise rational) then break differently.
        step = (hi - lo) / lax.optimization_barrier(jnp.asarray(nb, dt))
        # numpy.linspace(lo, hi, nb + 1)[:nb] = fl(fl(k·step) + lo); without the bit round trip
        # XLA-CPU fuses the two into an FMA, and offsets lying exactly on an edge change bins.
        edges = _materialise(ks.astype(dt) * step, jnp.minimum(start, 0)) + lo
        cnt = jnp.clip(jnp.searchsorted(sc, edges, side="left"), start, end) - start
        hist_cs = cnt.astype(dt) / lax.optimization_barrier(jnp.broadcast_to(m.astype(dt), cnt.shape))
        diff = hist_cs - uni[:nb]
        kmin = jnp.argmin(diff[: int(0.9 * nb)])
        kmax = jnp.argmax(jnp.where(ks >= kmin, diff, -jnp.inf))
        kv = hist_cs[kmax] + uni[kmin] - hist_cs[kmin] - uni[kmax]
        new_start = jnp.clip(jnp.searchsorted(sc, edges[kmin], side="right"), start, end)
        new_end = jnp.maximum(jnp.clip(jnp.searchsorted(sc, edges[kmax], side="left"), start, end), new_start)
        # An interval that did not shrink would repeat forever (all offsets equal: issue 15): stop.
        # Every other step drops at least one offset, so the loop ends after at most K steps.
        return new_start, new_end, kv, (new_start != start) | (new_end != end)

    start0 = jnp.minimum(jnp.asarray(trim, jnp.int32), n)
    end0 = jnp.maximum(n - trim, start0)
    start, end, _, _ = lax.while_loop(cond, body, (start0, end0, jnp.asarray(1.0, dt), jnp.asarray(True)))
    return jnp.where(end > start, median(start, end), median(jnp.int32(0), n))


def _estimates(a_i, d_i, a_j, d_j):
    """Offsets along line i of the closest approach to lines j (authors' ``calc_estimate_from_line``)."""
    a_i, d_i = a_i[None, :], d_i[None, :]
    n = jnp.cross(d_i, d_j)
    n = n / (safe_norm(n, keepdims=True) + _EPS)  # safe_norm: the line itself (n = 0) is a coarse neighbour
    n2 = jnp.cross(n, d_j)
    n2 = n2 / (safe_norm(n2, keepdims=True) + _EPS)
    return jnp.sum((a_j - a_i) * n2, axis=-1) / (jnp.sum(d_i * n2, axis=-1) + _EPS)


def _line_line_dist(a_i, d_i, aT, dT):
    """Authors' ``get_n_closest_lines_from_line`` distance ``|(a_j − a_i)·c/(‖c‖ + 1e-6)|``,
    ``c = d_i × d_j``, of line i to all lines (components ``aT, dT``: ``(3, N)``; one fused loop)."""
    cx = d_i[1] * dT[2] - d_i[2] * dT[1]
    cy = d_i[2] * dT[0] - d_i[0] * dT[2]
    cz = d_i[0] * dT[1] - d_i[1] * dT[0]
    num = (aT[0] - a_i[0]) * cx + (aT[1] - a_i[1]) * cy + (aT[2] - a_i[2]) * cz
    return jnp.abs(num) / (jnp.sqrt(cx * cx + cy * cy + cz * cz) + _EPS)


def _point_line_key(vT, dT):
    """``‖v × d‖²`` for columns of ``vT``, ``dT`` (``(3, N)``, ``(3, N)`` or ``(3,)``).

    The authors' point–line distance ``|v·n₁|`` (``n = v × d``, ``n₁ = n × d``, each normalised
    with ``+1e-6``) equals ``s²/(s(1+ε) + ε²)`` with ``s = ‖v × d‖`` for unit ``d``: strictly
    increasing in ``s``, so ranking by ``s²`` selects the same neighbours.
    """
    cx = vT[1] * dT[2] - vT[2] * dT[1]
    cy = vT[2] * dT[0] - vT[0] * dT[2]
    cz = vT[0] * dT[1] - vT[1] * dT[0]
    return cx * cx + cy * cy + cz * cz


def _anchors(lines: LineCloud) -> tuple[Float[Array, "N 3"], Float[Array, "N 3"]]:
    """``(a, d)``: unit directions and anchors ``a = d × m`` (closest points to the origin)."""
    d = jnp.asarray(lines.directions)
    d = d / jnp.linalg.norm(d, axis=-1, keepdims=True)
    a = jnp.cross(d, jnp.asarray(lines.moments, d.dtype))
    return a, d


def _coarse_select(i, a, d, aT, dT, k: int):
    """Coarse neighbour set of line ``i``: the ``k`` nearest lines by the authors' distance."""
    return select_smallest(_line_line_dist(a[i], d[i], aT, dT), k)


def _refine_select(i, a, d, pe, aT, dT, peT, k1: int, k2: int, config: Line2PointConfig):
    """Refinement neighbour set of line ``i`` and its mask: the l2p set, masked to l2p ∩ p2l
    when that has more than ``min_intersection`` members."""
    l2p = select_smallest(_point_line_key(peT - a[i][:, None], d[i][:, None]), k1)
    p2l = select_smallest(_point_line_key(aT - pe[i][:, None], dT), k2)
    member = jnp.any(l2p[:, None] == p2l[None, :], axis=1)
    use = jnp.where(jnp.sum(member.astype(jnp.int32)) > config.min_intersection, member, True)
    return l2p, use


def _row_offset(i, a, d, nb, valid, config: Line2PointConfig, peak):
    """Offset of line ``i`` from its neighbours ``nb`` (entries with ``valid``): the peak of the
    closest-approach estimates."""
    est = _estimates(a[i], d[i], a[nb], d[nb])
    return peak(est, valid, config)


@partial(jax.jit, static_argnames=("k", "config"))
def _coarse_rows(rows, a, d, *, k: int, config: Line2PointConfig):
    aT, dT = a.T, d.T

    def one(i):
        nn = _coarse_select(i, a, d, aT, dT, k)
        return _row_offset(i, a, d, nn, jnp.ones(nn.shape, bool), config, get_peak)

    return lax.map(one, rows, batch_size=config.chunk_size)


@partial(jax.jit, static_argnames=("config",))
def _refine_rows(rows, a, d, t, *, config: Line2PointConfig):
    pe = a + t[:, None] * d
    n = a.shape[0]
    k1, k2 = min(config.refine_l2p, n), min(config.refine_p2l, n)

    aT, dT, peT = a.T, d.T, pe.T

    def one(i):
        l2p, use = _refine_select(i, a, d, pe, aT, dT, peT, k1, k2, config)
        return _row_offset(i, a, d, l2p, use, config, get_peak)

    return lax.map(one, rows, batch_size=config.chunk_size)


def _map_rows(fn, n: int, chunk_size: int):
    """``fn`` on rows ``0 … n−1`` by ``lax.map`` in blocks of ``chunk_size``; the rows are padded
    with row ``n − 1`` to whole blocks, so the body is compiled once (no remainder branch)."""
    step = max(1, min(chunk_size, n))
    rows = jnp.minimum(jnp.arange(-(-n // step) * step), n - 1)
    return jax.tree.map(lambda x: x[:n], lax.map(fn, rows, batch_size=step))


def _offsets(a, d, neighbours, valid, config: Line2PointConfig):
    def one(i):
        return _row_offset(i, a, d, neighbours[i], valid[i], config, _peak_differentiable)

    return _map_rows(one, a.shape[0], config.chunk_size)


def line2point_offsets(
    lines: LineCloud,
    neighbours: Int[Array, "N K"],
    valid: Bool[Array, "N K"] | None = None,
    config: Line2PointConfig = Line2PointConfig(),
) -> Float[Array, " N"]:
    """The continuous part of Line2Point: the offset ``t_i`` of every line from a given
    neighbour set (pure and jit-able, differentiable in ``lines``; no input checks).

    ``t_i`` is the Kuiper peak (:func:`get_peak`) of the closest-approach offsets along line
    ``i`` of the lines ``neighbours[i, j]`` with ``valid[i, j]`` (all, when ``valid`` is
    ``None``).  The peak's interval and the sorted position of its median are piecewise
    constant and are held constant (``lax.stop_gradient``): the gradient is that of the
    estimates the median picks.  Same values as the public attack for the same neighbour sets.
    """
    a, d = _anchors(lines)
    nb = jnp.asarray(neighbours)
    ok = jnp.ones(nb.shape, bool) if valid is None else jnp.asarray(valid, bool)
    return _offsets(a, d, nb, ok, config)


def line2point_core(
    lines: LineCloud, config: Line2PointConfig = Line2PointConfig()
) -> tuple[Float[Array, "N 3"], Float[Array, " N"]]:
    """Line2Point as one pure, jit-able and differentiable function: ``(points, offsets)`` as
    :func:`line2point` returns them, without its input checks, host threads or progress bar.

    The neighbour sets (coarse: the ``k`` nearest lines; refinement: l2p, p2l and their
    intersection) are chosen on ``lax.stop_gradient`` copies of the lines, so they are
    constants of the gradient, as are the peak finder's interval and median position (module
    docstring); the offsets are then :func:`line2point_offsets` of those sets.  Memory
    ``O(N·k)`` for the neighbour sets (``int32``) plus ``O(chunk_size · N)`` for the search.
    Call :func:`line2point` for untrusted input: NaN lines here give NaN points, not an error.
    """
    a, d = _anchors(lines)
    a0, d0 = lax.stop_gradient(a), lax.stop_gradient(d)
    n = a.shape[0]
    k = num_coarse_neighbours(n, config)
    aT, dT = a0.T, d0.T
    nb = _map_rows(lambda i: _coarse_select(i, a0, d0, aT, dT, k), n, config.chunk_size)
    t = _offsets(a, d, nb, jnp.ones(nb.shape, bool), config)
    k1, k2 = min(config.refine_l2p, n), min(config.refine_p2l, n)
    for _ in range(config.num_refine_iterations):
        pe = a0 + lax.stop_gradient(t)[:, None] * d0
        peT = pe.T
        nb, use = _map_rows(
            lambda i, pe=pe, peT=peT: _refine_select(i, a0, d0, pe, aT, dT, peT, k1, k2, config), n, config.chunk_size
        )
        t = _offsets(a, d, nb, use, config)
    return a + t[:, None] * d, t


def _num_threads(config: Line2PointConfig) -> int:
    if config.num_threads > 0:
        return config.num_threads
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def _block_rows(n: int, config: Line2PointConfig) -> int:
    """Rows per call: a multiple of ``chunk_size`` (so ``lax.map`` has no remainder branch), at
    most ``rows_per_call``, with the number of calls a multiple of the thread count (balanced)."""
    cs, workers = config.chunk_size, _num_threads(config)
    calls = -(-n // max(config.rows_per_call, cs))
    calls = -(-calls // workers) * workers
    step = -(-n // calls)
    return -(-step // cs) * cs


def _run_rows(fn, n: int, config: Line2PointConfig, bar) -> jax.Array:
    """Run ``fn`` on blocks of rows (all of one shape, so one compilation; the last block is
    padded with row ``n − 1``) from ``num_threads`` host threads and concatenate in order."""
    step = _block_rows(n, config)
    starts = list(range(0, n, step))
    x64 = bool(jax.config.jax_enable_x64)  # thread-local under ``jax.enable_x64``: pass it on

    def call(s: int) -> jax.Array:
        with jax.enable_x64(x64):
            rows = jnp.minimum(jnp.arange(s, s + step, dtype=jnp.int32), n - 1)
            return jax.block_until_ready(fn(rows)[: min(step, n - s)])

    workers = min(_num_threads(config), len(starts))
    if workers == 1:
        out = []
        for s in starts:
            out.append(call(s))
            if bar is not None:
                bar.update(out[-1].shape[0])
        return jnp.concatenate(out)
    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures = [pool.submit(call, s) for s in starts]
        if bar is not None:
            for f in as_completed(futures):
                bar.update(f.result().shape[0])
        return jnp.concatenate([f.result() for f in futures])


def line2point(
    lines: LineCloud, config: Line2PointConfig = Line2PointConfig(), *, progress: bool = False
) -> tuple[Float[Array, "N 3"], Float[Array, " N"]]:
    """Recover one point per line.  Returns ``(points, offsets)`` with ``points = a + t·d``,
    ``a = d × m`` the anchor (closest point to the origin) and ``t`` the offsets.

    Host entry point: checks the lines (``ValueError`` on fewer than 2, a wrong shape, NaN/inf or
    zero directions), then runs the rows in blocks from host threads.  Not traceable; under
    ``jit``/``grad`` use :func:`line2point_core` (the same numbers up to rounding)."""
    shape = tuple(np.shape(lines.directions))
    if len(shape) != 2 or shape[1] != 3 or shape[0] < 2:
        raise ValueError(f"Line2Point needs at least 2 lines of shape (N, 3), got {shape}")
    if tuple(np.shape(lines.moments)) != shape:
        raise ValueError(f"line moments must have the shape of the directions {shape}, got {tuple(np.shape(lines.moments))}")
    a, d = _anchors(lines)
    if not bool(jnp.all(jnp.isfinite(a)) & jnp.all(jnp.isfinite(d))):
        raise ValueError("line cloud contains NaN/inf or zero directions")
    n = d.shape[0]
    k = num_coarse_neighbours(n, config)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n * (1 + config.num_refine_iterations), desc="Line2Point", unit="line")
    t = _run_rows(lambda r: _coarse_rows(r, a, d, k=k, config=config), n, config, bar)
    for _ in range(config.num_refine_iterations):
        t_prev = t
        t = _run_rows(lambda r: _refine_rows(r, a, d, t_prev, config=config), n, config, bar)
    if bar is not None:
        bar.close()
    return a + t[:, None] * d, t
