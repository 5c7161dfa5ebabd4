"""Spatial calibration (issue 3): printable markers, detection, 3D corners from depth, the
sensor/marker graph with chaining (seed 000), joint pose-graph optimisation, ICP
refinement, versioned storage and the bumped-tripod check.

Modules: ``markers`` (dictionaries, sheets), ``detect`` (sub-pixel + pattern-fit corners,
marker pose), ``corners3d`` (plane fit, frame averaging, rejection reasons), ``graph``
(Procrustes edges, connectivity, chaining), ``posegraph`` (joint least squares),
``icp`` (guarded ICP), ``pipeline`` (``calibrate``, ``calibrate_frames``), ``store``
(save/load/versions/``check_moved``), ``simcapture`` (simulated capture and scoring).

The names of ``__all__`` import from this package
(``from engine.calibration import calibrate_frames``);
each is loaded from its module on first use, so importing the package stays cheap.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from engine import _lazy_exports

#: public name → the module that defines it
_EXPORTS: dict[str, str] = {
    "calibrate": "engine.calibration.pipeline",
    "calibrate_frames": "engine.calibration.pipeline",
    "CalibrationResult": "engine.calibration.pipeline",
    "apply_icp": "engine.calibration.pipeline",
    "SensorFrames": "engine.calibration.corners3d",
    "Observation": "engine.calibration.corners3d",
    "observe_sensor": "engine.calibration.corners3d",
    "detect_markers": "engine.calibration.detect",
    "DetectionSet": "engine.calibration.detect",
    "MarkerDetection": "engine.calibration.detect",
    "estimate_marker_pose": "engine.calibration.detect",
    "MarkerPose": "engine.calibration.detect",
    "load_image": "engine.calibration.detect",
    "write_marker_sheet": "engine.calibration.markers",
    "marker_image": "engine.calibration.markers",
    "get_dictionary": "engine.calibration.markers",
    "save_calibration": "engine.calibration.store",
    "load_calibration": "engine.calibration.store",
    "save_version": "engine.calibration.store",
    "load_version": "engine.calibration.store",
    "list_versions": "engine.calibration.store",
    "check_moved": "engine.calibration.store",
    "check_frames": "engine.calibration.moved",
    "SensorCheck": "engine.calibration.moved",
    "optimise_poses": "engine.calibration.posegraph",
    "PoseGraphResult": "engine.calibration.posegraph",
    "refine_with_icp": "engine.calibration.icp",
    "icp_align": "engine.calibration.icp",
    "simulate_capture": "engine.calibration.simcapture",
    "pose_errors": "engine.calibration.simcapture",
}

__all__ = [
    "CalibrationResult",
    "DetectionSet",
    "MarkerDetection",
    "MarkerPose",
    "Observation",
    "PoseGraphResult",
    "SensorCheck",
    "SensorFrames",
    "apply_icp",
    "calibrate",
    "calibrate_frames",
    "check_frames",
    "check_moved",
    "detect_markers",
    "estimate_marker_pose",
    "get_dictionary",
    "icp_align",
    "list_versions",
    "load_calibration",
    "load_image",
    "load_version",
    "marker_image",
    "observe_sensor",
    "optimise_poses",
    "pose_errors",
    "refine_with_icp",
    "save_calibration",
    "save_version",
    "simulate_capture",
    "write_marker_sheet",
]

if TYPE_CHECKING:  # what type checkers see; at run time __getattr__ loads them
    from engine.calibration.corners3d import Observation, SensorFrames, observe_sensor
    from engine.calibration.detect import (
        DetectionSet,
        MarkerDetection,
        MarkerPose,
        detect_markers,
        estimate_marker_pose,
        load_image,
    )
    from engine.calibration.icp import icp_align, refine_with_icp
    from engine.calibration.markers import get_dictionary, marker_image, write_marker_sheet
    from engine.calibration.moved import SensorCheck, check_frames
    from engine.calibration.pipeline import (
        CalibrationResult,
        apply_icp,
        calibrate,
        calibrate_frames,
    )
    from engine.calibration.posegraph import PoseGraphResult, optimise_poses
    from engine.calibration.simcapture import pose_errors, simulate_capture
    from engine.calibration.store import (
        check_moved,
        list_versions,
        load_calibration,
        load_version,
        save_calibration,
        save_version,
    )

__getattr__, __dir__ = _lazy_exports(__name__, _EXPORTS, globals())
