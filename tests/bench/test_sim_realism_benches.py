"""The measurement helpers of ``bench/sim_stance_wander.py`` and
``bench/sim_walker_variability.py`` measure what they say."""

import numpy as np
import pytest

from bench.sim_stance_wander import stance_wander
from bench.sim_walker_variability import paper_figures, study_variability


def test_stance_wander_of_a_known_track():
    """A fused ankle that drifts 4 cm along the walkway over a still stance, 1 cm off
    the true place across it: extent 4 cm, error extent 4 cm, mean error (2, 1) cm,
    within-stance SD of a uniform ramp (4/√12 cm along, 0 across); gaps are counted."""
    t = np.arange(0.0, 1.0, 0.01)
    truth = np.tile([1.0, 0.5, 0.1], (len(t), 1))
    ankle = truth + np.c_[0.04 * t / t[-1], np.full(len(t), 0.01), np.zeros(len(t))]
    ankle[5] = np.nan
    rows = stance_wander(t, ankle, truth, [(0.0, 1.0), (2.0, 3.0)], np.array([1.0, 0.0]))
    assert len(rows) == 1  # no samples in the second interval
    r = rows[0]
    assert r["range"] == pytest.approx(0.04, abs=1e-9)
    assert r["err_range"] == pytest.approx(0.04, abs=1e-9)
    assert r["err_along"] == pytest.approx(0.02, abs=5e-4)
    assert r["err_across"] == pytest.approx(0.01, abs=1e-9)
    assert np.sqrt(r["var_along"]) == pytest.approx(0.04 / np.sqrt(12), rel=0.03)
    assert r["var_across"] == pytest.approx(0.0, abs=1e-12)
    assert r["seen"] == pytest.approx(0.99)


def test_paper_within_subject_figures():
    """The paper's Vicon within-subject SD is √(SD² − AV SD²): stride length L
    √(8.49² − 7.98²) ≈ 2.9 cm, 2.0 % of 145.4 cm."""
    f = paper_figures()["stride_length L"]
    assert f["within_sd"] == pytest.approx(2.90, abs=0.01)
    assert f["within_cv_pct"] == pytest.approx(1.99, abs=0.006)


def test_walker_variability_splits_within_and_between_subjects():
    """On a small sample: the within-subject stride CV is the walker's step-to-step
    variability (steps CV 3 %, independent: strides ≈ 3/√2 ≈ 2.1 %), far below the
    spread of the subject averages, and the lag-1 correlation of steps is near 0."""
    out = study_variability(4, 3, seed=0)
    for side in "LR":
        assert 1.0 < out[f"stride_length {side}"]["within_cv_pct"] < 3.5
        assert out[f"stride_length {side}"]["av_sd"] > out[f"stride_length {side}"]["within_sd"]
    assert abs(out["step_length lag1_r"]) < 0.5
