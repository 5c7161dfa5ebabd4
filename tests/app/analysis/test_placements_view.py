"""The report's top view of a recording walked back and forth: every pass on one axis."""

from __future__ import annotations

import numpy as np

from app.server.analysis import _placements
from engine.gait import GaitAnalysis
from engine.mocap import feet_from_skeleton
from engine.sim.walker import Walker, WalkerParams
from engine.skeleton import KINECT_V2, SkeletonSeries, TrackingState


def test_a_pass_walked_back_lies_on_the_same_stretch_of_floor() -> None:
    """Both passes of a 6 m walkway walked there and back are drawn within its 6 m, left
    feet on the left of each pass (they were drawn ≈ 10 m apart, the way back mirrored)."""
    w = Walker(WalkerParams(), np.array([0.0, 0.0, 0.0]), np.array([6.0, 0.0, 0.0]),
               start_time=0.5, back_and_forth=True, seed=1, horizon_s=40.0)
    t = np.arange(0.0, 16.0, 1 / 30)
    joints = w.joints(t)
    series = SkeletonSeries(t, joints, np.full(joints.shape[:2], TrackingState.TRACKED,
                                               np.uint8), KINECT_V2)
    feet = feet_from_skeleton(series)
    ga = GaitAnalysis("crossing").fit(feet)
    directions = {round(ga.passes_[s.pass_index].direction[0]) for s in ga.steps_}
    assert directions == {1, -1}, "the walk should hold a pass each way"
    out = _placements(ga, feet)
    along = np.array([o["position"][0] for o in out])
    assert along.min() >= 0.0 and along.max() < 6.5, along
    for o in out:
        across = o["position"][1]
        assert (across > 0) == (o["side"] == "L"), o
