"""The report table shows stance, swing and double support from real gait JSON, whose
summary gives them as ``{"mean", "left_mean", "right_mean"}`` (docs/gait-json.md)."""

from __future__ import annotations

from engine.gait import GaitAnalysis
from engine.mocap import feet_from_markers
from engine.report.render import TrialData, spatiotemporal_table
from engine.sim.straight_walk import synth_walk, walk_markers


def test_phase_rows_come_from_the_gait_summary() -> None:
    w = synth_walk(n_steps=14, rate=100.0)
    doc = GaitAnalysis("heelstrike").fit(feet_from_markers(walk_markers(w))).to_dict()
    st = doc["summary"]["stance_pct"]
    assert isinstance(st, dict) and st["mean"] is not None
    rows = {(r.label, r.side): r for r in spatiotemporal_table([TrialData("t", doc)])}
    assert abs(rows[("Stance", "")].mean - st["mean"]) < 1e-9
    assert abs(rows[("Stance", "L")].mean - st["left_mean"]) < 1e-9
    assert abs(rows[("Stance", "R")].mean - st["right_mean"]) < 1e-9
    assert abs(rows[("Swing", "")].mean - doc["summary"]["swing_pct"]["mean"]) < 1e-9
    assert ("Double support", "") in rows
    # A walk has stance ≈ 60 % of the cycle.
    assert 50.0 < rows[("Stance", "")].mean < 75.0


def test_crossing_method_has_no_phase_rows() -> None:
    w = synth_walk(n_steps=10, rate=100.0)
    doc = GaitAnalysis("crossing").fit(feet_from_markers(walk_markers(w))).to_dict()
    labels = {r.label for r in spatiotemporal_table([TrialData("t", doc)])}
    assert "Stance" not in labels and "Step length" in labels
