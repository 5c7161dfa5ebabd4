import dataclasses
import itertools

import numpy as np
import pytest

from engine.errors import InputError
from engine.sim.walker import BONES, Walker, WalkerParams
from engine.skeleton import KINECT_V2

PARAMS = WalkerParams(height_m=1.68, speed_m_s=1.2, step_length_m=0.68, step_width_m=0.12,
                      asymmetry=0.05)


@pytest.fixture(scope="module", params=["minjerk", "literature"])
def walker(request):
    """The default swing and the literature option keep every guarantee below."""
    params = dataclasses.replace(PARAMS, swing=request.param)
    return Walker(params, [-2.5, 0.0, 0.0], [8.5, 0.0, 0.0], start_time=1.0, seed=4)


def test_foot_placements_recover_parameters(walker):
    fp = walker.foot_placements(0.0, 60.0)
    sides = [f.side for f in fp]
    assert sides[0] == "L" and all(a != b for a, b in itertools.pairwise(sides))
    steady = [(a, b) for a, b in itertools.pairwise(fp)
              if a.kind == "walk" and b.kind == "walk"]
    assert len(steady) > 40
    lengths = {"L": [], "R": []}
    widths, times = [], []
    for a, b in steady:
        d = b.position[:2] - a.position[:2]
        u = np.array([np.cos(b.heading_rad), np.sin(b.heading_rad)])
        lengths[b.side].append(abs(d @ u))
        widths.append(abs(d @ [-u[1], u[0]]))
        times.append(b.time_s - a.time_s)
    mean_len = np.mean(lengths["L"] + lengths["R"])
    assert mean_len == pytest.approx(PARAMS.step_length_m, rel=0.02)
    assert np.mean(lengths["L"]) / np.mean(lengths["R"]) - 1 == pytest.approx(0.05, abs=0.025)
    assert np.mean(widths) == pytest.approx(PARAMS.step_width_m, abs=0.01)
    assert 60 / np.mean(times) == pytest.approx(PARAMS.cadence_steps_min, rel=0.02)
    assert mean_len / np.mean(times) == pytest.approx(PARAMS.speed_m_s, rel=0.03)
    # first step from standing is shorter (acceleration), as in the seed protocol
    assert fp[0].kind == "first"


def test_bone_lengths_constant_and_feet_on_floor(walker):
    t = np.arange(0.0, 40.0, 1 / 30)
    J = walker.joints(t)
    assert J.shape == (len(t), 25, 3) and np.all(np.isfinite(J))
    for p, c in KINECT_V2.bones:
        length = np.linalg.norm(J[:, KINECT_V2.index(p)] - J[:, KINECT_V2.index(c)], axis=1)
        assert length.std() < 1e-9, (p, c)
    ankle_h = walker.body.ankle_h
    for name in ("AnkleLeft", "AnkleRight"):
        assert J[:, KINECT_V2.index(name), 2].min() >= ankle_h - 1e-9
    # knee flexes between ~0-20° in stance and ~55-80° in swing
    h, k, a = (J[:, KINECT_V2.index(n)] for n in ("HipLeft", "KneeLeft", "AnkleLeft"))
    u, v = h - k, a - k
    flex = 180 - np.degrees(np.arccos(np.sum(u * v, 1) / np.linalg.norm(u, axis=1)
                                      / np.linalg.norm(v, axis=1)))
    assert flex.min() < 20 and 55 < flex.max() < 85


def test_ankle_still_during_foot_flat_and_at_placement(walker):
    for f in walker.foot_placements(0.0, 20.0):
        if f.kind != "walk":
            continue
        t = np.linspace(f.foot_flat_s, f.toe_off_s - 0.5 * PARAMS.step_time_s, 5)
        name = "AnkleLeft" if f.side == "L" else "AnkleRight"
        pos = walker.joints(t)[:, KINECT_V2.index(name)]
        assert np.allclose(pos, f.position, atol=1e-9)


def test_stance_and_double_support_fractions(walker):
    ev = walker.events(3.0, 9.0)
    strikes = [e for e in ev if e.kind == "foot_strike" and e.side == "L"]
    offs = [e for e in ev if e.kind == "foot_off" and e.side == "L"]
    stride = strikes[1].time_s - strikes[0].time_s
    off = next(e.time_s for e in offs if e.time_s > strikes[0].time_s)
    assert (off - strikes[0].time_s) / stride == pytest.approx(0.6, abs=0.03)
    r_off = next(e.time_s for e in ev if e.kind == "foot_off" and e.side == "R"
                 and e.time_s > strikes[0].time_s)
    assert (r_off - strikes[0].time_s) / stride == pytest.approx(0.1, abs=0.02)


def test_bone_frames_are_rigid_and_anchored(walker):
    t = np.linspace(2.0, 4.0, 11)
    fr = walker.bone_frames(t)
    J = walker.joints(t)
    assert set(fr) == set(BONES)
    for name, T in fr.items():
        R = T[:, :3, :3]
        assert np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-9), name
        assert np.allclose(np.linalg.det(R), 1.0)
    i = KINECT_V2.index
    assert np.allclose(fr["thigh_l"][:, :3, 3], J[:, i("HipLeft")])
    # shank z axis points from the ankle to the knee
    d = J[:, i("KneeRight")] - J[:, i("AnkleRight")]
    assert np.allclose(fr["shank_r"][:, :3, 2], d / np.linalg.norm(d, axis=1)[:, None])


def test_walks_back_and_forth(walker):
    passes = walker.pass_times(60.0)
    assert len(passes) >= 3
    J = walker.joints(np.array([passes[0][1], passes[1][1]]))
    x = J[:, KINECT_V2.index("SpineBase"), 0]
    assert x[0] > 7.0 and x[1] < -1.5


def test_body_mesh_and_random_params():
    rng = np.random.default_rng(0)
    for _ in range(20):
        p = WalkerParams.random(rng)
        assert 1.5 <= p.height_m <= 2.0 and 70 < p.cadence_steps_min < 140
    w = Walker(WalkerParams.random(rng), [0, 0, 0], [6, 0, 0], seed=1)
    V, F, labels = w.body_mesh(1.5)
    assert V.shape[1] == 3 and F.max() < len(V) and len(labels) == len(F)
    assert labels.max() == len(w.capsules) - 1
    assert V[:, 2].min() > -0.01 and V[:, 2].max() < w.params.height_m + 0.05


def test_bad_params_are_rejected():
    with pytest.raises(InputError, match="speed_m_s"):
        WalkerParams(speed_m_s=9.0)
    with pytest.raises(InputError, match="swing"):
        WalkerParams(swing="ballistic")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="landing_speed_frac"):
        WalkerParams(landing_speed_frac=2.0)
    with pytest.raises(InputError, match="two steps"):
        Walker(WalkerParams(), [0, 0, 0], [0.5, 0, 0])


def test_body_stands_still_before_the_start():
    """A walk from standing starts still: before ``start_time`` no joint moves but the
    first foot, whose heel rises 0.3 step times before it (push-off of the first step).
    The pelvis and arms used to follow spline knots 1000 s before the start and moved
    through the standing second (hands ≈ 1 m/s, pelvis ≈ 0.1 m/s)."""
    p = WalkerParams()
    w = Walker(p, [0.0, 0.0, 0.0], [8.0, 0.0, 0.0], start_time=1.5, back_and_forth=False,
               seed=3)
    t = np.arange(0.0, 1.5 - 0.3 * p.step_time_s - 0.02, 0.01)
    speed = np.linalg.norm(np.gradient(w.joints(t), t, axis=0), axis=-1)
    assert speed.max() < 1e-6
    # ... and it does walk afterwards, leaving with the pelvis at rest (no jump)
    t2 = np.arange(1.5, 3.5, 0.01)
    v2 = np.linalg.norm(np.gradient(w.joints(t2)[:, KINECT_V2.index("SpineBase"), :2],
                                    t2, axis=0), axis=1)
    assert v2[0] < 0.05 and v2.max() > 0.8 * p.speed_m_s
