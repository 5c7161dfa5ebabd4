"""File readers and writers.

* :mod:`engine.io.markers` — :class:`MarkerTrajectories` (mocap markers in metres),
  unit and vertical-axis detection.
* :mod:`engine.io.c3d` — C3D via ezc3d (points, labels, rate, units, EVENT group);
  skeleton export.
* :mod:`engine.io.trc` — OpenSim TRC.
* :mod:`engine.io.csv` — skeleton CSV ``time,<Joint>_x,_y,_z[,_state]``.

The names of ``__all__`` import from this package (``from engine.io import read_c3d``);
each is loaded from its module on first use, so importing the package stays cheap.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from engine import _lazy_exports

#: public name → the module that defines it
_EXPORTS: dict[str, str] = {
    "MarkerTrajectories": "engine.io.markers",
    "MarkerEvent": "engine.io.markers",
    "detect_units": "engine.io.markers",
    "detect_vertical_axis": "engine.io.markers",
    "to_z_up": "engine.io.markers",
    "up_rotation": "engine.io.markers",
    "unit_scale": "engine.io.markers",
    "read_c3d": "engine.io.c3d",
    "write_c3d": "engine.io.c3d",
    "write_skeleton_c3d": "engine.io.c3d",
    "skeleton_to_markers": "engine.io.c3d",
    "read_trc": "engine.io.trc",
    "write_trc": "engine.io.trc",
    "read_skeleton_csv": "engine.io.csv",
    "write_skeleton_csv": "engine.io.csv",
}

__all__ = [
    "MarkerEvent",
    "MarkerTrajectories",
    "detect_units",
    "detect_vertical_axis",
    "read_c3d",
    "read_skeleton_csv",
    "read_trc",
    "skeleton_to_markers",
    "to_z_up",
    "unit_scale",
    "up_rotation",
    "write_c3d",
    "write_skeleton_c3d",
    "write_skeleton_csv",
    "write_trc",
]

if TYPE_CHECKING:  # what type checkers see; at run time __getattr__ loads them
    from engine.io.c3d import read_c3d, skeleton_to_markers, write_c3d, write_skeleton_c3d
    from engine.io.csv import read_skeleton_csv, write_skeleton_csv
    from engine.io.markers import (
        MarkerEvent,
        MarkerTrajectories,
        detect_units,
        detect_vertical_axis,
        to_z_up,
        unit_scale,
        up_rotation,
    )
    from engine.io.trc import read_trc, write_trc

__getattr__, __dir__ = _lazy_exports(__name__, _EXPORTS, globals())
