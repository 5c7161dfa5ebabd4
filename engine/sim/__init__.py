"""The simulated lab: the embedded default of gaitrig and its test bed.

* :mod:`engine.sim.rig` — Kinect v2 sensor model, sensors, floor markers, the seed
  paper's six-sensor avenue (:func:`~engine.sim.rig.default_avenue_rig`), rig files.
* :mod:`engine.sim.clock` — per-sensor clocks (offset, drift) and jittered frame times.
* :mod:`engine.sim.walker` — an articulated walker with exact ground truth (joints, foot
  placements, gait events, bone frames, body mesh).
* :mod:`engine.sim.render` — ray-cast depth, body index and colour with ArUco floor markers.
* :mod:`engine.sim.skeleton_model` — Kinect-like skeletons with literature-based errors.
* :mod:`engine.sim.world` — everything together, frame by frame, for the ``sim`` node.
* :mod:`engine.sim.imu` — simulated IMUs on the walker's bones (IMU helper).

The names of ``__all__`` import from this package (``from engine.sim import Walker``);
each is loaded from its module on first use, so importing the package stays cheap.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from engine import _lazy_exports

#: public name → the module that defines it
_EXPORTS: dict[str, str] = {
    "Rig": "engine.sim.rig",
    "SimSensor": "engine.sim.rig",
    "SensorModel": "engine.sim.rig",
    "FloorMarker": "engine.sim.rig",
    "Walkway": "engine.sim.rig",
    "Room": "engine.sim.rig",
    "default_avenue_rig": "engine.sim.rig",
    "sensor_pose": "engine.sim.rig",
    "load_rig": "engine.sim.rig",
    "save_rig": "engine.sim.rig",
    "SimClock": "engine.sim.clock",
    "frame_times": "engine.sim.clock",
    "Walker": "engine.sim.walker",
    "WalkerParams": "engine.sim.walker",
    "SensorRenderer": "engine.sim.render",
    "SimFrame": "engine.sim.render",
    "render_frame": "engine.sim.render",
    "SkeletonErrorModel": "engine.sim.skeleton_model",
    "observe_skeletons": "engine.sim.skeleton_model",
    "SimWorld": "engine.sim.world",
    "ImuNoise": "engine.sim.imu",
    "simulate_imu": "engine.sim.imu",
    "simulate_imus": "engine.sim.imu",
    "simulate_walker_imus": "engine.sim.imu",
    "SynthWalk": "engine.sim.straight_walk",
    "synth_walk": "engine.sim.straight_walk",
    "walk_markers": "engine.sim.straight_walk",
    "walk_skeleton": "engine.sim.straight_walk",
    "six_sensor_streams": "engine.sim.straight_walk",
}

__all__ = [
    "FloorMarker",
    "ImuNoise",
    "Rig",
    "Room",
    "SensorModel",
    "SensorRenderer",
    "SimClock",
    "SimFrame",
    "SimSensor",
    "SimWorld",
    "SkeletonErrorModel",
    "SynthWalk",
    "Walker",
    "WalkerParams",
    "Walkway",
    "default_avenue_rig",
    "frame_times",
    "load_rig",
    "observe_skeletons",
    "render_frame",
    "save_rig",
    "sensor_pose",
    "simulate_imu",
    "simulate_imus",
    "simulate_walker_imus",
    "six_sensor_streams",
    "synth_walk",
    "walk_markers",
    "walk_skeleton",
]

if TYPE_CHECKING:  # what type checkers see; at run time __getattr__ loads them
    from engine.sim.clock import SimClock, frame_times
    from engine.sim.imu import ImuNoise, simulate_imu, simulate_imus, simulate_walker_imus
    from engine.sim.render import SensorRenderer, SimFrame, render_frame
    from engine.sim.rig import (
        FloorMarker,
        Rig,
        Room,
        SensorModel,
        SimSensor,
        Walkway,
        default_avenue_rig,
        load_rig,
        save_rig,
        sensor_pose,
    )
    from engine.sim.skeleton_model import SkeletonErrorModel, observe_skeletons
    from engine.sim.straight_walk import (
        SynthWalk,
        six_sensor_streams,
        synth_walk,
        walk_markers,
        walk_skeleton,
    )
    from engine.sim.walker import Walker, WalkerParams
    from engine.sim.world import SimWorld

__getattr__, __dir__ = _lazy_exports(__name__, _EXPORTS, globals())
