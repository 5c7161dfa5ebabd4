"""Active-area trapezoid, coverage map, coverage image and placement table."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from engine.coverage import (
    BLIND_RGB,
    SENSOR_MODELS,
    CoverageModel,
    Grid,
    SensorSpec,
    active_area_polygon,
    active_area_trapezoid,
    avenue_rig,
    coverage_image,
    coverage_legend,
    coverage_map,
    format_placement_table,
    placement_table,
    preset_trapezoid,
    sensor_pose,
    sensors_from_rig,
)
from engine.errors import InputError
from engine.geometry import invert_transform, transform_points

# ---------------------------------------------------------------- trapezoid


def test_kinect_v1_trapezoid_reproduces_seed_004() -> None:
    t = active_area_trapezoid(1.0, 43.0, 57.0, 0.8, 4.0)
    assert abs(100 * t.near_m - 254) < 1.0
    assert abs(100 * t.far_m - 400) < 1.0
    assert abs(100 * t.near_half_width_m - 138) < 1.0
    assert abs(100 * t.far_half_width_m - 217) < 1.0
    assert abs(100 * t.depth_m - 146) < 1.0
    # the polygon is the isosceles trapezoid itself
    assert t.polygon.shape == (4, 2)
    assert np.allclose(sorted(t.polygon[:, 0]), [t.near_m] * 2 + [t.far_m] * 2)


def test_trapezoid_presets_match_closed_form() -> None:
    for name in ("kinect_v2", "azure_nfov", "azure_wfov"):
        m = SENSOR_MODELS[name]
        t = preset_trapezoid(name, 1.0)
        tv = np.tan(np.radians(m.vfov_deg / 2))
        th = np.tan(np.radians(m.hfov_deg / 2))
        near = max(1.0 / tv, 0.8 / tv, m.min_range_m)  # feet, head (1.8 m body), range
        assert t.near_m == pytest.approx(near, abs=1e-6)
        assert t.far_m == pytest.approx(m.max_range_m, abs=1e-6)
        assert t.near_width_m == pytest.approx(2 * near * th, abs=1e-6)
        assert t.far_width_m == pytest.approx(2 * m.max_range_m * th, abs=1e-6)


def test_trapezoid_head_limit_and_body_radius() -> None:
    # a sensor at 0.4 m: the head (1.4 m above the sensor) is the limiting point
    t = active_area_trapezoid(0.4, 43.0, 57.0, 0.8, 6.0, body_height_m=1.8)
    assert t.near_m == pytest.approx(1.4 / np.tan(np.radians(21.5)), abs=1e-6)
    # a body of radius r shrinks the width by r/cos(θh/2) on each side
    r = 0.2
    t2 = active_area_trapezoid(1.0, 43.0, 57.0, 0.8, 4.0, body_radius_m=r)
    t0 = active_area_trapezoid(1.0, 43.0, 57.0, 0.8, 4.0)
    assert t2.near_m == pytest.approx(t0.near_m + r, abs=1e-9)
    assert t2.far_m == pytest.approx(4.0 - r, abs=1e-9)
    shrink = r / np.cos(np.radians(28.5))
    assert t2.far_width_m == pytest.approx(2 * (3.8 * np.tan(np.radians(28.5)) - shrink),
                                           abs=1e-6)


def test_trapezoid_tilt_and_impossible_geometry() -> None:
    t = active_area_trapezoid(1.0, 43.0, 57.0, 0.8, 4.0, tilt_deg=5.0)
    # tilting down: the feet are seen nearer, the head is the new near limit
    assert t.near_m == pytest.approx(0.8 / np.tan(np.radians(21.5 - 5.0)), abs=1e-6)
    with pytest.raises(InputError, match="fully visible"):
        active_area_trapezoid(1.0, 43.0, 57.0, 0.8, 4.0, tilt_deg=10.0)
    with pytest.raises(InputError):
        active_area_trapezoid(1.0, 43.0, 57.0, 4.0, 0.8)
    with pytest.raises(InputError):
        preset_trapezoid("kinect_v9")


# ----------------------------------------------------------------- coverage


def _analytic_v1(X: np.ndarray, Y: np.ndarray, x_s: float, direction: int) -> np.ndarray:
    """Whole-line-body visibility of a level Kinect v1 at 1 m looking along ±X."""
    d = direction * (X - x_s)
    tv, th = np.tan(np.radians(21.5)), np.tan(np.radians(28.5))
    return (d >= 1.0 / tv) & (d <= 4.0) & (np.abs(Y) <= d * th)


def test_coverage_counts_hand_computed() -> None:
    a = SensorSpec.from_model("a", sensor_pose((0.0, 0.0, 1.0), 0.0), "kinect_v1")
    b = SensorSpec.from_model("b", sensor_pose((7.0, 0.0, 1.0), 180.0), "kinect_v1")
    grid = Grid(0.0, 7.0, -2.5, 2.5, 0.1)
    cm = coverage_map([a, b], grid, body_radius_m=0.0)
    x, y = grid.centres()
    X, Y = np.meshgrid(x, y)
    expected = _analytic_v1(X, Y, 0.0, 1).astype(int) + _analytic_v1(X, Y, 7.0, -1)
    assert cm.counts.shape == (50, 70)
    assert np.array_equal(cm.counts, expected)
    assert cm.counts.max() == 2  # the overlap 3.0 ≤ x ≤ 4.0 (7 − 4 … 0 + 4)
    assert np.array_equal(cm.blind, expected == 0)
    # both look along the walkway: neither sees a side at y = 0
    assert not cm.two_sided[np.abs(Y) < 0.05].any()


def test_exact_cylinder_test_matches_dense_sampling() -> None:
    rng = np.random.default_rng(3)
    grid = Grid(-1.0, 5.0, -3.0, 3.0, 0.2)
    x, y = grid.centres()
    X, Y = np.meshgrid(x, y)
    H, r = 1.7, 0.25
    # dense feet-to-head cylinder samples
    z = np.linspace(0.0, H, 9)
    ang = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    ring = np.stack([r * np.cos(ang), r * np.sin(ang)], 1)
    for k in range(4):
        pos = (rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(0.6, 2.0))
        T = sensor_pose(pos, rng.uniform(-40, 40), rng.uniform(-25, 5))
        s = SensorSpec.from_model(f"s{k}", T, "kinect_v2")
        vis = coverage_map([s], grid, body_height_m=H, body_radius_m=r).counts == 1
        P = np.stack(np.broadcast_arrays(X[..., None, None] + ring[:, 0][None, None, :, None],
                                         Y[..., None, None] + ring[:, 1][None, None, :, None],
                                         z[None, None, None, :]), -1)
        Pc = transform_points(invert_transform(T), P.reshape(-1, 3)).reshape(P.shape)
        th = np.tan(np.radians(s.hfov_deg / 2))
        tv = np.tan(np.radians(s.vfov_deg / 2))
        zc = Pc[..., 2]
        inside = ((np.abs(Pc[..., 0]) <= zc * th) & (np.abs(Pc[..., 1]) <= zc * tv)
                  & (zc >= s.min_range_m) & (zc <= s.max_range_m))
        sampled = inside.all(axis=(-1, -2))
        # sampling can only over-report at the rim (points between samples); never under
        assert not (vis & ~sampled).any()
        assert (sampled & ~vis).sum() <= 0.02 * sampled.size
        assert vis.sum() > 0 or sampled.sum() == 0


def test_two_sided_and_side_counts() -> None:
    left = SensorSpec.from_model("L", sensor_pose((5.0, 3.0, 1.0), -90.0), "kinect_v2")
    right = SensorSpec.from_model("R", sensor_pose((5.0, -3.0, 1.0), 90.0), "kinect_v2")
    grid = Grid(3.0, 7.0, -1.0, 1.0, 0.1)
    cm = coverage_map([left, right], grid)
    iy, ix = 10, 20  # cell centred at (5.05, 0.05)
    assert cm.counts[iy, ix] == 2
    assert cm.left[iy, ix] == 1 and cm.right[iy, ix] == 1 and cm.two_sided[iy, ix]
    one = coverage_map([left], grid)
    assert not one.two_sided.any()
    # walking along Y instead: both sensors are now front/back, not sides
    along_y = coverage_map([left, right], grid, walkway_axis=(0.0, 1.0))
    assert not along_y.two_sided[iy, ix]


def test_default_avenue_has_two_sided_cells_and_incremental_update() -> None:
    rig = avenue_rig()
    assert len(rig) == 6
    assert [s.id for s in rig] == ["S1", "S2", "S3", "S4", "S5", "S6"]
    grid = Grid(-3.0, 7.0, -2.0, 2.0, 0.05)
    model = CoverageModel(rig, grid)
    cm = model.map()
    assert cm.two_sided.any()
    # on the centre line 3 m before the first pair the walker is seen from both sides
    x, y = grid.centres()
    ix = int(np.argmin(np.abs(x - -0.6)))
    iy = int(np.argmin(np.abs(y - 0.0)))
    assert cm.two_sided[iy, ix] and cm.counts[iy, ix] >= 2
    # drag one tripod: the map changes, and equals a full recomputation
    moved = sensor_pose((2.4, 1.0, 1.0), 180.0 + 10.0, -8.0)
    cm2 = model.move_sensor("S1", moved)
    assert not np.array_equal(cm.counts, cm2.counts)
    rig2 = [s if s.id != "S1" else SensorSpec(s.id, moved, s.hfov_deg, s.vfov_deg,
                                                s.min_range_m, s.max_range_m) for s in rig]
    full = coverage_map(rig2, grid)
    assert np.array_equal(full.counts, cm2.counts)
    assert np.array_equal(full.two_sided, cm2.two_sided)
    with pytest.raises(InputError, match="no sensor"):
        model.move_sensor("nope", moved)


def test_tuple_sensors_and_bad_input() -> None:
    T = sensor_pose((0.0, 0.0, 1.0), 0.0)
    cm = coverage_map([("t", T, 57.0, 43.0, 0.8, 4.0)], (0.0, 5.0, -1.0, 1.0, 0.5),
                      body_radius_m=0.0)
    assert cm.counts.sum() > 0
    with pytest.raises(InputError):
        coverage_map([("t", T, 57.0)], (0.0, 5.0, -1.0, 1.0, 0.5))
    with pytest.raises(InputError, match="unique"):
        coverage_map([("t", T, 57, 43, 0.8, 4), ("t", T, 57, 43, 0.8, 4)], (0, 5, -1, 1, 0.5))
    with pytest.raises(InputError, match="rotation"):
        SensorSpec("bad", np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(InputError, match="grid"):
        Grid(0.0, -1.0, 0.0, 1.0, 0.1)


def test_coverage_image_colours() -> None:
    left = SensorSpec.from_model("L", sensor_pose((5.0, 3.0, 1.0), -90.0), "kinect_v2")
    right = SensorSpec.from_model("R", sensor_pose((5.0, -3.0, 1.0), 90.0), "kinect_v2")
    cm = coverage_map([left, right], Grid(0.0, 10.0, -1.0, 1.0, 0.1))
    img = coverage_image(cm, pixels_per_cell=4)
    assert img.shape == (20 * 4, 100 * 4, 3) and img.dtype == np.uint8
    # the first column (x ≈ 0) is blind: red
    assert np.all(img[:, 0] == BLIND_RGB)
    # a two-sided cell has white hatch pixels and ramp pixels, a blind one has none
    iy, ix = 10, 50
    assert cm.two_sided[iy, ix]
    rows = slice((19 - iy) * 4, (20 - iy) * 4)  # image is north-up
    block = img[rows, ix * 4:(ix + 1) * 4].reshape(-1, 3)
    assert (block == 255).all(1).any() and not (block == BLIND_RGB).all(1).any()


def test_placement_table() -> None:
    T = sensor_pose((3.0, 4.0, 1.2), 135.0, -10.0)
    (row,) = placement_table([SensorSpec("k1", T)])
    assert row.distance_m == pytest.approx(5.0)
    assert row.bearing_deg == pytest.approx(np.degrees(np.arctan2(4, 3)))
    assert row.height_m == pytest.approx(1.2)
    assert row.yaw_deg == pytest.approx(135.0)
    assert row.pitch_deg == pytest.approx(-10.0)
    text = format_placement_table([row])
    assert "k1" in text and "500.0" in text and "135.0" in text


def test_sensors_from_rig_duck_typed() -> None:
    model = SimpleNamespace(depth_hfov_deg=70.6, depth_vfov_deg=60.0, range_min_m=0.5,
                            range_max_m=4.5)
    T = sensor_pose((1.0, 2.0, 1.0), 30.0)
    rig = SimpleNamespace(sensors=[SimpleNamespace(id="S9", T_world_sensor=T, model=model)])
    (s,) = sensors_from_rig(rig)
    assert s.id == "S9" and s.hfov_deg == 70.6 and np.array_equal(s.T_world_sensor, T)
    with pytest.raises(InputError, match="no sensors"):
        sensors_from_rig(SimpleNamespace())


def test_active_area_polygon_matches_coverage_cells() -> None:
    T = sensor_pose((2.0, -1.0, 1.1), 40.0, -6.0)
    s = SensorSpec.from_model("k", T, "kinect_v2")
    poly = active_area_polygon(s, body_height_m=1.75, body_radius_m=0.15)
    assert poly.shape[1] == 3 and len(poly) >= 4 and np.allclose(poly[:, 2], 0.0)
    grid = Grid(-2.0, 8.0, -4.0, 6.0, 0.1)
    cm = coverage_map([s], grid, body_height_m=1.75, body_radius_m=0.15)
    x, y = grid.centres()
    X, Y = np.meshgrid(x, y)
    # signed distance to each edge of the counter-clockwise polygon (> 0 inside)
    P = poly[:, :2]
    E = np.roll(P, -1, axis=0) - P
    L = np.hypot(E[:, 0], E[:, 1])
    cross = (E[:, 0, None, None] * (Y - P[:, 1, None, None])
             - E[:, 1, None, None] * (X - P[:, 0, None, None])) / L[:, None, None]
    inside = (cross.min(axis=0) > 1e-9)
    border = np.abs(cross).min(axis=0) < 1e-6
    assert np.array_equal(inside[~border], (cm.counts == 1)[~border])
    assert inside.sum() > 100
    # tilted so far down that the head never fits: empty
    steep = SensorSpec.from_model("s", sensor_pose((0.0, 0.0, 1.0), 0.0, -45.0), "kinect_v2")
    assert active_area_polygon(steep).shape == (0, 3)


def test_add_and_remove_sensors_in_planning_mode() -> None:
    rig = avenue_rig()
    grid = Grid(-3.0, 7.0, -2.0, 2.0, 0.1)
    model = CoverageModel(rig[:4], grid)
    added = model.add_sensor(rig[4])
    assert added.sensor_ids == ("S1", "S2", "S3", "S4", "S5")
    assert np.array_equal(added.counts, coverage_map(rig[:5], grid).counts)
    with pytest.raises(InputError, match="already"):
        model.add_sensor(rig[4])
    removed = model.remove_sensor("S2")
    expected = coverage_map([s for s in rig[:5] if s.id != "S2"], grid)
    assert np.array_equal(removed.counts, expected.counts)
    assert np.array_equal(removed.two_sided, expected.two_sided)
    empty = CoverageModel([], grid).map()
    assert empty.blind.all() and not empty.two_sided.any()


def test_map_to_dict_and_legend() -> None:
    rig = avenue_rig()
    cm = coverage_map(rig, Grid(-3.0, 7.0, -2.0, 2.0, 0.25))
    d = cm.to_dict()
    assert d["grid"]["nx"] == 40 and d["grid"]["ny"] == 16  # type: ignore[index]
    assert np.array_equal(np.array(d["counts"]), cm.counts)
    assert d["two_sided_fraction"] == pytest.approx(cm.two_sided.mean())
    json.dumps(d)  # serialisable
    legend = coverage_legend()
    assert legend[0][1] == BLIND_RGB and len(legend) == 8
    img = coverage_image(cm, 1)
    colours = {tuple(int(v) for v in c) for c in img.reshape(-1, 3)}
    assert colours <= {c for _, c in legend}
