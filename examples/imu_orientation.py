"""Sensor orientation from an IMU file, scored against the file's reference orientation.

    .venv/bin/python examples/imu_orientation.py [FILE] [--demo]

``FILE``: any IMU recording :func:`engine.load_imu` reads (x-IMU/Shimmer/Xsens/generic
CSV, Madgwick's .mat, BROAD .hdf5, APDM .h5, .mvnx, a phone app's .zip); by default the
BROAD trial ``07_undisturbed_fast_rotation_B.hdf5`` of ``../shared/data``. ``--demo``
(or no file and no shared data) simulates the left-shank IMU of a walker who stands 2 s
and then walks, writes it as a generic CSV with its true orientation as ``qw,qx,qy,qz``
columns, and reads that file back — the same code path as a real recording.

Everything is in SI units (time s, rad/s, m/s², µT) with time as the first axis; the
orientations are w-first quaternions, sensor-to-ENU (x east, y north, z up). Three
estimates are compared: gaitrig's filter causal (as live) and offline (zero-phase, bias
known from the start), and Madgwick's filter (β = 0.041) in ENU.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from engine import GaitrigError, ImuRecording, InputError, load_imu, orientation_filter
from engine.imu import Madgwick, orientation_errors
from engine.sim import Walker, WalkerParams, simulate_walker_imus

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_FILE = (ROOT.parent / "shared" / "data" / "imu" / "broad"
                / "07_undisturbed_fast_rotation_B.hdf5")


def write_demo_csv(path: Path, seconds: float = 8.0, rate_hz: float = 256.0) -> Path:
    """Write a simulated left-shank IMU (consumer MEMS noise) as a generic IMU CSV.

    Args:
        path: The CSV to write (columns ``time_s``, ``gyr_x_rads`` ..., ``acc_x_ms2`` ...,
            ``mag_x_ut`` ..., ``qw, qx, qy, qz``: the true sensor-to-ENU orientation).
        seconds: Length of the recording (s); the walker stands for the first 2 s.
        rate_hz: Sampling rate (Hz).

    Returns:
        ``path``.
    """
    walker = Walker(WalkerParams(), [0.0, 0.0, 0.0], [8.0, 0.0, 0.0], start_time=2.0, seed=1)
    t = np.arange(0.0, seconds, 1.0 / rate_hz)
    rec = simulate_walker_imus(walker, t, sensors={"shank_l": "shank_l"})["shank_l"]
    assert rec.mag is not None and rec.quat_ref is not None  # the simulator gives both
    cols = np.column_stack([rec.time, rec.gyr, rec.acc, rec.mag, rec.quat_ref])
    header = ("time_s,gyr_x_rads,gyr_y_rads,gyr_z_rads,acc_x_ms2,acc_y_ms2,acc_z_ms2,"
              "mag_x_ut,mag_y_ut,mag_z_ut,qw,qx,qy,qz")
    np.savetxt(path, cols, delimiter=",", header=header, comments="", fmt="%.9g")
    return path


def estimate(path: Path, quat_frame: str | None = None) -> dict[str, dict[str, float]]:
    """Read ``path``, estimate its orientation three ways and score each.

    Args:
        path: An IMU recording with a reference orientation (BROAD, or a CSV with
            quaternion columns, as :func:`write_demo_csv` writes).
        quat_frame: Earth frame of a CSV's reference quaternions (``"ENU"``/``"NED"``);
            None: told from gravity by the reader.

    Returns:
        Estimate name (``gaitrig causal``, ``gaitrig offline``, ``madgwick``) ->
        :func:`engine.imu.orientation_errors` (``total_deg``, ``heading_deg``,
        ``inclination_deg``: RMS over the file's movement phase, or all samples).

    Raises:
        InputError: the file cannot be read, or it has no reference orientation.
    """
    rec: ImuRecording = load_imu(path, quat_frame=quat_frame)
    print(f"{path.name}: {len(rec)} samples at {rec.frequency:.1f} Hz "
          f"({rec.time[-1] - rec.time[0]:.1f} s), format {rec.meta.get('format')}, "
          f"magnetometer {'yes' if rec.mag is not None else 'no'}")
    for w in rec.warnings:
        print(f"  note: {w}")
    if rec.quat_ref is None:
        raise InputError(f"{path.name} has no reference orientation to compare with "
                         "(BROAD trials and CSVs with qw,qx,qy,qz columns have one)")
    q_causal, bias, _ = orientation_filter(rec.gyr, rec.acc, rec.mag,
                                           frequency=rec.frequency)
    q_offline, _, _ = orientation_filter(rec.gyr, rec.acc, rec.mag, frequency=rec.frequency,
                                         offline=True)
    q_madgwick = Madgwick(frequency=rec.frequency, frame="ENU").fit(
        rec.gyr, rec.acc, rec.mag).quat_
    assert q_madgwick is not None  # set by fit
    print(f"gyroscope bias estimated at the end: "
          f"{np.degrees(np.linalg.norm(bias[-1])):.2f} °/s")
    out: dict[str, dict[str, float]] = {}
    print("\nestimate          total   heading  inclination (RMS, degrees)")
    for name, q in (("gaitrig causal", q_causal), ("gaitrig offline", q_offline),
                    ("madgwick", q_madgwick)):
        e = orientation_errors(q, rec.quat_ref, rec.movement)
        out[name] = e
        print(f"{name:<16} {e['total_deg']:6.2f}  {e['heading_deg']:7.2f}  "
              f"{e['inclination_deg']:9.2f}")
    return out


def main(argv: list[str] | None = None) -> int:
    """Command line: see the module docstring. Returns the exit code."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("file", type=Path, nargs="?", help="IMU recording (default: BROAD trial)")
    ap.add_argument("--demo", action="store_true", help="simulate a recording instead")
    args = ap.parse_args(argv)
    try:
        if args.demo or (args.file is None and not DEFAULT_FILE.is_file()):
            with tempfile.TemporaryDirectory() as tmp:
                estimate(write_demo_csv(Path(tmp) / "shank_l.csv"), "ENU")
        else:
            estimate(args.file or DEFAULT_FILE)
    except GaitrigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
