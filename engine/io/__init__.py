"""File readers and writers.

* :mod:`engine.io.markers` — :class:`MarkerTrajectories` (mocap markers in metres),
  unit and vertical-axis detection.
* :mod:`engine.io.c3d` — C3D via ezc3d (points, labels, rate, units, EVENT group);
  skeleton export.
* :mod:`engine.io.trc` — OpenSim TRC.
* :mod:`engine.io.csv` — skeleton CSV ``time,<Joint>_x,_y,_z[,_state]``.
"""
