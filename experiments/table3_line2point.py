"""Table 3 of the source paper, redone honestly: how much of a map do line-cloud attacks recover?

Goal: for the random lift, paired-point lifting, ray clouds (8 anchors) and sphere clouds, attacked
by Line2Point (faithful to Chelani et al.'s code), by the gradient attack, (paired lifting) by
two-peak finding (``privslam_jax.attacks.two_peaks``; the two peaks handed out by a fair coin per
pair, and by the oracle that knows the truth: Lee et al.'s swap ratios ½ and 0) and (ray clouds) by
the vote across centres of ``privslam_jax.attacks.centred``, report every metric of ``privslam_jax.metrics.privacy``
(the paper's mean nearest-neighbour distance, per-point errors with known correspondences,
Chamfer) with the no-attack baselines beside them, on
  (a) a sparse SLAM-like map: ORB keypoints of the synthetic street world (object-free renders,
      so only static surfaces) back-projected with the true depth and pose, voxel-deduplicated;
  (b) the real KITTI ``seq1`` map: the 15,698 COLMAP points of
      ``../shared/reference/ba/kitti_seq1_colmap_optimum.bal.txt.bz2`` (skipped when absent), scaled to
      metres (COLMAP's scale is arbitrary; :func:`colmap_metric_scale`).

Command:   python experiments/table3_line2point.py            (writes results/table3_line2point.md)
Runtime:   ~2 min on 2 idle CPU cores (the ray-cloud vote and TPF on ~15k lines ≈ 35 s each).
Expected:  on KITTI a faithful Line2Point recovers a large share of the random-lifted map within
           0.5 m, while the paper's NN metric looks similar for attack and no attack; paired-point
           lifting defeats it.  Ray and sphere clouds are attacked only by the attacks we have; a
           sphere cloud has none made for it yet.  Lift keys are fixed seeds (explicit, for
           reproducibility only).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()

import cv2  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from privslam_jax._shared import shared_dir  # noqa: E402
from privslam_jax.data.files import write_atomic  # noqa: E402
from privslam_jax.attacks.centred import ray_cloud_attack  # noqa: E402
from privslam_jax.attacks.gradient import GradientAttackConfig, gradient_attack  # noqa: E402
from privslam_jax.attacks.line2point import Line2PointConfig, line2point  # noqa: E402
from privslam_jax.attacks.two_peaks import assign_pairs, two_peak_attack  # noqa: E402
from privslam_jax.metrics.privacy import baseline_points, point_recovery_metrics  # noqa: E402
from privslam_jax.privacy.lift import fixed_key, paired_lift, random_lift, ray_lift, sphere_lift  # noqa: E402


def get_config() -> dict:
    return {
        "synthetic_frames": 60,  # frames of the synthetic sequence used for the map
        "synthetic_stride": 2,  # every 2nd frame contributes keypoints
        "orb_features": 500,  # per frame (OpenCV default)
        "max_depth": 40.0,  # metres, like a SLAM map's far points
        "voxel": 0.05,  # dedupe points closer than this (a map point is observed once)
        "lift_seed": 0,
        "ray_anchors": 8,  # ray_lift's default
        "line2point": Line2PointConfig(num_refine_iterations=2),
        "gradient": GradientAttackConfig(),
        "out": ROOT / "results" / "table3_line2point.md",
    }


def synthetic_map(cfg: dict, with_descriptors: bool = False):
    """Sparse map from the synthetic world: ORB keypoints on object-free renders, back-projected;
    ``(points, their ORB descriptors, the centre of the camera that saw each, the sequence)`` with
    ``with_descriptors``."""
    from privslam_jax.data.synthetic import SynthConfig, make_sequence

    seq = make_sequence(SynthConfig(num_frames=cfg["synthetic_frames"], object_density=0.0, seed=0))
    cam = seq.camera
    orb = cv2.ORB_create(nfeatures=cfg["orb_features"])
    pts, descs, views = [], [], []
    for i in range(0, len(seq), cfg["synthetic_stride"]):
        f = seq[i]
        grey = cv2.cvtColor((np.clip(f.background, 0, 1) * 255).astype(np.uint8), cv2.COLOR_RGB2GRAY)
        kps, desc = orb.detectAndCompute(grey, None)
        if not kps:
            continue
        uv = np.array([k.pt for k in kps])
        z = f.background_depth if f.background_depth is not None else f.depth
        zz = z[np.clip(np.rint(uv[:, 1]).astype(int), 0, z.shape[0] - 1), np.clip(np.rint(uv[:, 0]).astype(int), 0, z.shape[1] - 1)]
        ok = (zz > 0) & (zz < cfg["max_depth"])
        uv, zz = uv[ok], zz[ok]
        descs.append(desc[ok])
        p_c = np.stack([(uv[:, 0] - cam.cx) / cam.fx * zz, (uv[:, 1] - cam.cy) / cam.fy * zz, zz], 1)
        T = f.T_w_c
        pts.append(p_c @ T[:3, :3].T + T[:3, 3])
        views.append(np.tile(T[:3, 3], (len(p_c), 1)))
    p = np.concatenate(pts)
    _, keep = np.unique(np.floor(p / cfg["voxel"]).astype(np.int64), axis=0, return_index=True)
    keep = np.sort(keep)
    return (p[keep], np.concatenate(descs)[keep], np.concatenate(views)[keep], seq) if with_descriptors else p[keep]


def colmap_metric_scale(problem, shared: Path) -> float:
    """The factor that puts the COLMAP ``seq1`` map in metres.  COLMAP's scale is arbitrary: its 51 camera
    centres span about a quarter of the ground truth's 60 m.  Umeyama scale of the centres onto the
    ground-truth centres, refitted without the cameras more than 0.25 m off after the first fit (8 of
    the 51 sit one frame step, ~1.2 m, from the frame of the same index; the other 43 agree within 2 cm)."""
    from privslam_jax.data.bal import bal_to_opencv
    from privslam_jax.data.kitti import KittiSequence
    from privslam_jax.geometry.align import umeyama_np

    T = bal_to_opencv(problem)[0]
    centres = np.einsum("nji,nj->ni", T[:, :3, :3], -T[:, :3, 3])  # −Rᵀt per camera
    truth = KittiSequence(shared / "data" / "kitti_odometry" / "sequences" / "seq1", grey=True).poses[: len(centres), :3, 3]
    R, t, c = umeyama_np(centres, truth, with_scale=True)
    ok = np.linalg.norm(c * centres @ R.T + t - truth, axis=1) < 0.25
    return umeyama_np(centres[ok], truth[ok], with_scale=True)[2]


def kitti_map() -> tuple[np.ndarray, float] | None:
    """The COLMAP ``seq1`` map in metres and the scale that put it there (:func:`colmap_metric_scale`), or
    None without ``../shared``."""
    shared = shared_dir()
    path = None if shared is None else shared / "reference" / "ba" / "kitti_seq1_colmap_optimum.bal.txt.bz2"
    if path is None or not path.is_file():
        return None
    from privslam_jax.data.bal import read_bal

    problem = read_bal(path)
    scale = colmap_metric_scale(problem, shared)
    return np.asarray(problem.points, np.float64) * scale, scale


KEYS = ("nn_mean", "per_point_median", "per_point_mean", "within_0.1", "within_0.5", "within_1.0", "chamfer")


def evaluate(points: np.ndarray, cfg: dict, scene: str) -> list[tuple]:
    rows = []
    lifts = {"random": random_lift, "paired": paired_lift,
             "ray": lambda p, key: ray_lift(p, key, num_anchors=cfg["ray_anchors"]), "sphere": sphere_lift}
    for lift_name, lift in lifts.items():
        lines = lift(jnp.asarray(points, jnp.float32), fixed_key(cfg["lift_seed"]))
        for rule in ("closest", "uniform"):
            rows.append((scene, lift_name, f"no attack ({rule})", point_recovery_metrics(points, baseline_points(lines, rule)), 0.0))
        t0 = time.perf_counter()
        rec, _ = line2point(lines, cfg["line2point"], progress=True)
        rec = np.asarray(jax.block_until_ready(rec))
        rows.append((scene, lift_name, "Line2Point", point_recovery_metrics(points, rec), time.perf_counter() - t0))
        t0 = time.perf_counter()
        rec = gradient_attack(lines, cfg["gradient"], throw=False).points  # max_steps is its usual stop: the last iterate
        rec = np.asarray(jax.block_until_ready(rec))
        rows.append((scene, lift_name, "gradient", point_recovery_metrics(points, rec), time.perf_counter() - t0))
        extra = 0
        if lift_name == "ray":
            t0 = time.perf_counter()
            rec, _, _ = ray_cloud_attack(lines, progress=True)
            rows.append((scene, lift_name, "ray vote", point_recovery_metrics(points, rec), time.perf_counter() - t0))
            extra = 1
        if lift_name == "paired":
            t0 = time.perf_counter()
            res = two_peak_attack(lines, progress=True)
            dt = time.perf_counter() - t0
            for rule, name in (("random", "TPF (coin per pair)"), ("oracle", "TPF (oracle assignment)")):
                rows.append((scene, lift_name, name, point_recovery_metrics(points, assign_pairs(res, rule, truth=points)), dt))
            extra = 2
        for r in rows[-(4 + extra):]:
            print(r[0], r[1], r[2], {k: round(r[3][k], 3) for k in KEYS}, f"{r[4]:.1f}s", flush=True)
    return rows


def main() -> None:
    cfg = get_config()
    scenes = []
    syn = synthetic_map(cfg)
    scenes.append(("synthetic", syn, f"synthetic street world, {len(syn)} ORB map points (seed 0, {cfg['synthetic_frames']} frames, no objects)"))
    kitti = kitti_map()
    if kitti is not None:
        kit, scale = kitti
        scenes.append(("KITTI seq1", kit, f"KITTI seq1 COLMAP map, {len(kit)} points, scaled to metres (COLMAP's scale is "
                       f"arbitrary: 1 unit = {scale:.3f} m; `colmap_metric_scale`)"))
    rows = []
    for name, pts, _ in scenes:
        rows += evaluate(pts, cfg, name)
    lines = [
        "# Table 3 redone: point recovery from line clouds",
        "",
        "Generated by `python experiments/table3_line2point.py` (lift keys: fixed seed "
        f"{cfg['lift_seed']}, for reproducibility only). Distances in metres; `within_τ` = % of points whose "
        "recovered point (from their own line) lies within τ m of them. `nn_mean` is the source paper's metric "
        "(mean distance from each original point to the nearest recovered point, any point). "
        "No-attack baselines: `closest` = each line's closest point to the origin (the start of the canonical "
        "export), `uniform` = a uniform point of the line inside the box of those closest points. "
        "Line2Point: authors' parameters, 2 refinement rounds, float32. Times on 2 CPU cores shared with other jobs (noisy).",
        "",
    ]
    for name, pts, desc in scenes:
        lines.append(f"- **{name}**: {desc}")
    lines.append("")
    for name, _, _ in scenes:
        for lift in ("random", "paired", "ray", "sphere"):
            got = {r[2]: r[3] for r in rows if r[0] == name and r[1] == lift}
            attack = max((k for k in got if not k.startswith("no attack") and "oracle" not in k),
                         key=lambda k: got[k]["within_0.5"])
            a, b = got[attack], got["no attack (closest)"]
            lines.append(
                f"**{name}, {lift} lift:** the strongest implemented attack ({attack}) recovers **{a['within_0.5']:.1f} %** "
                f"of the points to within 0.5 m of the truth (median error {a['per_point_median']:.2f} m; "
                f"{a['within_1.0']:.1f} % within 1 m); with no attack (closest point of each line) {b['within_0.5']:.1f} %. "
                f"The paper's NN metric reads {a['nn_mean']:.3f} m for the attack vs {b['nn_mean']:.3f} m for no attack.  "
            )
    lines += ["", "Paired lifting: TPF finds both points of a pair's line; which is whose is not in the cloud, so "
              "`TPF (coin per pair)` hands them out at random (what an attacker gets) and `TPF (oracle assignment)` "
              "with the truth (Lee et al.'s swap ratio 0: an upper bound, not an attack; never the 'strongest "
              "implemented attack' above).", "", "Ray clouds: 8 anchors (k-means centres), Line2Point and the gradient attack put their estimates on the "
              "anchors; `ray vote` is the attack made for them (`privslam_jax/attacks/centred.py`). Sphere clouds: "
              "no attack made for them is implemented yet (their lines all meet at the centroid, where the two "
              "attacks put every estimate), so their row is an upper bound on their privacy, not a measure of it."]
    lines += ["", "| map | lift | method | nn_mean | median | mean | within 0.1 | within 0.5 | within 1.0 | chamfer | time (s) |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for scene, lift, method, m, t in rows:
        lines.append(
            f"| {scene} | {lift} | {method} | {m['nn_mean']:.3f} | {m['per_point_median']:.3f} | {m['per_point_mean']:.3f} | "
            f"{m['within_0.1']:.1f} | {m['within_0.5']:.1f} | {m['within_1.0']:.1f} | {m['chamfer']:.3f} | {t:.1f} |"
        )
    out = Path(cfg["out"])
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, "\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
