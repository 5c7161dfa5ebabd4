"""``engine.sim.straight_walk.walk_markers``: the axes it writes are the ones it says."""

from __future__ import annotations

import numpy as np
import pytest

from engine.errors import InputError
from engine.io import detect_vertical_axis
from engine.sim.straight_walk import synth_walk, walk_markers


def test_y_up_is_the_world_rotated_as_documented() -> None:
    w = synth_walk()
    z, y = walk_markers(w), walk_markers(w, up="y")
    np.testing.assert_allclose(y.positions, z.positions[..., [1, 2, 0]])
    assert detect_vertical_axis(y.positions, y.labels) == "y"


@pytest.mark.parametrize("up", ["-y", "x", "Y"])
def test_an_axis_it_cannot_write_is_refused(up: str) -> None:
    """``up="-y"`` returned a Z-up marker set without a word."""
    with pytest.raises(InputError, match="up must be 'z' or 'y'"):
        walk_markers(synth_walk(), up=up)
