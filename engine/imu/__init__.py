"""IMU fusion (seed paper 002): orientation filters, import, jump sync, fused skeleton.

Modules:
    madgwick: Madgwick's gradient-descent filter (IMU/MARG), matching ``ahrs``.
    filter: gaitrig's orientation filter (rest/bias/disturbance handling; ENU output).
    io: x-IMU/Shimmer/Xsens CSV, Madgwick .mat, BROAD and APDM HDF5, Xsens .mvnx, phone
        apps' zips, generic CSV -> ``ImuRecording`` (SI units, time first axis).
    sync: five-jump synchronisation of IMU streams and the depth skeleton.
    fusion: plank calibration, bone mapping, fused skeleton, joint angles, RMSE/NCC.
    metrics: BROAD orientation error measure, RMSE, NCC.
    pipeline: end-to-end session processing and CSV export.

The names of ``__all__`` import from this package (``from engine.imu import load_imu``);
each is loaded from its module on first use, so importing the package stays cheap.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from engine import _lazy_exports

#: public name → the module that defines it
_EXPORTS: dict[str, str] = {
    "ImuRecording": "engine.imu.io",
    "MultipleSensorsError": "engine.imu.io",
    "load_imu": "engine.imu.io",
    "load_csv": "engine.imu.io",
    "load_xio_csv": "engine.imu.io",
    "load_madgwick_mat": "engine.imu.io",
    "load_broad": "engine.imu.io",
    "load_apdm": "engine.imu.io",
    "load_mvnx": "engine.imu.io",
    "load_mvnx_all": "engine.imu.io",
    "load_phone": "engine.imu.io",
    "fill_gaps": "engine.imu.io",
    "Madgwick": "engine.imu.madgwick",
    "to_enu": "engine.imu.madgwick",
    "from_enu": "engine.imu.madgwick",
    "orientation_filter": "engine.imu.filter",
    "OrientationFilter": "engine.imu.filter",
    "FilterParams": "engine.imu.filter",
    "synchronize": "engine.imu.sync",
    "SyncResult": "engine.imu.sync",
    "shift_recording": "engine.imu.sync",
    "plank_calibration": "engine.imu.fusion",
    "PlankCalibration": "engine.imu.fusion",
    "fuse_skeleton": "engine.imu.fusion",
    "FusedSkeleton": "engine.imu.fusion",
    "joint_rotation": "engine.imu.fusion",
    "flexion_angles": "engine.imu.fusion",
    "orientation_errors": "engine.imu.metrics",
    "rmse": "engine.imu.metrics",
    "ncc": "engine.imu.metrics",
    "process_imu_session": "engine.imu.pipeline",
    "ImuSessionResult": "engine.imu.pipeline",
    "angles_csv": "engine.imu.pipeline",
}

__all__ = [
    "FilterParams",
    "FusedSkeleton",
    "ImuRecording",
    "ImuSessionResult",
    "Madgwick",
    "MultipleSensorsError",
    "OrientationFilter",
    "PlankCalibration",
    "SyncResult",
    "angles_csv",
    "fill_gaps",
    "flexion_angles",
    "from_enu",
    "fuse_skeleton",
    "joint_rotation",
    "load_apdm",
    "load_broad",
    "load_csv",
    "load_imu",
    "load_madgwick_mat",
    "load_mvnx",
    "load_mvnx_all",
    "load_phone",
    "load_xio_csv",
    "ncc",
    "orientation_errors",
    "orientation_filter",
    "plank_calibration",
    "process_imu_session",
    "rmse",
    "shift_recording",
    "synchronize",
    "to_enu",
]

if TYPE_CHECKING:  # what type checkers see; at run time __getattr__ loads them
    from engine.imu.filter import FilterParams, OrientationFilter, orientation_filter
    from engine.imu.fusion import (
        FusedSkeleton,
        PlankCalibration,
        flexion_angles,
        fuse_skeleton,
        joint_rotation,
        plank_calibration,
    )
    from engine.imu.io import (
        ImuRecording,
        MultipleSensorsError,
        fill_gaps,
        load_apdm,
        load_broad,
        load_csv,
        load_imu,
        load_madgwick_mat,
        load_mvnx,
        load_mvnx_all,
        load_phone,
        load_xio_csv,
    )
    from engine.imu.madgwick import Madgwick, from_enu, to_enu
    from engine.imu.metrics import ncc, orientation_errors, rmse
    from engine.imu.pipeline import ImuSessionResult, angles_csv, process_imu_session
    from engine.imu.sync import SyncResult, shift_recording, synchronize

__getattr__, __dir__ = _lazy_exports(__name__, _EXPORTS, globals())
