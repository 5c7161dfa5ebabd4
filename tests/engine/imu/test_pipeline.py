"""End-to-end IMU session on the simulated walker: auto plank, fusion, CSV export."""

from __future__ import annotations

import numpy as np
import pytest

from engine.errors import InputError
from engine.imu.fusion import flexion_angles, rmse
from engine.imu.pipeline import angles_csv, process_imu_session
from engine.skeleton import KINECT_V2, SkeletonSeries
from tests.engine.imu.test_fusion import T_PLANK, T_STILL, T_STRAP, scenario  # noqa: F401


def test_session_end_to_end(scenario: dict) -> None:  # noqa: F811
    res = process_imu_session(scenario["imus"], scenario["depth"], synchronise=False,
                              q_world_plank=scenario["q_plank_world"])
    # the plank pose is found automatically (all sensors resting with equal tilt)
    assert 0.5 < res.calibration.time < T_PLANK
    fs = res.fused.skeleton
    truth = SkeletonSeries(fs.times, scenario["walker"].joints(np.maximum(fs.times, T_STILL)),
                           fs.states, KINECT_V2)
    ang_t = flexion_angles(truth)
    walk = fs.times > T_STILL
    for j in ("knee_left", "knee_right"):
        assert rmse(res.angles_fused[j][walk], ang_t[j][walk]) < 4.0
    text = angles_csv(res)
    lines = text.strip().splitlines()
    assert lines[0].startswith("time_s,knee_left_fused_deg,knee_left_depth_deg")
    assert len(lines) == len(fs.times) + 1
    row = lines[len(lines) // 2].split(",")
    assert len(row) == 9 and row[1] != "" and row[2] != ""
    # the fused skeleton exists only while the depth skeleton does
    assert fs.times[0] >= T_STRAP


def test_session_input_errors(scenario: dict) -> None:  # noqa: F811
    imus = dict(scenario["imus"])
    with pytest.raises(InputError, match="unknown sensor"):
        process_imu_session({**imus, "knee": imus["chest"]}, scenario["depth"],
                            synchronise=False)
    imus.pop("chest")
    with pytest.raises(InputError, match="chest"):
        process_imu_session(imus, scenario["depth"], synchronise=False)
