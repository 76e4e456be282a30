"""Damped normal equations of bundle adjustment solved by the Schur complement on the points.

Cameras ``ξ_c`` (6 per camera, left perturbation) and points ``δ_p`` (3 per point); per observation
``o = (c, p)`` the Jacobian blocks ``A_o``, ``B_o`` and IRLS weight ``w_o`` give

    [ U   W ] [ξ]   [−g_c]     U = blockdiag_c Σ_{o∈c} w A_oᵀA_o  (6×6 blocks)
    [ Wᵀ  V ] [δ] = [−g_p],    V = blockdiag_p Σ_{o∈p} w B_oᵀB_o  (3×3 blocks),  W_o = w A_oᵀB_o,

damped as ``U + λ diag(U)``, ``V + λ diag(V)`` (diagonals clamped to [1e-6, 1e32] as in Ceres).
Eliminating the points (Triggs et al. 2000, §6.1; Agarwal et al., *Bundle Adjustment in the Large*,
ECCV 2010, §3) gives the reduced camera system

    S ξ = −g_c + Σ_o Y_o g_{p(o)},     S = U − Σ_p Σ_{o,o'∈p} Y_o W_{o'}ᵀ,    Y_o = W_o V_{p(o)}⁻¹,

then ``δ_p = V_p⁻¹(−g_p − Σ_{o∈p} W_oᵀ ξ_{c(o)})``.  The 3×3 blocks ``V_p`` are inverted in batch in
closed form (adjugate, after Jacobi scaling); ``S`` (``6M × 6M``, dense) is factorised by Cholesky.
Fixed cameras get ``ξ_c = 0`` (identity rows in ``S``).

Assembly.  ``S``'s off-diagonal part is a sum over the pairs ``(o, o')`` of observations of one
point.  The pairs are built on the host (:func:`analyze`), sorted by camera pair and padded per camera
pair to a multiple of ``chunk`` so that the jitted code sums chunks with a dense reduction and runs
the (slow on CPU) scatter ``segment_sum`` only over ``Q/chunk`` chunk sums.  Only ``o < o'`` is
stored; ``S_off = X + Xᵀ``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jaxtyping import Array, Bool, Float, Int

__all__ = ["BlockSystem", "SchurStructure", "analyze", "block_diag", "pow2_bucket", "schur_damped_solve", "sym3_inverse"]


@struct.dataclass
class BlockSystem:
    """The blocks of the normal equations of a linearisation, and the cost there."""

    U: Float[Array, "M 6 6"]
    """Camera blocks."""
    V: Float[Array, "P 3 3"]
    """Point blocks."""
    W: Float[Array, "O 6 3"]
    """Camera-point block of each observation."""
    gc: Float[Array, "M 6"]
    gp: Float[Array, "P 3"]
    cost: Float[Array, ""]


@struct.dataclass
class SchurStructure:
    """Host-computed sparsity of the Schur complement (:func:`analyze`), padded."""

    pair_a: Int[Array, " Q"]
    """First observation of each pair (``o < o'``, same point)."""
    pair_b: Int[Array, " Q"]
    """Second observation of each pair."""
    chunk_seg: Int[Array, " Qc"]
    """Camera-pair segment ``c(o)·M + c(o')`` of each chunk of ``chunk`` consecutive pairs."""



def pow2_bucket(n: int, minimum: int = 4) -> int:
    """Padded size: the smallest power of two ``≥ max(n, minimum)``."""
    return int(max(minimum, 1 << max(0, int(n - 1).bit_length())))



def analyze(
    obs_cam: np.ndarray, obs_pt: np.ndarray, n_cams: int, n_obs_padded: int, chunk: int, pad: bool = True
) -> SchurStructure:
    """Pairs of observations of the same point, sorted by camera pair and padded per pair to ``chunk``.

    ``obs_cam``/``obs_pt`` hold the *valid* observations only (rows ``0..O-1`` of the padded arrays);
    ``n_obs_padded > O`` so that row ``O`` (a padded, zero-weight observation) serves as the dummy.
    """
    obs_cam = np.asarray(obs_cam, np.int64)
    obs_pt = np.asarray(obs_pt, np.int64)
    n = obs_cam.shape[0]
    if n_obs_padded <= n:
        raise ValueError("analyze needs at least one padded observation row for the dummy pair")
    order = np.argsort(obs_pt, kind="stable")
    pts_sorted = obs_pt[order]
    starts = np.flatnonzero(np.r_[True, pts_sorted[1:] != pts_sorted[:-1]]) if n else np.zeros(0, np.int64)
    sizes = np.diff(np.r_[starts, n])
    group_start = np.repeat(starts, sizes)
    pos = np.arange(n)
    later = group_start + np.repeat(sizes, sizes) - pos - 1  # observations after `pos` in its group
    total = int(later.sum())
    first_pos = np.repeat(pos, later)
    offs = np.arange(total) - np.repeat(np.cumsum(later) - later, later)
    second_pos = first_pos + 1 + offs
    a, b = order[first_pos], order[second_pos]
    seg = obs_cam[a] * n_cams + obs_cam[b]
    srt = np.argsort(seg, kind="stable")
    a, b, seg = a[srt], b[srt], seg[srt]
    # pad every segment to a multiple of `chunk`
    useg, cnt = np.unique(seg, return_counts=True)
    padded_cnt = -(-cnt // chunk) * chunk
    n_chunks = int(padded_cnt.sum() // chunk)
    dummy = n
    pa = np.full(n_chunks * chunk, dummy, np.int64)
    pb = np.full(n_chunks * chunk, dummy, np.int64)
    dst = np.repeat(np.cumsum(padded_cnt) - padded_cnt, cnt) + (np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt))
    pa[dst], pb[dst] = a, b
    chunk_seg = np.repeat(useg, padded_cnt // chunk)
    n_chunks_pad = pow2_bucket(n_chunks + 1, minimum=8) if pad else n_chunks + 1
    pa = np.r_[pa, np.full((n_chunks_pad - n_chunks) * chunk, dummy)]
    pb = np.r_[pb, np.full((n_chunks_pad - n_chunks) * chunk, dummy)]
    chunk_seg = np.r_[chunk_seg, np.zeros(n_chunks_pad - n_chunks, np.int64)]
    return SchurStructure(
        # cast on the host and transferred: ``jnp.asarray`` of a host array compiles a copy program
        # for every new length (jax 0.10), and these lengths change with every local BA
        pair_a=jax.device_put(pa.astype(np.int32)), pair_b=jax.device_put(pb.astype(np.int32)),
        chunk_seg=jax.device_put(chunk_seg.astype(np.int32)),
    )



def sym3_inverse(A: Float[Array, "P 3 3"]) -> Float[Array, "P 3 3"]:
    """Batched inverse of symmetric positive-definite 3×3 blocks (Jacobi scaling + adjugate)."""
    d = jnp.sqrt(jnp.diagonal(A, axis1=1, axis2=2))  # (P, 3)
    s = 1.0 / d
    B = A * s[:, :, None] * s[:, None, :]
    a, b, c = B[:, 0, 0], B[:, 0, 1], B[:, 0, 2]
    e, f, i = B[:, 1, 1], B[:, 1, 2], B[:, 2, 2]
    c00 = e * i - f * f
    c01 = c * f - b * i
    c02 = b * f - c * e
    c11 = a * i - c * c
    c12 = b * c - a * f
    c22 = a * e - b * b
    inv_det = 1.0 / (a * c00 + b * c01 + c * c02)
    inv = jnp.stack(
        [jnp.stack([c00, c01, c02], -1), jnp.stack([c01, c11, c12], -1), jnp.stack([c02, c12, c22], -1)], -2
    ) * inv_det[:, None, None]
    return inv * s[:, :, None] * s[:, None, :]



def _off_diagonal(Y: Array, W: Array, structure: SchurStructure, n_cams: int, chunk: int) -> Array:
    """``X = Σ_{o<o'} Y_o W_o'ᵀ`` placed at block ``(c(o), c(o'))``, as a dense ``(6M, 6M)`` matrix."""
    Ya = Y.reshape(-1, 18)[structure.pair_a].T.reshape(6, 3, -1)  # pair axis last: vectorises
    Wb = W.reshape(-1, 18)[structure.pair_b].T.reshape(6, 3, -1)
    prod = Ya[:, None, 0, :] * Wb[None, :, 0, :]
    for k in (1, 2):
        prod = prod + Ya[:, None, k, :] * Wb[None, :, k, :]  # (6, 6, Q)
    prod = jnp.sum(prod.reshape(36, -1, chunk), axis=2).T  # (Q/chunk, 36)
    Xs = jax.ops.segment_sum(prod, structure.chunk_seg, n_cams * n_cams, indices_are_sorted=True)
    M = n_cams
    return Xs.reshape(M, M, 6, 6).transpose(0, 2, 1, 3).reshape(6 * M, 6 * M)



def schur_damped_solve(
    lin: BlockSystem, cam: Int[Array, " O"], pt: Int[Array, " O"], lam: Float[Array, ""], fixed_cams: Bool[Array, " M"],
    structure: SchurStructure, chunk: int,
) -> tuple[Float[Array, "M 6"], Float[Array, "P 3"], Float[Array, ""]]:
    """Solve the damped normal equations by the Schur complement; returns ``(ξ, δ, predicted decrease)``."""
    M = fixed_cams.shape[0]
    P = lin.V.shape[0]
    dtype = lin.U.dtype
    eye6 = jnp.eye(6, dtype=dtype)
    dU = jnp.clip(jnp.diagonal(lin.U, axis1=1, axis2=2), 1e-6, 1e32)
    dV = jnp.clip(jnp.diagonal(lin.V, axis1=1, axis2=2), 1e-6, 1e32)
    Vinv = sym3_inverse(lin.V + (lam * dV)[:, :, None] * jnp.eye(3, dtype=dtype)[None])
    Y = jnp.sum(lin.W[:, :, :, None] * Vinv[pt][:, None, :, :], axis=2)  # (O, 6, 3)
    # materialise Y: otherwise XLA fuses its computation into every gather below (measured 3-5× slower)
    Y, Vinv = jax.lax.optimization_barrier((Y, Vinv))
    rc = -lin.gc + jax.ops.segment_sum(jnp.sum(Y * lin.gp[pt][:, None, :], axis=2), cam, M)
    S_diag = jax.ops.segment_sum(jnp.sum(Y[:, :, None, :] * lin.W[:, None, :, :], axis=3), cam, M)
    X_off = _off_diagonal(Y, lin.W, structure, M, chunk)
    Ud = lin.U + (lam * dU)[:, :, None] * eye6[None] - S_diag
    Ud = jnp.where(fixed_cams[:, None, None], eye6[None], Ud)
    fixed6 = jnp.repeat(fixed_cams, 6)
    S = block_diag(Ud) - X_off - X_off.T
    S = jnp.where(fixed6[:, None] | fixed6[None, :], jnp.eye(6 * M, dtype=dtype), S)
    rc = jnp.where(fixed_cams[:, None], 0.0, rc).reshape(-1)
    L = jnp.linalg.cholesky(S)
    xi = jax.scipy.linalg.cho_solve((L, True), rc).reshape(M, 6)
    # back-substitution for the points
    rp = -lin.gp - jax.ops.segment_sum(jnp.sum(lin.W * xi[cam][:, :, None], axis=1), pt, P)
    dp = jnp.sum(Vinv * rp[:, None, :], axis=2)
    pred = 0.5 * (jnp.sum(xi * (lam * dU * xi - lin.gc)) + jnp.sum(dp * (lam * dV * dp - lin.gp)))
    return xi, dp, pred



def block_diag(B: Float[Array, "M 6 6"]) -> Float[Array, "N N"]:
    M = B.shape[0]
    eyeM = jnp.eye(M, dtype=B.dtype)
    return (eyeM[:, None, :, None] * B[:, :, None, :]).reshape(6 * M, 6 * M)
