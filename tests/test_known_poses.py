"""A map triangulated from images with known poses, against the rendered depth of the synthetic world."""

from __future__ import annotations

import numpy as np
import pytest

from privslam_jax.data.synthetic import SynthConfig, make_sequence
from privslam_jax.slam.known_poses import KnownPoseMapConfig, map_from_known_poses


def test_points_lie_on_the_rendered_surfaces_with_their_descriptors_and_viewing_directions():
    """Seen from the first frame, the points have the rendered depth at their pixels: median relative error
    ≤ 10 % and no bias beyond 3 % (the camera only moves forward, 0.8 m per frame, so depth from two views is
    coarse: measured 5.6 % and −1.5 %; wrong poses or a broken triangulation give errors of order 1).
    Viewing directions are unit and point from the centre of the frame that made the point; descriptors are
    ORB's 32 bytes."""
    seq = make_sequence(SynthConfig(num_frames=6, object_density=0.0, seed=5))
    frames = [seq[i] for i in range(len(seq))]
    T_w_c = np.stack([f.T_w_c for f in frames])
    K = np.asarray(seq.camera.K, np.float64)
    cloud = map_from_known_poses([f.background for f in frames], T_w_c, K, KnownPoseMapConfig(n_features=2000))
    X, v = np.asarray(cloud.xyz, np.float64), np.asarray(cloud.normals, np.float64)
    assert len(X) > 300 and cloud.descriptors.shape == (len(X), 32)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-5)
    rays = X[:, None, :] - T_w_c[None, :, :3, 3]
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    assert np.min(np.max(np.sum(rays * v[:, None, :], axis=2), axis=1)) > 1 - 1e-5
    T = np.linalg.inv(T_w_c[0])
    Xc = X @ T[:3, :3].T + T[:3, 3]
    uv = (Xc @ K.T)[:, :2] / Xc[:, 2:3]
    depth = frames[0].background_depth
    inside = (Xc[:, 2] > 0) & np.all((uv >= 0) & (uv <= np.array(depth.shape[::-1]) - 1), axis=1)
    assert inside.mean() > 0.9
    r, c = np.rint(uv[inside, 1]).astype(int), np.rint(uv[inside, 0]).astype(int)
    rel = (Xc[inside, 2] - depth[r, c]) / Xc[inside, 2]
    assert np.median(np.abs(rel)) <= 0.10 and abs(np.median(rel)) <= 0.03, (np.median(np.abs(rel)), np.median(rel))


def test_bad_input_is_refused():
    K = np.array([[100.0, 0, 32], [0, 100, 24], [0, 0, 1]])
    images = [np.zeros((48, 64), np.uint8)] * 2
    with pytest.raises(ValueError, match="one finite 4x4 pose per image"):
        map_from_known_poses(images, np.tile(np.eye(4), (3, 1, 1)), K)
    with pytest.raises(ValueError, match="K must be finite"):
        map_from_known_poses(images, np.tile(np.eye(4), (2, 1, 1)), np.where(K == 100.0, np.nan, K))
    with pytest.raises(ValueError, match="no point passed"):
        map_from_known_poses(images, np.tile(np.eye(4), (2, 1, 1)), K)  # blank images: no features
