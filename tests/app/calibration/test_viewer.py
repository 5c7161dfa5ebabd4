"""viser panel of a calibration: sensors, markers, residual-coloured edges."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

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


def test_live_view_draws_the_active_calibration(server: viser.ViserServer,
                                                tmp_path: Path) -> None:
    """The live 3D view's graph layer shows the saved calibration (its sensors, markers
    and residual-coloured edges), not the simulator's true poses."""
    from app.config import Settings
    from app.server import calibration as cal
    from app.server.hub import Hub
    from app.viewer.live import LiveServices

    hub = Hub(Settings(data_dir=tmp_path, viewer_enabled=False, node_token="viewer-token"))
    live = LiveServices(hub, server)
    live._draw_graph()
    names = set(server.scene._handle_from_node_name)
    assert not any(n.startswith("/graph/edges/S") for n in names)  # no calibration yet
    res = _result()
    cal.save(tmp_path, res)
    live._draw_graph()
    names = set(server.scene._handle_from_node_name)
    edges = [n for n in names if n.startswith("/graph/edges/") and n.count("/") == 3]
    assert len(edges) == len(res.edges)
    assert {f"/graph/sensors/S{i}" for i in range(1, 7)} <= names
    assert "/graph/label" in names
