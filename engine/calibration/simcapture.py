"""Calibration capture in the simulator: colour + noisy depth of the floor markers.

Used by ``gaitrig calibrate --rig ...``, the tests and ``bench/calibration.py`` to measure
the calibration against the simulator's true sensor poses.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from engine.calibration.corners3d import DEFAULT_FRAMES, SensorFrames
from engine.calibration.pipeline import CalibrationResult
from engine.geometry import pose_error
from engine.sim.render import SensorRenderer
from engine.sim.rig import Rig

#: Colour size for marker detection (the simulator's renderer defaults to 640×360; floor
#: markers 4 m away need ≥ 960×540 to decode).
CAPTURE_COLOR_SIZE = (960, 540)
#: Colour read noise (1σ, 8-bit levels) added per frame when noise is on.
COLOR_NOISE_DN = 2.0


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
    """
    rng = np.random.default_rng(seed) if noise else None
    out = []
    for s in rig.sensors:
        r = SensorRenderer(s, rig, color_size=color_size)
        rendered = [r.render([], rng) for _ in range(frames)]
        colors = [f.color for f in rendered if f.color is not None]
        if rng is not None:  # camera read noise (the renderer's colour is noise-free)
            colors = [np.clip(c + rng.normal(0.0, COLOR_NOISE_DN, c.shape), 0, 255)
                      .astype(np.uint8) for c in colors]
        out.append(SensorFrames(
            sensor_id=s.id,
            colors=colors,
            depths=[f.depth for f in rendered],
            depth_intrinsics=rendered[0].K_depth,
            color_intrinsics=r.K_color,
            T_depth_color=s.model.T_depth_color,
            depth_scale=1000.0,
        ))
    return out


def pose_errors(result: CalibrationResult, rig: Rig) -> dict[str, dict[str, Any]]:
    """Per sensor: position (m) and rotation (deg) errors of the chained and optimised
    estimates against the rig's true poses, and the distance to the origin marker."""
    origin = rig.marker(result.origin_marker).T_world_marker[:3, 3]
    out: dict[str, dict[str, Any]] = {}
    for s in rig.sensors:
        if s.id not in result.T_world_sensor:
            continue
        tc, rc = pose_error(result.T_world_sensor_chained[s.id], s.T_world_sensor)
        to, ro = pose_error(result.T_world_sensor[s.id], s.T_world_sensor)
        out[s.id] = {
            "chained_pos_m": tc, "chained_rot_deg": float(np.degrees(rc)),
            "optimised_pos_m": to, "optimised_rot_deg": float(np.degrees(ro)),
            "distance_to_origin_m": float(np.linalg.norm(s.position - origin)),
        }
    return out
