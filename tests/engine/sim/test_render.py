import cv2
import numpy as np
import pytest

from engine.errors import InputError
from engine.geometry import invert_transform, transform_points
from engine.sim.render import QUIET_ZONE, SensorRenderer, _Room, depth_to_points, render_frame
from engine.sim.rig import FloorMarker, default_avenue_rig, marker_visible
from engine.sim.walker import Walker, WalkerParams
from engine.skeleton import KINECT_V2


@pytest.fixture(scope="module")
def rig():
    return default_avenue_rig(seed=0)


def test_floor_depth_matches_geometry(rig):
    s = rig.sensor("S4")
    K = s.model.depth_intrinsics()
    frame = render_frame(s, rig, [], color_size=None, rng=np.random.default_rng(1))
    assert frame.depth.shape == (424, 512) and frame.depth.dtype == np.uint16
    assert frame.color is None and np.all(frame.body_index == 255)
    R, o = s.T_world_sensor[:3, :3], s.position
    for u, v in ((256, 400), (100, 380), (400, 350)):
        d = R @ np.array([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], 1.0])
        z_true = -o[2] / d[2]  # ray o + z·d meets the floor z = 0 at depth z
        sd = s.model.depth_noise_sd(z_true)
        assert abs(frame.depth[v, u] / 1000.0 - z_true) < 4 * sd + 0.0006
    # back-projected floor points lie on the floor
    pts = transform_points(s.T_world_sensor, depth_to_points(frame.depth, K))
    floor = pts[pts[:, 2] < 0.2]
    assert len(floor) > 50000 and abs(np.median(floor[:, 2])) < 0.002
    # nothing beyond the 4.5 m range
    assert np.linalg.norm(depth_to_points(frame.depth, K), axis=1).max() < 4.53


def test_body_index_marks_the_walker(rig):
    s = rig.sensor("S1")
    w = Walker(WalkerParams(), rig.walkway.start, rig.walkway.end, seed=0)
    t = 1.6
    r = SensorRenderer(s, rig, color_size=(320, 180))
    f = r.render([w.body_mesh(t)], rng=None)
    K = s.model.depth_intrinsics()
    p = transform_points(s.T_sensor_world, w.joints([t])[0, KINECT_V2.index("SpineMid")])
    u = round(K[0, 0] * p[0] / p[2] + K[0, 2])
    v = round(K[1, 1] * p[1] / p[2] + K[1, 2])
    assert f.body_index[v, u] == 0
    # the surface is in front of the spine joint, by less than the trunk's depth
    assert 0.03 < p[2] - f.depth[v, u] / 1000.0 < 0.2
    assert (f.body_index == 0).sum() > 2000
    empty = r.render([], rng=None)
    changed = f.depth != empty.depth
    assert np.all(f.body_index[changed] == 0)
    assert f.color is not None and np.any(f.color != empty.color)


def test_markers_detected_in_colour(rig):
    s = rig.sensor("S3")
    r = SensorRenderer(s, rig, color_size=(960, 540))
    f = r.render([], rng=None)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50),
                                  params)
    corners, ids, _ = det.detectMarkers(cv2.cvtColor(f.color, cv2.COLOR_RGB2GRAY))
    assert ids is not None
    found = {int(i): c.reshape(4, 2) for i, c in zip(ids.ravel(), corners, strict=True)}
    # 960 px wide renders resolve markers down to ~40 native px per edge
    expected = {m.id for m in rig.markers if marker_visible(s, m, min_side_px=40)}
    assert expected and expected <= set(found)
    T_cw = invert_transform(s.T_world_color)
    K = f.K_color
    for mid in expected:
        q = transform_points(T_cw, rig.marker(mid).corners_world())
        uv = (q[:, :2] / q[:, 2:]) * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
        assert np.abs(found[mid] - uv).max() < 1.0, mid


def test_bad_color_size():
    rig = default_avenue_rig()
    with pytest.raises(InputError, match="color_size"):
        SensorRenderer(rig.sensors[0], rig, color_size=(4, 4))


def test_flying_pixels_only_at_depth_edges():
    from engine.sim.render import _flying_pixels

    z = np.ones((20, 30))
    z[:, 15:] = 3.0
    out = _flying_pixels(z, np.random.default_rng(0), prob=1.0)
    changed = out != z
    assert changed[:, 15].all() and changed.sum() == 20  # the far side of the edge only
    assert np.all((out[:, 15] > 1.0) & (out[:, 15] < 3.0))


def _floor_colour_brute_force(room: _Room, p: np.ndarray) -> np.ndarray:
    """The floor colour with every point tested against every marker (no culling)."""
    fx, fy = np.mod(p[:, 0], 0.5), np.mod(p[:, 1], 0.5)
    grout = (np.minimum(fx, 0.5 - fx) < 0.008) | (np.minimum(fy, 0.5 - fy) < 0.008)
    tile = (np.floor(p[:, 0] / 0.5) + np.floor(p[:, 1] / 0.5)) % 2
    out = np.repeat(np.where(grout, 95.0, 140.0 + 12.0 * tile)[:, None], 3, axis=1) \
        * [1.0, 0.97, 0.9]
    for m, T_mw, tex in room.markers:
        q = transform_points(T_mw, p)
        half = m.size_m * (0.5 + QUIET_ZONE)
        inside = (np.abs(q[:, 0]) <= half) & (np.abs(q[:, 1]) <= half)
        n = tex.shape[0]
        col_px = np.clip(((q[inside, 0] + half) / (2 * half) * n).astype(int), 0, n - 1)
        row_px = np.clip(((half - q[inside, 1]) / (2 * half) * n).astype(int), 0, n - 1)
        out[inside] = tex[row_px, col_px][:, None].astype(float)
    return out


@pytest.mark.parametrize("tilt_deg", [0.0, 25.0, 89.99, 90.0])
def test_floor_colour_culling_changes_no_pixel(tilt_deg: float) -> None:
    """Testing only the points in each marker's bounding box colours exactly the pixels
    that testing every point does: flat markers, a tilted one, and one standing on edge
    (whose prism the z range does not bound)."""
    rig = default_avenue_rig(seed=0)
    c, s = np.cos(np.radians(tilt_deg)), np.sin(np.radians(tilt_deg))
    T = np.eye(4)
    T[:3, :3] = [[1, 0, 0], [0, c, -s], [0, s, c]]
    T[:3, 3] = [1.0, 0.3, 0.05]
    rig.markers.append(FloorMarker(id=9, size_m=0.2, T_world_marker=T))
    room = _Room(rig)
    rng = np.random.default_rng(1)
    lo, hi = np.array(rig.room.floor_min), np.array(rig.room.floor_max)
    p = np.column_stack([rng.uniform(lo[0], hi[0], 200_000), rng.uniform(lo[1], hi[1], 200_000),
                         rng.normal(0.0, 0.05, 200_000)])
    # dense around every marker, edges included
    near = [m.T_world_marker[:3, 3] + rng.uniform(-0.2, 0.2, (20_000, 3)) for m in rig.markers]
    p = np.vstack([p, *near])
    assert np.array_equal(room.floor_colour(p), _floor_colour_brute_force(room, p))
