"""3D panels of the KSCC page: both users side by side and overlaid, active areas on the floor."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
import viser

from app.viewer.active_area import ActiveArea, populate_active_areas
from app.viewer.kscc import populate_kscc
from engine.coverage import active_area_polygon, sensor_pose
from engine.skeleton import KINECT_V2


def _names(server: viser.ViserServer) -> set[str]:
    return set(server.scene._handle_from_node_name)  # the only read-back viser offers


@pytest.fixture
def server() -> Iterator[viser.ViserServer]:
    s = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    yield s
    s.stop()


def test_kscc_panels(server: viser.ViserServer) -> None:
    pos = np.zeros((25, 3))
    pos[:, 2] = np.linspace(-0.9, 0.8, 25)
    pos[3] = np.nan  # a joint without an estimate: its bones are left out
    st = np.full(25, 2, np.uint8)
    populate_kscc(server, {"a": (pos, st, KINECT_V2), "b": None}, {"a": "S1", "b": "R1 @ x"})
    names = _names(server)
    assert {"/kscc", "/kscc/side/a", "/kscc/overlay/a"} <= names
    assert "/kscc/side/b" not in names
    h = server.scene._handle_from_node_name["/kscc/side/a"]
    n_bones = sum(1 for j, p in enumerate(KINECT_V2.parent_indices) if p >= 0 and 3 not in (j, p))
    assert np.asarray(h.points).shape == (n_bones, 2, 3)
    # side by side: user A shifted to its side of the panel, overlay 2.5 m ahead
    assert np.allclose(np.asarray(h.points)[:, :, 1], 0.8)
    o = server.scene._handle_from_node_name["/kscc/overlay/a"]
    assert np.allclose(np.asarray(o.points)[:, :, 0], 2.5)
    populate_kscc(server, {"a": None, "b": (pos, st, KINECT_V2)})
    names = _names(server)
    assert "/kscc/side/a" not in names and "/kscc/side/b" in names


def test_active_area_outlines(server: viser.ViserServer) -> None:
    T = sensor_pose((1.0, 2.0, 1.0), 90.0)
    poly = active_area_polygon(("S1", T, 70.6, 60.0, 0.5, 4.5))
    populate_active_areas(server, [ActiveArea("S1", poly), ActiveArea("S2", np.zeros((0, 3)))])
    names = _names(server)
    assert "/active_area/S1" in names and "/active_area/S2" not in names
    seg = np.asarray(server.scene._handle_from_node_name["/active_area/S1"].points)
    assert seg.shape == (len(poly), 2, 3)
    assert np.allclose(seg[:, :, 2], 0.005)
    assert seg[:, :, 1].min() > 2.0  # in front of a sensor looking along +Y
    populate_active_areas(server, [])
    assert "/active_area/S1" not in _names(server)
