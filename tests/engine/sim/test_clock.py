import numpy as np
import pytest

from engine.errors import InputError
from engine.sim.clock import SimClock, frame_times


def test_local_and_true_are_inverse():
    c = SimClock(offset_s=-0.37, drift_ppm=85.0)
    t = np.linspace(0, 3600, 7)
    local = c.local(t)
    assert np.allclose(c.true(local), t, atol=1e-9)
    # after one hour the drift alone amounts to 85 ppm × 3600 s = 306 ms
    assert local[-1] - local[0] == pytest.approx(3600 * (1 + 85e-6), abs=1e-9)
    assert c.local(0.0) == pytest.approx(-0.37)


def test_frame_times_jitter_within_25_35_hz():
    rng = np.random.default_rng(3)
    t = frame_times(10.0, 70.0, rng, fps=30.0, jitter=0.08)
    periods = np.diff(t)
    assert t[0] == 10.0 and t[-1] < 70.0
    assert periods.min() >= 1 / 35 - 1e-12 and periods.max() <= 1 / 25 + 1e-12
    assert periods.std() > 0.001  # it really jitters
    assert 1 / periods.mean() == pytest.approx(30.0, rel=0.01)


def test_frame_times_rejects_bad_rate():
    with pytest.raises(InputError, match="fps"):
        frame_times(0, 1, np.random.default_rng(0), fps=60)
