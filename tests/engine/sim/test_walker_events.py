"""The walker's true gait events (``Walker.events``) against its own foot kinematics:
a foot strike is the instant its heel reaches the floor, a foot off the instant its
forefoot (the metatarsal heads it rolls over) leaves it."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from engine.sim.walker import Walker, WalkerParams


@pytest.fixture(scope="module")
def walker() -> Walker:
    return Walker(WalkerParams(height_m=1.7, speed_m_s=1.15, step_length_m=0.66),
                  [0.0, 0.0, 0.0], [9.0, 0.0, 0.0], start_time=1.0, back_and_forth=False,
                  seed=2)


def _contact_points(w: Walker, side: str, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World heel and forefoot (metatarsal heads) contact points of one foot."""
    T = w.bone_frames(t)["foot_l" if side == "L" else "foot_r"]
    b = w.body
    heel = T[:, :3, 3] + T[:, :3, :3] @ np.array([-b.heel_back, 0.0, -b.ankle_h])
    ball = T[:, :3, 3] + T[:, :3, :3] @ np.array([b.ball_fwd, 0.0, -b.ankle_h])
    return heel, ball


def test_foot_strike_is_when_the_heel_reaches_the_floor(walker: Walker) -> None:
    strikes = [e for e in walker.events(0.0, 9.0) if e.kind == "foot_strike"]
    assert len(strikes) >= 10
    dt = 0.02
    for e in strikes:
        heel, _ = _contact_points(walker, e.side, np.array([e.time_s - dt, e.time_s,
                                                             e.time_s + dt]))
        assert heel[1, 2] == pytest.approx(0.0, abs=1e-9), e
        # in the air just before (the heel descends onto the floor), on it just after
        assert heel[0, 2] > 1e-3, e
        assert heel[2, 2] == pytest.approx(0.0, abs=1e-9), e


def test_foot_off_is_when_the_forefoot_leaves_the_floor(walker: Walker) -> None:
    offs = [e for e in walker.events(1.5, 9.0) if e.kind == "foot_off"]
    assert len(offs) >= 10
    dt = 0.02
    for e in offs:
        _, ball = _contact_points(walker, e.side, np.array([e.time_s - dt, e.time_s,
                                                             e.time_s + dt]))
        assert ball[0, 2] == pytest.approx(0.0, abs=1e-9), e  # rolling over it
        assert ball[1, 2] == pytest.approx(0.0, abs=1e-9), e
        assert ball[2, 2] > 5e-4, e  # lifted


def test_events_alternate_strike_then_off_per_foot(walker: Walker) -> None:
    for side in "LR":
        ev = [e for e in walker.events(1.5, 9.0) if e.side == side]
        kinds = [e.kind for e in ev]
        assert all(a != b for a, b in itertools.pairwise(kinds)), kinds
