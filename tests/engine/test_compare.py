"""ComparisonResult conveniences for analysis from Python."""

from __future__ import annotations

import numpy as np
import pytest

from engine.compare import compare_motions
from engine.sim.straight_walk import synth_walk, walk_skeleton
from engine.skeleton import KINECT_V2, SkeletonSeries


def test_result_repr_and_per_joint_by_name() -> None:
    w = synth_walk(n_steps=4, rate=30.0)
    P = walk_skeleton(w)
    a = SkeletonSeries(w.times, P, np.full(P.shape[:2], 2, np.uint8), KINECT_V2)
    shifted = P.copy()
    shifted[:, KINECT_V2.index("AnkleLeft"), 2] += 0.05  # one joint 5 cm higher
    b = SkeletonSeries(w.times, shifted, a.states, KINECT_V2)
    res = compare_motions(a, b, align=False)
    per = res.per_joint()
    assert list(per) == res.joints and len(per) == len(KINECT_V2.joints)
    assert per["AnkleLeft"] == pytest.approx(0.05)
    assert per["Head"] == pytest.approx(0.0, abs=1e-12)
    text = repr(res)
    assert len(text) < 200, text
    assert f"{len(w.times)} aligned frame pairs" in text
    assert f"mean distance {100 * 0.05 / len(KINECT_V2.joints):.2f} cm" in text
