import math
from collections import deque

import numpy as np
import pytest

from engine.errors import InputError
from engine.sim.rig import default_avenue_rig, load_rig, marker_visibility, save_rig


def test_avenue_geometry_matches_paper():
    rig = default_avenue_rig(seed=0)
    assert [s.id for s in rig.sensors] == ["S1", "S2", "S3", "S4", "S5", "S6"]
    p = {s.id: s.position for s in rig.sensors}
    # pairs 2 m apart across the walkway, rows 2.5 m apart along it
    for a, b in (("S1", "S2"), ("S3", "S4"), ("S5", "S6")):
        assert np.linalg.norm(p[a] - p[b]) == pytest.approx(2.0)
    for a, b in (("S1", "S3"), ("S3", "S5"), ("S2", "S4")):
        assert np.linalg.norm(p[a] - p[b]) == pytest.approx(2.5)
    for s in rig.sensors:
        assert 0.8 <= s.position[2] <= 1.3  # tripod height
        assert abs(s.position[1]) == pytest.approx(1.0)
        z = s.T_world_sensor[:3, 2]  # optical axis
        h = z[:2] / np.linalg.norm(z[:2])
        # axis turned 35° inwards from looking back along the walkway (−X)
        assert math.degrees(math.acos(-h[0])) == pytest.approx(35.0, abs=0.5)
        assert np.sign(h[1]) == -np.sign(s.position[1])
        assert -15 < math.degrees(math.asin(z[2])) < 0  # pitched slightly down
        R = s.T_world_sensor[:3, :3]
        assert np.allclose(R @ R.T, np.eye(3)) and np.linalg.det(R) == pytest.approx(1.0)
        assert abs(s.clock_offset_s) <= 0.5 and abs(s.clock_drift_ppm) <= 100


def test_marker_visibility_counts_and_graph_connectivity():
    rig = default_avenue_rig()
    assert np.allclose(rig.marker(1).T_world_marker, np.eye(4))
    vis = marker_visibility(rig)
    assert sorted(vis[1]) == ["S1", "S2"]
    assert all(len(v) < len(rig.sensors) for v in vis.values())
    assert len(rig.markers) == 8
    # every sensor reaches marker 1 in the bipartite sensor/marker graph
    reached = {("m", 1)}
    queue = deque([("m", 1)])
    while queue:
        kind, key = queue.popleft()
        nbrs = ([("s", s) for s in vis[key]] if kind == "m"
                else [("m", m) for m, ss in vis.items() if key in ss])
        for n in nbrs:
            if n not in reached:
                reached.add(n)
                queue.append(n)
    assert {k for kind, k in reached if kind == "s"} == set(rig.sensor_ids)


def test_seeded_clocks_differ_and_repeat():
    a, b, c = default_avenue_rig(1), default_avenue_rig(1), default_avenue_rig(2)
    assert [s.clock_offset_s for s in a.sensors] == [s.clock_offset_s for s in b.sensors]
    assert [s.clock_offset_s for s in a.sensors] != [s.clock_offset_s for s in c.sensors]
    assert all(s.clock_offset_s == 0 for s in default_avenue_rig(None).sensors)


def test_intrinsics_from_field_of_view():
    m = default_avenue_rig().sensors[0].model
    K = m.depth_intrinsics()
    assert K[0, 0] == pytest.approx(256 / math.tan(math.radians(35.3)))
    assert K[1, 1] == pytest.approx(212 / math.tan(math.radians(30.0)))
    Kc = m.color_intrinsics(1920, 1080)
    assert Kc[0, 0] == pytest.approx(960 / math.tan(math.radians(42.05)))
    assert m.color_intrinsics(640, 360)[0, 0] == pytest.approx(Kc[0, 0] / 3)


@pytest.mark.parametrize("suffix", [".toml", ".json"])
def test_save_load_roundtrip(tmp_path, suffix):
    rig = default_avenue_rig(seed=5)
    path = tmp_path / f"rig{suffix}"
    save_rig(rig, path)
    back = load_rig(path)
    for s, t in zip(rig.sensors, back.sensors, strict=True):
        assert s.id == t.id
        assert np.allclose(s.T_world_sensor, t.T_world_sensor)
        assert s.clock_drift_ppm == t.clock_drift_ppm
        assert np.allclose(s.model.T_depth_color, t.model.T_depth_color)
    assert [m.id for m in back.markers] == [m.id for m in rig.markers]
    assert np.allclose(back.walkway.end, rig.walkway.end)


def test_load_names_the_bad_field(tmp_path):
    rig = default_avenue_rig()
    path = tmp_path / "rig.toml"
    save_rig(rig, path)
    text = path.read_text().replace("clock_drift_ppm = ", "clock_drift_ppm = 'x' #", 1)
    path.write_text(text)
    with pytest.raises(InputError, match=r"sensors\[0\]\.clock_drift_ppm"):
        load_rig(path)
    path.write_text(path.read_text().replace("size_m = 0.4", "size_m = -1", 1).replace(
        "clock_drift_ppm = 'x' #", "clock_drift_ppm = "))
    with pytest.raises(InputError, match=r"markers\[0\]\.size_m"):
        load_rig(path)
    with pytest.raises(InputError, match="does not exist"):
        load_rig(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text('{"sensors": [{"id": "A", "T_world_sensor": [[2,0,0,0],[0,1,0,0],'
                   '[0,0,1,0],[0,0,0,1]]}], "walkway": {}, "room": {}}')
    with pytest.raises(InputError, match=r"T_world_sensor.*rigid"):
        load_rig(bad)
