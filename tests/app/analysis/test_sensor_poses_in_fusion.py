"""The server hands the fusion each sensor at its pose: the weighted estimator weighs a
sensor by where it stands (distance, the body side it sees, the surface it fits to)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from app.server import analysis as an
from engine.geometry import transform_points
from engine.sim.rig import default_avenue_rig
from engine.sim.straight_walk import synth_walk, walk_skeleton
from engine.skeleton import KINECT_V2, SkeletonSeries


def test_streams_carry_the_sensor_poses(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                        ) -> None:
    """Each stream's pose is its sensor's, and its skeleton, placed by that pose, is the
    world skeleton (un-mirrored). The streams had an identity pose with world
    coordinates: every sensor stood at the world origin for the weighted fusion."""
    rig = default_avenue_rig(0)
    w = synth_walk(n_steps=8, rate=30.0, origin=(1.0, 0.0, 0.0))
    world = walk_skeleton(w)
    poses = {s.id: {"T_world_sensor": np.asarray(s.T_world_sensor, float).tolist()}
             for s in rig.sensors[:2]}
    parts = {sid: tmp_path / sid for sid in poses}

    def read_part(d: Path) -> SkeletonSeries:
        T = np.asarray(poses[d.name]["T_world_sensor"], float)
        local = transform_points(np.linalg.inv(T), world)
        return SkeletonSeries(w.times, local, np.full(world.shape[:2], 2, np.uint8),
                              KINECT_V2)

    monkeypatch.setattr(an, "part_dirs", lambda _d: parts)
    monkeypatch.setattr(an, "read_meta", lambda _d: {"t_start_server": 0.0})
    monkeypatch.setattr(an, "read_part", read_part)
    streams, _facts = an.load_streams(tmp_path, poses)
    assert [s.sensor_id for s in streams] == list(poses)
    for s in streams:
        T = np.asarray(poses[s.sensor_id]["T_world_sensor"], float)
        np.testing.assert_allclose(s.T_world_sensor, T)
        assert np.linalg.norm(np.asarray(s.T_world_sensor)[:3, 3]) > 0.5  # not the origin
        placed = transform_points(np.asarray(s.T_world_sensor), s.series.positions)
        fixed, _ = an.unmirror_back_facing(
            SkeletonSeries(w.times, world, np.full(world.shape[:2], 2, np.uint8), KINECT_V2),
            T[:3, 3])
        np.testing.assert_allclose(placed, fixed.positions, atol=1e-9)


def test_fused_export_streams_are_unmirrored_like_the_reports(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two sensors that see the subject's back (she walks away from them) label her left
    leg right, as Kinect trackers do. The fused export's streams (C3D/TRC/CSV) put each
    ankle on its own side, as the reports' do; they kept the mirrored labels."""
    from app.server import storage

    rig = default_avenue_rig(0)
    sensors = rig.sensors[:2]  # S1/S2 at x = 2.4 m, looking along −x
    w = synth_walk(n_steps=8, rate=30.0, origin=(1.5, 0.0, 0.0), heading_deg=180.0)
    world = walk_skeleton(w)
    js = KINECT_V2
    swap = np.arange(len(js.joints))
    for i, j in an._swap_pairs(js.joints):
        swap[i], swap[j] = j, i
    poses = {s.id: np.asarray(s.T_world_sensor, float) for s in sensors}
    for T in poses.values():  # both behind her: she walks from x = 1.5 m towards −x
        assert T[0, 3] > 1.5 + 0.5

    def mirrored(part_dir: Path) -> SkeletonSeries:
        T = poses[part_dir.name]
        local = transform_points(np.linalg.inv(T), world)[:, swap]
        return SkeletonSeries(w.times, local, np.full(world.shape[:2], 2, np.uint8), js)

    class Layout:
        def complete_parts(self, _rec: str) -> list[str]:
            return list(poses)

        def part_dir(self, _rec: str, node: str) -> Path:
            return tmp_path / node

    monkeypatch.setattr(storage, "read_part_skeleton", mirrored)
    streams = storage.sensor_streams(Layout(), "rec", dict(poses))  # type: ignore[arg-type]
    left = js.index(js.roles["ankle_left"])
    walking = slice(len(w.times) // 4, 3 * len(w.times) // 4)  # away from the start/stop
    for s in streams:
        placed = transform_points(np.asarray(s.T_world_sensor), s.series.positions)
        np.testing.assert_allclose(placed[walking, left], world[walking, left], atol=1e-9)
    fused, _events = storage.fused_skeleton(streams)
    lateral = fused.positions[:, left, 1] - fused.positions[:, js.index(js.roles["ankle_right"]), 1]
    # walking towards −x her left is −y: the fused left ankle lies on that side
    assert np.nanmedian(lateral) < -0.05
