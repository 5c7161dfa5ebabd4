"""Spatial calibration (issue 3): printable markers, detection, 3D corners from depth, the
sensor/marker graph with chaining (seed 000), joint pose-graph optimisation, ICP
refinement, versioned storage and the bumped-tripod check.

Modules: ``markers`` (dictionaries, sheets), ``detect`` (sub-pixel + pattern-fit corners,
marker pose), ``corners3d`` (plane fit, frame averaging, rejection reasons), ``graph``
(Procrustes edges, connectivity, chaining), ``posegraph`` (joint least squares),
``icp`` (guarded ICP), ``pipeline`` (``calibrate``, ``calibrate_frames``), ``store``
(save/load/versions/``check_moved``), ``simcapture`` (simulated capture and scoring).
"""
