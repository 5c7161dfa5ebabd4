"""gaitrig engine: pure computation over arrays (numpy, scipy, open3d, opencv).

No web, no database, no global state. Files are read or written only by explicit
``load_*``/``save_*``/``read_*``/``write_*`` functions. Time is the first axis of every
series. Units are SI (m, s, rad); the world frame is right-handed, Z up, origin at
marker 1. Transforms are 4×4 and named ``T_<to>_<from>``; quaternions are w-first.

The names most analyses need are importable from here (``from engine import
GaitAnalysis, load_feet``); each is loaded from its module on first use, so ``import
engine`` stays cheap. Where things live:

* files → trajectories: :func:`~engine.mocap.load_feet` (C3D/TRC/skeleton CSV → per-foot
  trajectories in m, Z up; units, up axis and marker names detected),
  :mod:`engine.io` (``read_c3d``, ``read_trc``, ``read_skeleton_csv`` and the writers);
* gait: :class:`~engine.gait.GaitAnalysis` (``fit`` → ``steps_``, ``strides_``,
  ``events_``, ``passes_``, ``summary_``; ``to_records`` for tables, ``to_dict`` for the
  JSON document of ``docs/gait-json.md``); :func:`~engine.gait.gait_cycles` splits events
  into gait cycles (:class:`~engine.gait.GaitCycle`);
* other files: :func:`~engine.pointcloud.load_point_cloud`,
  :func:`~engine.pointcloud.load_depth_image`, :func:`~engine.pointcloud.load_intrinsics`
  (point clouds, depth images, camera intrinsics of other labs and tools),
  :func:`~engine.imu.io.load_imu` (IMU recordings);
* several sensors → one skeleton: :func:`~engine.integration.integrate_skeletons`;
* agreement with a reference (seed 000's statistics): :mod:`engine.agreement`;
* skeletons and joint sets: :mod:`engine.skeleton` (``SkeletonSeries.to_columns`` gives
  the named columns of the skeleton CSV, for pandas); SE(3)/quaternions:
  :mod:`engine.geometry`; comparing two motions (DTW): :mod:`engine.compare`;
* calibration, coverage, IMU fusion, KSCC, reports, the simulated lab:
  :mod:`engine.calibration`, :mod:`engine.coverage`, :mod:`engine.imu`,
  :mod:`engine.kscc`, :mod:`engine.report`, :mod:`engine.sim`;
* errors: every user-caused problem raises a :class:`~engine.errors.GaitrigError`
  (:class:`~engine.errors.InputError`, :class:`~engine.errors.InsufficientDataError`,
  :class:`~engine.errors.CalibrationError`) whose message says what to fix.

Each subpackage re-exports its own public names the same way (``from engine.imu import
load_mvnx_all``, ``from engine.sim import Walker``); ``docs/engine-api.md`` lists every
exported name with one line. Worked scripts: ``examples/vicon_trial.py`` (a real Vicon
trial), ``examples/fuse_skeletons.py``, ``examples/calibrate_simulated.py``,
``examples/imu_orientation.py``; more in ``docs/research.md``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

#: public name → the module that defines it
_EXPORTS: dict[str, str] = {
    "GaitAnalysis": "engine.gait", "GaitEvent": "engine.gait", "Step": "engine.gait",
    "Stride": "engine.gait", "WalkPass": "engine.gait",
    "FeetTrajectories": "engine.mocap", "load_feet": "engine.mocap",
    "feet_from_markers": "engine.mocap", "feet_from_skeleton": "engine.mocap",
    "MarkerTrajectories": "engine.io.markers", "MarkerEvent": "engine.io.markers",
    "read_c3d": "engine.io.c3d", "write_c3d": "engine.io.c3d",
    "write_skeleton_c3d": "engine.io.c3d",
    "read_trc": "engine.io.trc", "write_trc": "engine.io.trc",
    "read_skeleton_csv": "engine.io.csv", "write_skeleton_csv": "engine.io.csv",
    "SkeletonSeries": "engine.skeleton", "TrackingState": "engine.skeleton",
    "JointSet": "engine.skeleton", "joint_set_for": "engine.skeleton",
    "SensorStream": "engine.integration", "integrate_skeletons": "engine.integration",
    # not the function ``agreement``: ``engine.agreement`` is its module
    "Agreement": "engine.agreement", "agreement_levels": "engine.agreement",
    "match_steps": "engine.agreement", "match_events": "engine.agreement",
    "bland_altman_png": "engine.agreement", "AgreementStudy": "engine.agreement",
    "StudyRow": "engine.agreement", "StudyTrial": "engine.agreement",
    "GaitCycle": "engine.gait", "gait_cycles": "engine.gait",
    "load_point_cloud": "engine.pointcloud", "load_depth_image": "engine.pointcloud",
    "load_intrinsics": "engine.pointcloud", "load_imu": "engine.imu.io",
    "CameraIntrinsics": "engine.pointcloud", "depth_to_points": "engine.pointcloud",
    "pixel_ray_table": "engine.pointcloud", "jump_edge_pixels": "engine.pointcloud",
    "ImuRecording": "engine.imu.io", "load_mvnx_all": "engine.imu.io",
    "load_phone": "engine.imu.io", "orientation_filter": "engine.imu.filter",
    "process_imu_session": "engine.imu.pipeline",
    "calibrate_frames": "engine.calibration.pipeline",
    "CalibrationResult": "engine.calibration.pipeline",
    "simulate_capture": "engine.calibration.simcapture",
    "load_kscc": "engine.kscc", "save_kscc": "engine.kscc",
    "KsccCalibrator": "engine.kscc", "compare_motions": "engine.compare",
    "GaitrigError": "engine.errors", "InputError": "engine.errors",
    "InsufficientDataError": "engine.errors", "CalibrationError": "engine.errors",
}

__all__ = [
    "Agreement",
    "AgreementStudy",
    "CalibrationError",
    "CalibrationResult",
    "CameraIntrinsics",
    "FeetTrajectories",
    "GaitAnalysis",
    "GaitCycle",
    "GaitEvent",
    "GaitrigError",
    "ImuRecording",
    "InputError",
    "InsufficientDataError",
    "JointSet",
    "KsccCalibrator",
    "MarkerEvent",
    "MarkerTrajectories",
    "SensorStream",
    "SkeletonSeries",
    "Step",
    "Stride",
    "StudyRow",
    "StudyTrial",
    "TrackingState",
    "WalkPass",
    "__version__",
    "agreement_levels",
    "bland_altman_png",
    "calibrate_frames",
    "compare_motions",
    "depth_to_points",
    "feet_from_markers",
    "feet_from_skeleton",
    "gait_cycles",
    "integrate_skeletons",
    "joint_set_for",
    "jump_edge_pixels",
    "load_depth_image",
    "load_feet",
    "load_imu",
    "load_intrinsics",
    "load_kscc",
    "load_mvnx_all",
    "load_phone",
    "load_point_cloud",
    "match_events",
    "match_steps",
    "orientation_filter",
    "pixel_ray_table",
    "process_imu_session",
    "read_c3d",
    "read_skeleton_csv",
    "read_trc",
    "save_kscc",
    "simulate_capture",
    "write_c3d",
    "write_skeleton_c3d",
    "write_skeleton_csv",
    "write_trc",
]

if TYPE_CHECKING:  # what type checkers and IDEs see; at run time __getattr__ loads them
    from engine.agreement import (
        Agreement,
        AgreementStudy,
        StudyRow,
        StudyTrial,
        agreement_levels,
        bland_altman_png,
        match_events,
        match_steps,
    )
    from engine.calibration.pipeline import CalibrationResult, calibrate_frames
    from engine.calibration.simcapture import simulate_capture
    from engine.compare import compare_motions
    from engine.errors import (
        CalibrationError,
        GaitrigError,
        InputError,
        InsufficientDataError,
    )
    from engine.gait import (
        GaitAnalysis,
        GaitCycle,
        GaitEvent,
        Step,
        Stride,
        WalkPass,
        gait_cycles,
    )
    from engine.imu.filter import orientation_filter
    from engine.imu.io import ImuRecording, load_imu, load_mvnx_all, load_phone
    from engine.imu.pipeline import process_imu_session
    from engine.integration import SensorStream, integrate_skeletons
    from engine.io.c3d import read_c3d, write_c3d, write_skeleton_c3d
    from engine.io.csv import read_skeleton_csv, write_skeleton_csv
    from engine.io.markers import MarkerEvent, MarkerTrajectories
    from engine.io.trc import read_trc, write_trc
    from engine.kscc import KsccCalibrator, load_kscc, save_kscc
    from engine.mocap import FeetTrajectories, feet_from_markers, feet_from_skeleton, load_feet
    from engine.pointcloud import (
        CameraIntrinsics,
        depth_to_points,
        jump_edge_pixels,
        load_depth_image,
        load_intrinsics,
        load_point_cloud,
        pixel_ray_table,
    )
    from engine.skeleton import JointSet, SkeletonSeries, TrackingState, joint_set_for


def _lazy_exports(package: str, exports: dict[str, str], namespace: dict[str, Any]
                  ) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The module-level ``__getattr__`` and ``__dir__`` of a package with lazy re-exports.

    Each name of ``exports`` is imported from its module on first use (PEP 562), so
    importing a package (or any of its submodules, which imports the package first) loads
    nothing heavy. ``engine`` and each subpackage use it the same way.

    Args:
        package: The package's ``__name__`` (used in the error message).
        exports: Public name -> the module that defines it.
        namespace: The package's ``globals()``: a loaded name is cached there, so later
            look-ups skip ``__getattr__``.

    Returns:
        ``(__getattr__, __dir__)`` to assign at the package's module level.
    """

    def getattr_(name: str) -> Any:
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        namespace[name] = value
        return value

    def dir_() -> list[str]:
        return sorted({*namespace, *exports})

    return getattr_, dir_


__getattr__, __dir__ = _lazy_exports(__name__, _EXPORTS, globals())
