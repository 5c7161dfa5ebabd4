"""Acceptance on a real Vicon trial (kineticstoolkit walk.c3d, Plug-in Gait, 100 Hz)."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from engine.gait import GaitAnalysis
from engine.io.c3d import read_c3d
from engine.mocap import feet_from_markers, load_feet


@pytest.fixture(scope="module")
def walk(shared_data: Path) -> Path:
    p = shared_data / "mocap" / "kineticstoolkit" / "walk.c3d"
    if not p.is_file():
        pytest.skip(f"{p} absent")
    return p


def test_reads_vicon_file(walk: Path) -> None:
    m = read_c3d(walk)
    assert m.rate == 100.0 and m.units == "mm"
    assert len(m) == 221 and "LHEE" in m.labels and "LHipAngles" not in m.labels
    assert m.times[0] == pytest.approx(1.52)
    fs = [e for e in m.events if e.kind == "foot_strike"]
    assert len(m.events) == 8 and len(fs) == 4
    f = feet_from_markers(m)
    assert f.sources["up"] == "z"
    # heels on the floor: a few cm above the lab floor, in metres
    assert 0.0 < np.nanmin(f.points["L"]["heel"][:, 2]) < 0.08


def test_every_annotated_foot_strike_detected_within_20ms(walk: Path) -> None:
    f = load_feet(walk)
    g = GaitAnalysis("heelstrike").fit(f)
    det = [e for e in g.events_ if e.kind == "foot_strike"]
    for ref in (e for e in f.events if e.kind == "foot_strike"):
        same = [e.time_s for e in det if e.side == ref.side]
        assert same, f"no {ref.side} strike detected"
        err = min(abs(t - ref.time_s) for t in same)
        assert err <= 0.020, f"{ref.side} strike at {ref.time_s:.3f}s: nearest off by {err:.3f}s"


def test_annotated_foot_offs_detected_within_20ms(walk: Path) -> None:
    f = load_feet(walk)
    g = GaitAnalysis("heelstrike").fit(f)
    det = [e for e in g.events_ if e.kind == "foot_off"]
    for ref in (e for e in f.events if e.kind == "foot_off"):
        err = min(abs(e.time_s - ref.time_s) for e in det if e.side == ref.side)
        assert err <= 0.020, f"{ref.side} foot off at {ref.time_s:.3f}s: off by {err:.3f}s"


def test_step_lengths_and_widths_match_annotated_events(walk: Path) -> None:
    f = load_feet(walk)
    g = GaitAnalysis("heelstrike", exclude_first=False).fit(f)
    d = np.array([*g.passes_[0].direction, 0.0])
    lat = np.cross([0, 0, 1.0], d)
    ref = sorted((e for e in f.events if e.kind == "foot_strike"), key=lambda e: e.time_s)
    t = f.times
    matched = 0
    for a, b in itertools.pairwise(ref):
        if a.side == b.side:
            continue
        hb = np.array([np.interp(b.time_s, t, f.points[b.side]["heel"][:, k]) for k in range(3)])
        # footprint to footprint: each heel at its own annotated strike
        ha = np.array([np.interp(a.time_s, t, f.points[a.side]["heel"][:, k]) for k in range(3)])
        L_ref, W_ref = (hb - ha) @ d, abs((hb - ha) @ lat)
        step = min(g.steps_, key=lambda s: abs(s.time_s - b.time_s))
        assert step.side == b.side and abs(step.time_s - b.time_s) < 0.02
        assert step.length_m == pytest.approx(L_ref, abs=0.01)
        assert step.width_m == pytest.approx(W_ref, abs=0.01)
        matched += 1
    assert matched == 3


def test_crossing_method_on_vicon(walk: Path) -> None:
    g = GaitAnalysis("crossing", exclude_first=False).fit(load_feet(walk))
    assert [e.kind for e in g.events_] == ["placement"] * len(g.events_)
    assert len(g.steps_) >= 3
    sides = [e.side for e in g.events_]
    assert all(a != b for a, b in itertools.pairwise(sides))
    # ≈ 2 m walked in ≈ 2 s by an adult: plausible ranges
    assert 0.4 < g.summary_["step_length_m"]["mean"] < 0.7
    assert 0.6 < g.summary_["walking_speed_m_s"] < 1.3


def test_stance_matches_annotated_events(walk: Path) -> None:
    f = load_feet(walk)
    g = GaitAnalysis("heelstrike").fit(f)
    for side, key in (("L", "left_mean"), ("R", "right_mean")):
        fs = sorted(e.time_s for e in f.events if e.side == side and e.kind == "foot_strike")
        fo = [e.time_s for e in f.events if e.side == side and e.kind == "foot_off"
              and fs[0] < e.time_s < fs[1]]
        ref = 100.0 * (fo[0] - fs[0]) / (fs[1] - fs[0])
        assert g.summary_["stance_pct"][key] == pytest.approx(ref, abs=2.0)
