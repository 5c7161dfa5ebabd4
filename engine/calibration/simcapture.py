"""Calibration capture in the simulator: colour + noisy depth of the floor markers.

Used by ``gaitrig calibrate --rig ...``, the tests and ``bench/calibration.py`` to measure
the calibration against the simulator's true sensor poses.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from engine.calibration.corners3d import DEFAULT_FRAMES, SensorFrames
from engine.calibration.pipeline import CalibrationResult
from engine.errors import InputError
from engine.geometry import pose_error
from engine.pointcloud import CameraIntrinsics
from engine.sim.render import BodyMesh, SensorRenderer
from engine.sim.rig import Rig, SimSensor

#: Colour size for marker detection (the simulator's renderer defaults to 640×360; floor
#: markers 4 m away need ≥ 960×540 to decode).
CAPTURE_COLOR_SIZE = (960, 540)
#: Colour read noise (1σ, 8-bit levels) added per frame when noise is on.
COLOR_NOISE_DN = 2.0


def render_sensor_frames(sensor: SimSensor, rig: Rig, frames: int, rng: np.random.Generator | None,
                         color_size: tuple[int, int] = CAPTURE_COLOR_SIZE,
                         bodies: Callable[[int], list[BodyMesh]] | list[BodyMesh] | None = None,
                         renderer: SensorRenderer | None = None,
                         color_dist: Any = None) -> SensorFrames:
    """Render ``frames`` colour + depth frames of one simulated sensor.

    Args:
        sensor: The simulated sensor (its pose is the ground truth).
        rig: The rig (room and floor markers).
        frames: Number of frames.
        rng: Noise source (depth noise, dropouts, flying pixels, colour read noise);
            None = noise-free.
        color_size: Colour image size.
        bodies: Body meshes in the world (people in the room) for every frame, or a
            function frame index → meshes, or None (an empty room).
        renderer: A renderer of this sensor at ``color_size`` to reuse (it ray-casts the
            room once, which is the slow part).
        color_dist: OpenCV distortion of the colour lens to render (None: a pinhole;
            ignored with ``renderer``, which has its own). The frames' colour intrinsics
            carry it, as a node reporting its lens sends it.

    Returns:
        The sensor's :class:`SensorFrames` (colour, depth in metres, camera model).
    """
    if frames < 1:
        raise InputError(f"frames must be at least 1, got {frames}")
    r = renderer or SensorRenderer(sensor, rig, color_size=color_size, color_dist=color_dist)
    colors, depths = [], []
    for k in range(frames):
        meshes = bodies(k) if callable(bodies) else (bodies or [])
        f = r.render(meshes, rng)
        assert f.color is not None  # the renderer has a colour size
        c = f.color
        if rng is not None:  # camera read noise (the renderer's colour is noise-free)
            c = np.clip(c + rng.normal(0.0, COLOR_NOISE_DN, c.shape), 0, 255).astype(np.uint8)
        colors.append(c)
        depths.append(f.depth)
    assert r.K_color is not None and r.color_size is not None
    w, h = r.color_size
    color_intr = CameraIntrinsics.from_matrix(r.K_color, w, h, r.color_dist)
    dh, dw = r.depth_shape
    depth_intr = (r.K_depth if r.depth_dist is None  # a renderer's depth lens goes along too
                  else CameraIntrinsics.from_matrix(r.K_depth, dw, dh, r.depth_dist))
    return SensorFrames(sensor_id=sensor.id, colors=colors, depths=depths,
                        depth_intrinsics=depth_intr, color_intrinsics=color_intr,
                        T_depth_color=sensor.model.T_depth_color, depth_scale=1000.0)


def simulate_capture(rig: Rig, frames: int = DEFAULT_FRAMES, seed: int = 0,
                     color_size: tuple[int, int] = CAPTURE_COLOR_SIZE,
                     noise: bool = True) -> list[SensorFrames]:
    """Render ``frames`` colour + depth frames of the empty room for every sensor.

    Args:
        rig: The simulated rig (sensor poses are the ground truth).
        frames: Frames per sensor.
        seed: Seed of the depth noise.
        color_size: Colour image size.
        noise: Depth noise, dropouts and flying pixels on.

    Returns:
        One :class:`SensorFrames` per sensor, in rig order (colour, depth in metres, the
        camera model).
    """
    rng = np.random.default_rng(seed) if noise else None
    return [render_sensor_frames(s, rig, frames, rng, color_size) for s in rig.sensors]


def pose_errors(result: CalibrationResult, rig: Rig) -> dict[str, dict[str, Any]]:
    """Each sensor's pose errors against the simulated rig's true poses.

    Position (m) and rotation (deg) errors of the chained (paper) estimate, the joint
    optimisation (``optimised``) and the final pose after ICP (``final``; equal to
    ``optimised`` where ICP was refused or not run), and the distance to the origin marker.

    Args:
        result: A calibration of a simulated capture of ``rig``.
        rig: The simulated rig (the ground truth).

    Returns:
        Sensor id -> ``chained_pos_m``, ``chained_rot_deg``, ``optimised_pos_m``,
        ``optimised_rot_deg``, ``final_pos_m``, ``final_rot_deg``,
        ``distance_to_origin_m`` (sensors missing from the calibration are left out).
    """
    origin = rig.marker(result.origin_marker).T_world_marker[:3, 3]
    joint = result.T_world_sensor_joint or result.T_world_sensor
    out: dict[str, dict[str, Any]] = {}
    for s in rig.sensors:
        if s.id not in result.T_world_sensor:
            continue
        tc, rc = pose_error(result.T_world_sensor_chained[s.id], s.T_world_sensor)
        to, ro = pose_error(joint[s.id], s.T_world_sensor)
        tf, rf = pose_error(result.T_world_sensor[s.id], s.T_world_sensor)
        out[s.id] = {
            "chained_pos_m": tc, "chained_rot_deg": float(np.degrees(rc)),
            "optimised_pos_m": to, "optimised_rot_deg": float(np.degrees(ro)),
            "final_pos_m": tf, "final_rot_deg": float(np.degrees(rf)),
            "distance_to_origin_m": float(np.linalg.norm(s.position - origin)),
        }
    return out
