"""SkeletonSeries conveniences for analysis from Python."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from engine.io.csv import read_skeleton_csv, write_skeleton_csv
from engine.skeleton import AZURE_KINECT, KINECT_V2, SkeletonSeries, TrackingState


def _series() -> SkeletonSeries:
    rng = np.random.default_rng(3)
    T, J = 6, len(KINECT_V2.joints)
    P = rng.normal(size=(T, J, 3))
    S = np.full((T, J), TrackingState.TRACKED, np.uint8)
    P[2, 5] = np.nan
    S[2, 5] = TrackingState.NOT_TRACKED
    return SkeletonSeries(np.arange(T) / 30.0, P, S, KINECT_V2)


def test_to_columns_is_the_csv_table(tmp_path: Path) -> None:
    s = _series()
    cols = s.to_columns()
    f = tmp_path / "s.csv"
    write_skeleton_csv(f, s)
    assert list(cols) == f.read_text().splitlines()[0].split(",")
    np.testing.assert_array_equal(cols["AnkleLeft_y"], s.joint("AnkleLeft")[:, 1])
    j5 = KINECT_V2.joints[5]
    assert np.isnan(cols[f"{j5}_x"][2]) and cols[f"{j5}_state"][2] == TrackingState.NOT_TRACKED
    back = read_skeleton_csv(f).to_columns()
    for k, v in cols.items():
        np.testing.assert_allclose(back[k], v, equal_nan=True)
    cols["time"][0] = 99.0  # copies: the series is untouched
    assert s.times[0] == 0.0


def test_to_columns_without_states_and_other_joint_sets() -> None:
    s = _series()
    assert not any(k.endswith("_state") for k in s.to_columns(with_states=False))
    az = SkeletonSeries(np.arange(2) / 30, np.zeros((2, 32, 3)), np.full((2, 32), 2),
                        AZURE_KINECT)
    cols = az.to_columns()
    assert len(cols) == 1 + 32 * 4 and "ANKLE_LEFT_z" in cols
