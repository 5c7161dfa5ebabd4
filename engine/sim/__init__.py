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
"""
