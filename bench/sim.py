"""Simulation throughput: one JSON line.

Rendered depth frames/s for one sensor on one core (goal ≥ 30 so six sim nodes can each
stream), with colour, and skeleton observations/s; ``*_vs_30fps`` are ratios to the
Kinect v2 frame rate.
"""

from __future__ import annotations

import json
import time

import numpy as np

from engine.sim.clock import frame_times
from engine.sim.render import SensorRenderer
from engine.sim.rig import default_avenue_rig
from engine.sim.skeleton_model import observe_skeletons
from engine.sim.walker import Walker, WalkerParams


def main() -> None:
    rig = default_avenue_rig(seed=0)
    walker = Walker(WalkerParams(), rig.walkway.start, rig.walkway.end, seed=0)
    sensor = rig.sensor("S3")
    renderer = SensorRenderer(sensor, rig, color_size=(640, 360))
    rng = np.random.default_rng(0)
    times = np.arange(2.0, 6.0, 1 / 30)  # subject in view of S3
    t0 = time.perf_counter()
    for t in times:
        renderer.render([walker.body_mesh(t)], rng, with_color=False)
    depth_fps = len(times) / (time.perf_counter() - t0)
    t0 = time.perf_counter()
    for t in times:
        renderer.render([walker.body_mesh(t)], rng, with_color=True)
    rgbd_fps = len(times) / (time.perf_counter() - t0)
    ft = frame_times(0.0, 60.0, rng)
    t0 = time.perf_counter()
    for s in rig.sensors:
        observe_skeletons(s, rig, walker, ft, rng)
    skel_rate = len(ft) * len(rig.sensors) / (time.perf_counter() - t0)
    print(json.dumps({
        "bench": "sim",
        "depth_frames_per_s": round(depth_fps, 1),
        "depth_vs_30fps": round(depth_fps / 30.0, 2),
        "rgbd_frames_per_s": round(rgbd_fps, 1),
        "rgbd_vs_30fps": round(rgbd_fps / 30.0, 2),
        "skeleton_obs_per_s": round(skel_rate, 1),
        "skeleton_vs_30fps_x6": round(skel_rate / 180.0, 2),
    }))


if __name__ == "__main__":
    main()
