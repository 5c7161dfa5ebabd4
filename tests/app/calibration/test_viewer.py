"""viser panel of a calibration: sensors, markers, residual-coloured edges."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
import viser

from app.viewer.calibration import populate_calibration_graph, residual_colour
from tests.app.calibration.test_calibration_api import _result


@pytest.fixture
def server() -> Iterator[viser.ViserServer]:
    s = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    yield s
    s.stop()


def test_graph_panel(server: viser.ViserServer) -> None:
    res = _result()
    res.edges[0].residual_m = 0.005
    populate_calibration_graph(server, res)
    names = set(server.scene._handle_from_node_name)
    assert {f"/calibration/sensors/S{i}" for i in range(1, 7)} <= names
    assert {f"/calibration/markers/{i}" for i in range(1, 9)} <= names
    edges = [n for n in names if n.startswith("/calibration/edges/") and n.count("/") == 3]
    assert len(edges) == len(res.edges)
    e0 = res.edges[0]
    h = server.scene._handle_from_node_name[f"/calibration/edges/{e0.sensor_id}-{e0.marker_id}"]
    assert np.asarray(h.colors).reshape(-1, 3)[0].tolist() == [210, 50, 40]
    assert residual_colour(0.0005) == (40, 160, 70) and residual_colour(0.002) == (220, 170, 20)
    assert residual_colour(float("nan")) == (150, 150, 150)
