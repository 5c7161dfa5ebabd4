"""KSCC universal frame (seed 004), stillness collection and motion comparison with DTW."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from engine.compare import common_joints, compare_motions, dtw, frame_costs, joint_distances
from engine.errors import InputError, InsufficientDataError
from engine.geometry import make_transform, quat_from_axis_angle, quat_to_matrix
from engine.kscc import (
    KsccCalibrator,
    facing_left,
    find_still_window,
    kscc_calibrate,
    level_transform,
    load_kscc,
    save_kscc,
)
from engine.skeleton import (
    AZURE_KINECT,
    JOINT_SETS,
    KINECT_V1,
    KINECT_V2,
    JointSet,
    SkeletonSeries,
    TrackingState,
)

FPS = 30.0

#: Standing pose by role in a body frame: +X forward, +Y the body's left, +Z up (m).
_ROLE_POSE = {
    "pelvis": (0.0, 0.0, 0.95), "spine_mid": (0.0, 0.0, 1.20), "spine_top": (0.0, 0.0, 1.42),
    "neck": (0.0, 0.0, 1.50), "head": (0.02, 0.0, 1.65),
    "shoulder_left": (0.0, 0.18, 1.43), "elbow_left": (0.0, 0.22, 1.15),
    "wrist_left": (0.03, 0.23, 0.90), "hand_left": (0.04, 0.23, 0.83),
    "hip_left": (0.0, 0.09, 0.90), "knee_left": (0.02, 0.10, 0.50),
    "ankle_left": (0.0, 0.10, 0.08), "foot_left": (0.12, 0.11, 0.04),
}


def body_pose(js: JointSet, seed: int = 0) -> np.ndarray:
    """A standing skeleton of ``js`` in the body frame (extra joints placed near parents)."""
    rng = np.random.default_rng(seed)
    pose: dict[str, np.ndarray] = {}
    for role, xyz in _ROLE_POSE.items():
        p = np.array(xyz)
        if role.endswith("_left"):
            pose[js.roles[role]] = p
            q = p.copy()
            q[1] = -q[1]
            pose[js.roles[role.replace("_left", "_right")]] = q
        else:
            pose[js.roles[role]] = p
    out = np.empty((len(js.joints), 3))
    for i, name in enumerate(js.joints):
        if name in pose:
            out[i] = pose[name]
        else:  # e.g. HandTip, Thumb, clavicles, eyes: near the parent joint
            parent = js.parents[name]
            assert parent is not None
            base = pose.get(parent, np.array([0.0, 0.0, 1.5]))
            out[i] = base + rng.normal(0, 0.04, 3)
            pose[name] = out[i]
    return out


def standing_frames(js: JointSet, n: int = 150, sway_m: float = 0.003, noise_m: float = 0.0,
                    seed: int = 0) -> np.ndarray:
    """(n, J, 3) body-frame frames of a person standing still with slow sway."""
    rng = np.random.default_rng(seed)
    base = body_pose(js)
    t = np.arange(n) / FPS
    sway = sway_m * np.stack([np.sin(2 * np.pi * 0.3 * t), np.cos(2 * np.pi * 0.2 * t),
                              np.zeros(n)], 1)
    return base[None] + sway[:, None] * (base[None, :, 2:3] / 1.7) + rng.normal(
        0, noise_m, (n, len(js.joints), 3))


def series(P: np.ndarray, js: JointSet, t0: float = 0.0) -> SkeletonSeries:
    n = len(P)
    return SkeletonSeries(t0 + np.arange(n) / FPS, P,
                          np.full((n, len(js.joints)), TrackingState.TRACKED, np.uint8), js)


def place(P: np.ndarray, yaw_rad: float, t: np.ndarray) -> np.ndarray:
    """Rotate body-frame points about Z and translate (world = Z up)."""
    R = quat_to_matrix(quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), yaw_rad))
    return P @ R.T + t


# ----------------------------------------------------------------- exact KSCC


@pytest.mark.parametrize("js", [KINECT_V1, KINECT_V2, AZURE_KINECT], ids=lambda j: j.name)
def test_rotated_translated_copies_meet_in_universal_frame(js: JointSet) -> None:
    body = standing_frames(js, n=200)
    ref = KsccCalibrator(frame="world").fit(series(body, js))
    U_ref = ref.transform(series(body, js)).positions
    # the universal frame is the body frame re-centred: facing +X, left +Y, up +Z
    assert abs(ref.heading_) < 1e-9
    rng = np.random.default_rng(1)
    for _ in range(6):
        yaw = rng.uniform(-np.pi, np.pi)
        t = np.r_[rng.uniform(-1e3, 1e3, 2), rng.uniform(-2, 2)]  # far from the origin too
        moved = place(body, yaw, t)
        cal = kscc_calibrate(series(moved, js), frame="world")
        U = cal.transform(series(moved, js)).positions
        assert np.max(np.abs(U - U_ref)) < 1e-3  # 1 mm
        dyaw = np.degrees(np.angle(np.exp(1j * (cal.heading_ - yaw))))
        assert abs(dyaw) < 0.1
        assert np.allclose(cal.centre_, place(ref.centre_, yaw, t), atol=1e-6)
        assert np.allclose(cal.T_universal_input_ @ np.r_[cal.centre_, 1.0], [0, 0, 0, 1],
                           atol=1e-9)


@pytest.mark.parametrize("js", [KINECT_V1, KINECT_V2, AZURE_KINECT], ids=lambda j: j.name)
def test_sensor_frames_and_paper_angle(js: JointSet) -> None:
    """A user in front of a level sensor, turned by φ, seen in Kinect SDK / OpenCV frames."""
    body = standing_frames(js, n=160)
    ref = KsccCalibrator(frame="world").fit(series(body, js))
    U_ref = ref.transform(series(body, js)).positions
    M_kinect = level_transform("kinect")[0][:3, :3]  # input → level
    M_cv = level_transform("opencv")[0][:3, :3]
    for phi_deg in (-80.0, -35.0, 0.0, 12.5, 55.0, 85.0):
        # level frame of the sensor: X forward, Y its left, Z up; sensor 1 m above the floor
        L = place(body, np.pi + np.radians(phi_deg), np.array([2.7, -0.4, -1.0]))
        for frame, M in (("kinect", M_kinect), ("opencv", M_cv)):
            P_in = L @ M  # = (M.T @ L.T).T, level → input
            cal = KsccCalibrator(frame=frame).fit(series(P_in, js))
            U = cal.transform(series(P_in, js)).positions
            assert np.max(np.abs(U - U_ref)) < 1e-3
            # facing the sensor = 0; turned CCW by φ brings the right shoulder nearer: θ = −φ
            assert cal.initial_angle_deg_ == pytest.approx(-phi_deg, abs=0.1)
        # the paper's formula on Kinect SDK coordinates, for |φ| < 90°
        P_k = L @ M_kinect
        ls = P_k[:, js.role_index("shoulder_left")].mean(0)
        rs = P_k[:, js.role_index("shoulder_right")].mean(0)
        theta_paper = np.degrees(np.arctan((rs[2] - ls[2]) / (rs[0] - ls[0])))
        cal_k = KsccCalibrator(frame="kinect").fit(series(P_k, js))
        assert cal_k.initial_angle_deg_ == pytest.approx(theta_paper, abs=1e-6)


def test_tilted_sensor_pose_and_up_vector_agree() -> None:
    js = KINECT_V2
    body = standing_frames(js, n=150)
    U_ref = KsccCalibrator(frame="world").fit(series(body, js)).transform(
        series(body, js)).positions
    # a sensor pitched 15° down, yawed 30°, at (4, 2, 1.2): OpenCV camera frame
    from engine.coverage import sensor_pose

    T_ws = sensor_pose((4.0, 2.0, 1.2), 30.0, -15.0)
    W = place(body, np.radians(200.0), np.array([6.3, 3.0, 0.0]))
    T_sw = np.linalg.inv(T_ws)
    P_cam = W @ T_sw[:3, :3].T + T_sw[:3, 3]
    by_pose = KsccCalibrator(T_world_sensor=T_ws).fit(series(P_cam, js))
    up_cam = T_sw[:3, :3] @ np.array([0.0, 0.0, 1.0])
    by_up = KsccCalibrator(frame=up_cam).fit(series(P_cam, js))
    for cal in (by_pose, by_up):
        U = cal.transform(series(P_cam, js)).positions
        assert np.max(np.abs(U - U_ref)) < 1e-3
        assert np.allclose(cal.centre_, P_cam.reshape(-1, 3).mean(0), atol=0.02)


def test_centre_is_paper_mean_and_role_centre_agrees_across_joint_sets() -> None:
    P = standing_frames(KINECT_V2, n=130)
    cal = KsccCalibrator(frame="world").fit(series(P, KINECT_V2))
    assert np.allclose(cal.centre_, P[cal.still_indices_].mean(axis=(0, 1)), atol=1e-12)
    centres = []
    for js in (KINECT_V1, KINECT_V2, AZURE_KINECT):
        c = KsccCalibrator(frame="world", centre="roles").fit(
            series(standing_frames(js, n=130), js))
        centres.append(c.centre_)
    # role joints sit at the same body positions in every set (v1 maps neck & spine_top
    # to one joint, so it differs by a few mm only)
    assert np.max(np.abs(np.array(centres) - centres[1])) < 0.01


# ---------------------------------------------------------------- stillness


def test_noisy_still_user_is_collected_and_streaming_reports_progress() -> None:
    js = KINECT_V2
    walk_in = np.linspace(0, 1.5, 45)[:, None, None] * np.array([1.0, 0.0, 0.0])
    still = standing_frames(js, n=160, noise_m=0.005, seed=3)
    P = np.concatenate([body_pose(js)[None] - np.array([1.5, 0, 0]) + walk_in, still])
    cal = KsccCalibrator(frame="world")
    states = []
    for t, p in zip(np.arange(len(P)) / FPS, P, strict=True):
        pr = cal.update(t, p)
        states.append(pr.state)
        if pr.state == "done":
            break
    assert states[0] == "waiting" and "collecting" in states and states[-1] == "done"
    assert "moved" not in states[60:]  # 5 mm jitter is not movement
    assert cal.still_indices_[0] >= 45 and len(cal.still_indices_) == 120
    assert np.allclose(cal.centre_, still[:, :, :].mean(axis=(0, 1)), atol=0.01)
    with pytest.raises(InputError, match="increasing"):
        cal.update(0.0, P[0])


def test_user_who_moves_during_collection_restarts() -> None:
    js = KINECT_V2
    a = standing_frames(js, n=80, seed=1)
    # takes a 40 cm step to the side over 0.5 s, then stands still long enough
    step = np.linspace(0, 0.4, 15)[:, None, None] * np.array([0.0, 1.0, 0.0])
    b = body_pose(js)[None] + step
    c = standing_frames(js, n=130, seed=2) + np.array([0.0, 0.4, 0.0])
    P = np.concatenate([a, b, c])
    cal = KsccCalibrator(frame="world")
    seen = [cal.update(t, p) for t, p in zip(np.arange(len(P)) / FPS, P, strict=True)]
    assert any(s.state == "moved" for s in seen)
    moved_at = next(i for i, s in enumerate(seen) if s.state == "moved")
    assert 80 <= moved_at <= 90 and seen[moved_at].message.startswith("moved — restarting")
    assert seen[-1].state == "done"
    assert cal.centre_[1] == pytest.approx(c.mean(axis=(0, 1))[1], abs=0.01)
    fitted = KsccCalibrator(frame="world").fit(series(P, js))
    assert fitted.still_indices_[0] >= 95


def test_bad_input_messages() -> None:
    js = KINECT_V2
    with pytest.raises(InsufficientDataError, match="120 still frames"):
        kscc_calibrate(series(standing_frames(js, n=100), js), frame="world")
    # shoulder NaN everywhere
    P = standing_frames(js, n=150)
    P[:, js.index("ShoulderLeft")] = np.nan
    with pytest.raises(InputError, match="ShoulderLeft is missing"):
        kscc_calibrate(series(P, js), frame="world")
    # Azure: right shoulder NOT_TRACKED (position present but untrustworthy)
    az = AZURE_KINECT
    s = series(standing_frames(az, n=150), az)
    s.states[:, az.index("SHOULDER_RIGHT")] = TrackingState.NOT_TRACKED
    with pytest.raises(InputError, match="SHOULDER_RIGHT"):
        kscc_calibrate(s, frame="world")
    # a user who keeps walking
    walk = body_pose(js)[None] + (np.arange(300) / FPS * 0.8)[:, None, None] * np.array(
        [1.0, 0.0, 0.0])
    with pytest.raises(InsufficientDataError, match="never stood still"):
        kscc_calibrate(series(walk, js), frame="world")
    # shoulders lost every 60 frames: never 120 consecutive good frames
    P = standing_frames(js, n=400)
    P[::60, js.index("ShoulderRight")] = np.nan
    with pytest.raises(InsufficientDataError, match="restarted"):
        find_still_window(series(P, js), frame="world")
    with pytest.raises(InputError, match="not calibrated"):
        KsccCalibrator().transform_points(np.zeros(3))
    with pytest.raises(InputError, match="unknown skeleton frame"):
        KsccCalibrator(frame="sideways")
    cal = kscc_calibrate(series(standing_frames(js), js), frame="world")
    with pytest.raises(InputError, match="calibrated on kinect_v2"):
        cal.transform(series(standing_frames(KINECT_V1), KINECT_V1))


def test_update_infers_joint_set_and_rejects_unknown_sizes() -> None:
    cal = KsccCalibrator(frame="world", n_frames=10)
    P = standing_frames(KINECT_V1, n=30)
    for i, p in enumerate(P):
        pr = cal.update(i / FPS, p, states=np.full(20, TrackingState.TRACKED))
    assert pr.state == "done" and cal.joint_set_ is KINECT_V1
    with pytest.raises(InputError, match="21-joint"):
        KsccCalibrator().update(0.0, np.zeros((21, 3)))
    assert set(JOINT_SETS) == {"kinect_v1", "kinect_v2", "azure_kinect"}


# -------------------------------------------------------------- comparison


def _motion(js: JointSet, phase: np.ndarray) -> np.ndarray:
    """An arm-raising and squatting motion driven by ``phase`` in [0, 1]."""
    base = body_pose(js)
    P = np.repeat(base[None], len(phase), 0)
    s = np.sin(np.pi * phase)[:, None]
    for side, sign in (("left", 1.0), ("right", -1.0)):
        sh = base[js.role_index(f"shoulder_{side}")]
        a = sign * np.pi * 0.8 * s[:, 0]  # raise the arms sideways: rotation about X
        ca, sa = np.cos(a)[:, None], np.sin(a)[:, None]
        for role in (f"elbow_{side}", f"wrist_{side}", f"hand_{side}"):
            i = js.role_index(role)
            r = base[i] - sh
            P[:, i] = sh + np.column_stack([np.full(len(phase), r[0]),
                                            r[1] * ca[:, 0] - r[2] * sa[:, 0],
                                            r[1] * sa[:, 0] + r[2] * ca[:, 0]])
    P[..., 2] -= 0.15 * s  # squat
    return P


def test_dtw_recovers_known_time_warp() -> None:
    js = KINECT_V2
    n = 90
    u = np.linspace(0, 1, n)
    warp = u ** 1.8  # the second performer starts slowly and finishes fast
    a = _motion(js, u)
    b = _motion(js, warp)
    res = dtw(frame_costs(a, b), band=0.3)
    # for each frame i of b the matched frame of a should be warp(i)·(n−1)
    matched = np.zeros(n)
    for i, j in res.path:
        matched[j] = i
    err = np.abs(matched - warp * (n - 1))
    assert np.median(err) <= 1.0 and err.max() <= 3.0
    assert res.path[0].tolist() == [0, 0] and res.path[-1].tolist() == [n - 1, n - 1]
    # a band too narrow for the warp costs more than a wide one
    assert dtw(frame_costs(a, b), band=2).total_cost > res.total_cost


def test_compare_motions_similarity_and_mismatched_sets() -> None:
    js = KINECT_V2
    n = 80
    u = np.linspace(0, 1, n)
    a = series(_motion(js, u), js)
    b_slow = series(_motion(js, np.linspace(0, 1, 130)), js)
    same = compare_motions(a, b_slow)
    assert same.similarity > 95.0 and same.mean_distance_m < 0.01
    # a 5 cm offset of every joint: similarity = 100·exp(−0.05/0.10) ≈ 60.7
    shifted = series(_motion(js, u) + np.array([0.0, 0.05, 0.0]), js)
    r = compare_motions(a, shifted)
    assert r.mean_distance_m == pytest.approx(0.05, abs=1e-3)
    assert r.similarity == pytest.approx(100 * np.exp(-0.5), abs=0.5)
    assert r.per_joint_mean_m.shape == (25,)
    # different joint sets: clear error, or mapped by role on request
    v1 = series(_motion(KINECT_V1, u), KINECT_V1)
    with pytest.raises(InputError, match="different joint sets"):
        compare_motions(a, v1)
    mapped = compare_motions(a, v1, by_role=True)
    assert len(mapped.joints) == len(common_joints(KINECT_V2, KINECT_V1, by_role=True)[0])
    assert mapped.mean_distance_m < 0.01


def test_kscc_then_compare_two_sites() -> None:
    """Two users at two sites, standing anywhere, facing anyway: same motion → same data."""
    js = KINECT_V2
    still = standing_frames(js, n=130)
    u = np.linspace(0, 1, 90)
    mot = _motion(js, u)
    site_a = np.concatenate([still, mot])
    site_b = np.concatenate([still, _motion(js, np.linspace(0, 1, 120))])
    A = place(site_a, np.radians(40), np.array([3.0, -1.0, 0.0]))
    B = place(site_b, np.radians(-120), np.array([-7.0, 4.0, 0.0]))
    ca = kscc_calibrate(series(A, js), frame="world")
    cb = kscc_calibrate(series(B, js), frame="world")
    ua = ca.transform(series(A[130:], js, t0=130 / FPS))
    ub = cb.transform(series(B[130:], js, t0=130 / FPS))
    assert compare_motions(ua, ub).similarity > 95.0
    raw = compare_motions(series(A[130:], js), series(B[130:], js))
    assert raw.similarity < 1.0  # without KSCC the sites are metres apart


def test_transform_helpers_consistent() -> None:
    js = KINECT_V2
    P = standing_frames(js, n=130)
    cal = kscc_calibrate(series(P, js), frame="world")
    T = cal.T_universal_input_
    assert np.allclose(cal.transform_points(P), P @ T[:3, :3].T + T[:3, 3])
    assert np.allclose(quat_to_matrix(cal.quaternion_), T[:3, :3])
    assert np.allclose(make_transform(T[:3, :3], T[:3, 3]), T)


def test_trunk_facing_survives_a_hidden_far_shoulder() -> None:
    js = KINECT_V2
    body = standing_frames(js, n=150)
    body[:, js.index("ShoulderRight")] = np.nan  # hidden behind the body
    ref = KsccCalibrator(frame="world", facing="trunk").fit(series(body, js))
    U_ref = ref.transform(series(body, js)).positions
    with pytest.raises(InputError, match="ShoulderRight is missing"):
        kscc_calibrate(series(body, js), frame="world")
    for yaw in (-2.5, 0.7, 3.0):
        moved = place(body, yaw, np.array([5.0, -3.0, 0.2]))
        cal = KsccCalibrator(frame="world", facing="trunk").fit(series(moved, js))
        U = cal.transform(series(moved, js)).positions
        assert np.nanmax(np.abs(U - U_ref)) < 1e-3
        assert abs(np.degrees(np.angle(np.exp(1j * (cal.heading_ - yaw))))) < 0.1
    # half lines only (right shoulder and right hip hidden): still the right heading
    pose = body_pose(js)
    pose[[js.index("ShoulderRight"), js.index("HipRight")]] = np.nan
    left = facing_left(place(pose, 1.0, np.zeros(3)), js, "trunk")
    assert left is not None
    assert np.degrees(np.arctan2(left[1], left[0])) == pytest.approx(90.0 + np.degrees(1.0),
                                                                     abs=0.1)
    assert facing_left(pose, js, "shoulders") is None


def test_turning_on_the_spot_restarts_collection() -> None:
    js = KINECT_V2
    base = body_pose(js)
    # still for 60 frames, then a slow 60° turn at 15°/s (the centre hardly moves)
    yaw = np.r_[np.zeros(60), np.radians(np.arange(1, 121) * 0.5)]
    P = np.array([place(base, a, np.zeros(3)) for a in yaw])
    cal = KsccCalibrator(frame="world")
    seen = [cal.update(t, p) for t, p in zip(np.arange(len(P)) / FPS, P, strict=True)]
    assert any(s.state == "moved" and s.message.startswith("turned") for s in seen[60:])
    assert not any(s.state == "done" for s in seen)
    assert all(s.state != "moved" for s in seen[:60])


def test_calibration_round_trips_through_json(tmp_path: Path) -> None:
    js = AZURE_KINECT
    P = place(standing_frames(js, n=130), 0.4, np.array([1.0, 2.0, 0.0]))
    M_cv = level_transform("opencv")[0][:3, :3]
    cal = KsccCalibrator(frame="opencv", centre="roles").fit(series(P @ M_cv, js))
    save_kscc(tmp_path / "k.json", cal)
    back = load_kscc(tmp_path / "k.json")
    x = np.random.default_rng(0).normal(size=(10, 3))
    assert np.allclose(back.transform_points(x), cal.transform_points(x))
    assert back.joint_set_ is js and back.initial_angle_ == pytest.approx(cal.initial_angle_)
    (tmp_path / "bad.json").write_text('{"kind": "other"}')
    with pytest.raises(InputError, match="not a KSCC"):
        load_kscc(tmp_path / "bad.json")
    (tmp_path / "worse.json").write_text("[1, 2")
    with pytest.raises(InputError, match="cannot read"):
        load_kscc(tmp_path / "worse.json")


def test_joint_distances_pair_frames_by_time() -> None:
    js = KINECT_V2
    P = standing_frames(js, n=40)
    a = series(P, js)
    # the second site's clock is 10 ms late, its frames 2 cm to the left, one frame lost
    Q = P + np.array([0.0, 0.02, 0.0])
    b = SkeletonSeries(np.delete(np.arange(40) / FPS + 0.010, 20), np.delete(Q, 20, 0),
                       np.full((39, 25), TrackingState.TRACKED, np.uint8), js)
    t, names, d = joint_distances(a, b, max_gap_s=0.02)
    assert names == list(js.joints) and d.shape == (40, 25) and np.array_equal(t, a.times)
    good = np.asarray(np.isfinite(d).all(axis=1))
    assert good.sum() == 39 and not good[20]  # the lost frame's neighbours are > 20 ms away
    assert np.allclose(d[good], 0.02, atol=2e-3)
    with pytest.raises(InputError, match="different joint sets"):
        joint_distances(a, series(standing_frames(AZURE_KINECT, n=5), AZURE_KINECT))
    with pytest.raises(InputError, match="too large"):
        dtw(np.zeros((6000, 6000), dtype=np.float32), band=0.1)


def test_millimetre_skeletons_are_rejected() -> None:
    js = AZURE_KINECT
    P_mm = 1000.0 * standing_frames(js, n=150)
    with pytest.raises(InputError, match="millimetres"):
        kscc_calibrate(series(P_mm, js), frame="opencv")
    with pytest.raises(InputError, match="millimetres"):
        compare_motions(series(P_mm[:20], js), series(P_mm[:20], js))
    cal = kscc_calibrate(series(P_mm / 1000.0, js), frame="world")  # metres are fine
    assert cal.joint_set_ is js


def test_one_wild_joint_is_not_a_unit_error() -> None:
    js = KINECT_V2
    P = standing_frames(js, n=150)
    P[50, js.index("HandLeft")] += np.array([0.0, 6.0, 0.0])  # a fitting failure
    cal = kscc_calibrate(series(P, js), frame="world")
    assert cal.joint_set_ is js


def test_arms_facing_pools_the_body_plane_and_ignores_a_raised_arm() -> None:
    """The default facing sums the shoulder, elbow, wrist and hand lines (the paper's
    body-plane assumption): exact on a clean pose, blind to an arm held forward, and
    less noisy than the shoulder line alone when every joint has its own error."""
    for js in (KINECT_V1, KINECT_V2, AZURE_KINECT):
        pose = place(body_pose(js), 0.8, np.array([2.0, 1.0, 0.0]))
        for mode in ("arms", "shoulders"):
            left = facing_left(pose, js, mode)  # type: ignore[arg-type]
            assert left is not None
            assert np.degrees(np.arctan2(left[1], left[0])) == pytest.approx(
                90.0 + np.degrees(0.8), abs=1e-6)
    js = KINECT_V2
    pose = body_pose(js)
    for j in ("ElbowRight", "WristRight", "HandRight"):  # right forearm held forward
        pose[js.index(j)] += np.array([0.35, 0.10, 0.3])
    left = facing_left(pose, js, "arms")
    assert left is not None and abs(np.degrees(np.arctan2(left[1], left[0])) - 90.0) < 1e-6
    # 4 s still with a slowly varying 2 cm error per joint: heading error over 40 users
    errs: dict[str, list[float]] = {"arms": [], "shoulders": []}
    for seed in range(40):
        rng = np.random.default_rng(seed)
        n = 150
        slow = np.cumsum(rng.normal(0, 1, (n, len(js.joints), 3)), axis=0)
        slow = 0.02 * (slow - slow.mean(0)) / slow.std(0)
        P = standing_frames(js, n) + slow
        for mode in errs:
            cal = KsccCalibrator(frame="world", facing=mode).fit(  # type: ignore[arg-type]
                series(P, js))
            errs[mode].append(np.degrees(cal.heading_))
    sd = {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in errs.items()}
    assert sd["arms"] < 0.7 * sd["shoulders"], sd
    assert KsccCalibrator().facing == "arms"
