"""ICP wired into the pipeline, observations that are not their marker's square, and the
bumped-tripod check by re-detection in freshly rendered frames."""

from __future__ import annotations

import re

import numpy as np
import pytest

from engine.calibration.moved import check_frames
from engine.calibration.pipeline import CalibrationResult, apply_icp, calibrate, calibrate_frames
from engine.calibration.simcapture import render_sensor_frames
from engine.errors import CalibrationError
from engine.geometry import invert_transform, make_transform, pose_error, so3_exp
from engine.sim.rig import default_avenue_rig
from tests.engine.calibration.test_graph_pipeline import _sizes, _synthetic_obs
from tests.engine.calibration.test_icp import _room


def _truth() -> CalibrationResult:
    """A calibration equal to the simulator's truth (what a perfect run would save)."""
    r = default_avenue_rig(0)
    return CalibrationResult(
        T_world_sensor={s.id: s.T_world_sensor.copy() for s in r.sensors},
        T_world_sensor_chained={}, T_world_marker={m.id: m.T_world_marker for m in r.markers},
        marker_sizes=_sizes(r), sensor_residual_m={}, edges=[], observations=[], version=3)


def test_calibrate_frames_runs_icp_and_reports_it() -> None:
    rig = default_avenue_rig(0)
    rng = np.random.default_rng(2)
    frames = [render_sensor_frames(rig.sensor(s), rig, 4, rng) for s in ("S1", "S2")]
    res = calibrate_frames(frames, _sizes(rig))
    reports = {r["sensor"]: r for r in res.meta["icp"]}
    assert sorted(reports) == ["S1", "S2"]
    for sid, r in reports.items():
        assert "fitness" in r and "inlier_rmse_mm" in r, r  # an ICP run with its numbers
        assert r["reason"]
        if not r["accepted"]:  # refused: the final pose is the joint optimisation's
            assert np.allclose(res.T_world_sensor[sid], res.T_world_sensor_joint[sid])
        dt, dr = pose_error(res.T_world_sensor[sid], rig.sensor(sid).T_world_sensor)
        assert dt < 0.01 and np.degrees(dr) < 0.5
    # no ICP: the joint optimisation is final
    res2 = calibrate_frames(frames, _sizes(rig), icp=False)
    assert "icp" not in res2.meta and res2.T_world_sensor_joint == {}


def test_apply_icp_keeps_an_improvement_and_the_joint_pose() -> None:
    rng = np.random.default_rng(0)
    world = _room(rng, True)
    T_a = make_transform(so3_exp([0.2, -0.1, 0.3]), [1.0, 2.0, 1.2])
    T_b = make_transform(so3_exp([-0.1, 0.2, -0.4]), [2.5, 0.5, 1.0])
    err = make_transform(so3_exp(np.radians([0.3, -0.2, 0.4])), [0.008, -0.006, 0.004])
    clouds = {k: (invert_transform(T)[:3, :3] @ world.T).T + invert_transform(T)[:3, 3]
              for k, T in (("A", T_a), ("B", T_b))}
    res = CalibrationResult({"A": T_a, "B": err @ T_b}, {}, {}, {}, {}, [], [])
    apply_icp(res, {**clouds, "C": np.zeros((0, 3))}, voxel=0.03)
    assert np.allclose(res.T_world_sensor_joint["B"], err @ T_b)
    assert any(r["accepted"] for r in res.meta["icp"]), res.meta["icp"]
    rel = res.T_world_sensor["B"] @ invert_transform(res.T_world_sensor["A"])
    before = pose_error(err @ T_b @ invert_transform(T_a), T_b @ invert_transform(T_a))[0]
    assert pose_error(rel, T_b @ invert_transform(T_a))[0] < 0.5 * before


def test_wrong_marker_size_is_named() -> None:
    rig = default_avenue_rig(0)
    with pytest.raises(CalibrationError, match=r"measures 40\.0 cm in depth but its edge "
                       r"length was given as 20\.0 cm"):
        calibrate(_synthetic_obs(rig, None), 0.20)
    # the whole form is wrong: the message leads with what to do, not with moving markers
    with pytest.raises(CalibrationError, match=r"^The markers measure 40 cm in the depth "
                       r"images \(\d+ of \d+ views\) but 20 cm was entered: enter the "
                       r"black square's edge length") as exc:
        calibrate(_synthetic_obs(rig, None), 0.20)
    assert "Place a marker" not in str(exc.value)


def test_one_odd_marker_size_keeps_the_room_message() -> None:
    """One marker printed at another scale is that marker's problem, named per view."""
    rig = default_avenue_rig(0)
    sizes = _sizes(rig)
    sizes[1] = 0.20  # only the origin marker's size is wrong
    with pytest.raises(CalibrationError) as exc:
        calibrate(_synthetic_obs(rig, None), sizes)
    msg = str(exc.value)
    assert re.match(r"sensors S\d+(, S\d+)+ have no chain", msg), msg
    assert "marker 1 measures 40.0 cm in depth" in msg


def test_observation_off_its_square_is_rejected() -> None:
    rig = default_avenue_rig(0)
    obs = _synthetic_obs(rig, None)
    bad = next(o for o in obs if (o.sensor_id, o.marker_id) == ("S3", 4))
    bad.corners = bad.corners.copy()
    bad.corners[0, 2] += 0.05  # a foot on one corner
    res = calibrate(obs, _sizes(rig))
    assert not bad.accepted and "miss its square" in bad.reason
    assert ("S3", 4) not in {(e.sensor_id, e.marker_id) for e in res.edges}
    assert pose_error(res.T_world_sensor["S3"], rig.sensor("S3").T_world_sensor)[0] < 1e-6


def test_bumped_tripod_found_by_redetection() -> None:
    rig = default_avenue_rig(0)
    cal = _truth()
    rng = np.random.default_rng(4)
    s5 = rig.sensor("S5")
    s5.T_world_sensor = s5.T_world_sensor @ make_transform(so3_exp(np.radians([0, 0.8, 0])),
                                                           [0.0, 0.0, 0.0])
    s1 = rig.sensor("S1")
    s1.T_world_sensor = s1.T_world_sensor @ make_transform(np.eye(3), [0.0, 0.0, 0.004])
    frames = [render_sensor_frames(rig.sensor(s), rig, 4, rng) for s in ("S1", "S5")]
    checks = {c.sensor_id: c for c in check_frames(frames, cal)}
    assert checks["S5"].status == "moved" and "recalibrate" in checks["S5"].reason
    assert checks["S5"].rotated_deg == pytest.approx(0.8, abs=0.15)
    assert checks["S1"].status == "ok"  # 4 mm is within the 1 cm tolerance
    assert checks["S1"].moved_m == pytest.approx(0.004, abs=0.002)
    assert checks["S1"].markers == [1, 3]
    # a sensor unknown to the calibration, and one that sees no calibrated marker
    cal2 = _truth()
    del cal2.T_world_sensor["S1"]
    assert check_frames(frames[:1], cal2)[0].status == "unknown"
    cal3 = _truth()
    cal3.T_world_marker = {k: v for k, v in cal3.T_world_marker.items() if k not in (1, 3)}
    c = check_frames(frames[:1], cal3)[0]
    assert c.status == "unknown" and "sees no calibrated marker" in c.reason
