"""ICP refinement: real Open3D clouds, degenerate (floor-only) overlap refused, drift guard."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d

from engine.calibration.icp import icp_align, refine_with_icp
from engine.geometry import invert_transform, make_transform, pose_error, so3_exp

RGBD = "rgbd/open3d"


def _log_transform(path: Path) -> np.ndarray:
    lines = path.read_text().split("\n")
    return np.array([[float(x) for x in ln.split()] for ln in lines[1:5]])


def test_real_feature_clouds_icp(shared_data: Path) -> None:
    d = shared_data / RGBD
    src = np.asarray(o3d.io.read_point_cloud(str(d / "Feature_cloud_bin_0.pcd")).points)
    dst = np.asarray(o3d.io.read_point_cloud(str(d / "Feature_cloud_bin_1.pcd")).points)
    # from the initial transform of ICP_init.log: converges (fitness up, RMSE down)
    T_init = _log_transform(d / "ICP_init.log")
    r = icp_align(src, dst, T_init, voxel=None, max_dist=0.05)
    assert r.fitness > r.fitness_before and r.inlier_rmse < r.inlier_rmse_before
    assert 0 < r.inlier_rmse < 0.05
    # the two clouds share a frame already: ICP from there is the reference alignment, and
    # a start 3.7 cm / 2.7° away converges back to it
    ref = icp_align(src, dst, np.eye(4), voxel=None, max_dist=0.05)
    assert ref.fitness > 0.7 and ref.inlier_rmse < 0.03
    P = make_transform(so3_exp(np.radians([1.5, -1.0, 2.0])), [0.03, -0.02, 0.01])
    r2 = icp_align(src, dst, P, voxel=None, max_dist=0.08)
    assert r2.fitness > r2.fitness_before + 0.2
    dt, dr = pose_error(r2.T, ref.T)
    assert dt < 0.01 and np.degrees(dr) < 0.5


def _room(rng: np.random.Generator, walls: bool) -> np.ndarray:
    """World points of a floor (and optionally two walls and a box) on a 1 cm grid."""
    g = np.arange(0, 3, 0.02)
    X, Y = np.meshgrid(g, g)
    pts = [np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])]
    if walls:
        h = np.arange(0, 1.5, 0.02)
        A, H = np.meshgrid(g, h)
        pts.append(np.column_stack([A.ravel(), np.zeros(A.size), H.ravel()]))
        pts.append(np.column_stack([np.zeros(A.size), A.ravel(), H.ravel()]))
        b = np.arange(0, 0.4, 0.02)
        B1, B2 = np.meshgrid(b, b)
        pts.append(np.column_stack([1 + B1.ravel(), 1 + B2.ravel(), np.full(B1.size, 0.4)]))
        pts.append(np.column_stack([1 + B1.ravel(), np.full(B1.size, 1.0), B2.ravel()]))
    p = np.concatenate(pts)
    return p + rng.normal(0, 0.002, p.shape)


def test_refine_accepts_structured_overlap_refuses_floor_only() -> None:
    rng = np.random.default_rng(0)
    T_a = make_transform(so3_exp([0.2, -0.1, 0.3]), [1.0, 2.0, 1.2])
    T_b = make_transform(so3_exp([-0.1, 0.2, -0.4]), [2.5, 0.5, 1.0])
    err = make_transform(so3_exp(np.radians([0.3, -0.2, 0.4])), [0.008, -0.006, 0.004])
    for walls in (True, False):
        world = _room(rng, walls)
        clouds = {"A": (invert_transform(T_a)[:3, :3] @ world.T).T + invert_transform(T_a)[:3, 3],
                  "B": (invert_transform(T_b)[:3, :3] @ world.T).T + invert_transform(T_b)[:3, 3]}
        poses, reps = refine_with_icp({"A": T_a, "B": err @ T_b}, clouds, voxel=0.03)
        rep_b = next(r for r in reps if r.sensor_id == "B")
        assert rep_b.result is not None
        if walls:
            assert any(r.accepted for r in reps), [r.reason for r in reps]
            fixed = poses["B"] @ invert_transform(poses["A"])  # relative pose is what ICP sees
            true = T_b @ invert_transform(T_a)
            before = pose_error(err @ T_b @ invert_transform(T_a), true)[0]
            assert pose_error(fixed, true)[0] < 0.5 * before
        else:
            assert not any(r.accepted for r in reps)
            assert all("degenerate" in r.reason for r in reps), [r.reason for r in reps]
            assert np.allclose(poses["B"], err @ T_b)


def test_refine_refuses_large_drift() -> None:
    rng = np.random.default_rng(1)
    world = _room(rng, True)
    T = make_transform(np.eye(3), [0.0, 0.0, 0.0])
    err = make_transform(so3_exp(np.radians([0.0, 0.0, 3.0])), [0.05, 0.0, 0.0])
    poses, reps = refine_with_icp({"A": T, "B": err}, {"A": world, "B": world}, voxel=0.03,
                                  max_correction_m=0.02)
    assert not any(r.accepted for r in reps)
    assert np.allclose(poses["B"], err)
    assert any("away from the marker solution" in r.reason or "did not improve" in r.reason
               for r in reps)


def test_static_cloud_drops_flying_pixels_at_depth_edges() -> None:
    """ICP's static cloud of a box 1.5 m in front of a wall at 3 m, whose rim pixels read
    in between in every frame (a time-of-flight pixel across the edge mixes both
    surfaces, and the temporal median keeps what every frame shows): the points floating
    in the gap are dropped, the box and the wall kept."""
    from engine.calibration.corners3d import SensorFrames
    from engine.calibration.pipeline import static_cloud

    K = np.array([[250.0, 0, 63.5], [0, 250.0, 47.5], [0, 0, 1]])
    depth = np.full((96, 128), 3000, np.uint16)
    depth[30:66, 40:88] = 1500
    # the same mixed readings in every frame: the median cannot remove them
    rng = np.random.default_rng(3)
    for rows, cols in ((slice(30, 66), [38, 39, 88, 89]), ([28, 29, 66, 67], slice(40, 88))):
        depth[rows, cols] = rng.uniform(1600, 2900, depth[rows, cols].shape).astype(np.uint16)
    frames = [depth] * 5
    colour = np.zeros((96, 128, 3), np.uint8)
    pts = static_cloud(SensorFrames("S1", [colour] * 5, frames, K, K))
    z = pts[:, 2]
    # within ≈ 17 cm behind the rim a point is not told from the rim's own slope (two
    # pixels 1.2 cm apart at 1.5 m, 4°); beyond, nothing floats
    floating = (z > 1.7) & (z < 2.95)
    assert not np.any(floating), np.sort(z[floating])
    assert np.count_nonzero((depth[::2, ::2] > 1700) & (depth[::2, ::2] < 2950)) > 40
    box = np.count_nonzero(np.abs(z - 1.5) < 1e-6)
    wall = np.count_nonzero(np.abs(z - 3.0) < 1e-6)
    assert box == 18 * 24  # every other pixel of the 36 × 48 box, its rim included
    assert wall > 0.9 * (48 * 64 - box - 2 * (18 + 24) - 4)
