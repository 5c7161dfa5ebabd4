"""IMU files from other labs and devices, checked against an optical ground truth.

Base: the first 60 s of BROAD's ``07_undisturbed_fast_rotation_B`` (285.7 Hz, 9D, with its
optical reference orientation and movement mask). It is rewritten as other vendors and
tools write their exports — column names (Arduino ``ax…gz``, PicoQuake ``a_x…g_z``,
Physics Toolbox ``gFx/wx/Bx``, Axivity ``Ax(g)/Gx(d/s)``, Noraxon-, Delsys- and Xsens MT
Manager-style prefixed columns, phone loggers' ISO time stamps), units (g, mG, deg/s,
d/s, gauss, nT, a.u.), separators and decimal commas, time in ISO strings, integer ms,
µs, a wrapping counter or clock, reference quaternions scalar-first or -last, ENU or NED
— and resampled to 50-1000 Hz, with dropped samples, NaN rows and time jitter.

Each variant is read with :func:`engine.imu.io.load_imu` and must give the base's SI
values (to the text's precision), and the offline filter on it the base's orientation
error against the optical reference (BROAD's error measure): the same to 0.05° for a
rewrite of the same samples. Where the samples change (another rate, jitter, NaN rows)
the tolerances are measured ones with their reason. A reference quaternion read from the
variant's own columns must give the same error as BROAD's own reference.
"""

from __future__ import annotations

import tracemalloc
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from engine.errors import InputError
from engine.geometry import quat_mul
from engine.imu.filter import orientation_filter
from engine.imu.fusion import interp_quat
from engine.imu.io import G, ImuRecording, fill_gaps, load_imu
from engine.imu.metrics import orientation_errors

TRIAL = "imu/broad/07_undisturbed_fast_rotation_B.hdf5"
SECONDS = 60.0  # 26.5 s at rest, then the rotation: the filter's bias start and motion


@pytest.fixture(scope="module")
def base(shared_data: Path) -> ImuRecording:
    r = load_imu(shared_data / TRIAL)
    n = int(SECONDS * r.frequency)
    assert r.mag is not None and r.quat_ref is not None and r.movement is not None
    return replace(
        r,
        time=r.time[:n],
        gyr=r.gyr[:n],
        acc=r.acc[:n],
        mag=r.mag[:n],
        quat_ref=r.quat_ref[:n],
        movement=r.movement[:n],
        warnings=[],
    )


def errors(
    rec: ImuRecording, ref: np.ndarray, movement: np.ndarray | None, nine_d: bool = True
) -> dict[str, float]:
    q, _, _ = orientation_filter(
        rec.gyr, rec.acc, rec.mag if nine_d else None, frequency=rec.frequency, offline=True
    )
    return orientation_errors(q, ref, movement)


@pytest.fixture(scope="module")
def truth(base: ImuRecording) -> dict[str, dict[str, float]]:
    assert base.quat_ref is not None
    return {
        "9d": errors(base, base.quat_ref, base.movement),
        "6d": errors(base, base.quat_ref, base.movement, nine_d=False),
    }


def _cell(v: float, decimal: str) -> str:
    s = "nan" if not np.isfinite(v) else f"{v:.10g}"
    return s.replace(".", decimal)


def write_csv(
    path: Path,
    cols: list[tuple[str, Any]],
    *,
    sep: str = ",",
    decimal: str = ".",
    preamble: str = "",
) -> Path:
    """Columns of numbers (or of strings: ISO time) under one header row."""
    names = [n for n, _ in cols]
    data = [c if isinstance(c, list) else [_cell(float(v), decimal) for v in c] for _, c in cols]
    lines = [sep.join(names)] + [sep.join(row) for row in zip(*data, strict=True)]
    path.write_text(preamble + "\n".join(lines) + "\n", encoding="utf-8")
    return path


def xyz(name: str, arr: np.ndarray, factor: float = 1.0) -> list[tuple[str, Any]]:
    """Three columns ``name`` formatted with X/Y/Z (``{}``), values in file units."""
    return [(name.format(a), arr[:, k] / factor) for k, a in enumerate("XYZ")]


def xyz_lower(name: str, arr: np.ndarray, factor: float = 1.0) -> list[tuple[str, Any]]:
    return [(name.format(a), arr[:, k] / factor) for k, a in enumerate("xyz")]


def iso(t: np.ndarray, sep: str = " ", zone: str = "") -> list[str]:
    t0 = datetime(2024, 3, 5, 10, 15, 30, tzinfo=UTC).timestamp()
    return [
        datetime.fromtimestamp(t0 + v, UTC).strftime(f"%Y-%m-%d{sep}%H:%M:%S.%f") + zone for v in t
    ]


DEG = np.pi / 180
UT_PER_GAUSS = 100.0


def variants(
    b: ImuRecording,
) -> dict[str, tuple[list[tuple[str, Any]], dict[str, Any], dict[str, Any]]]:
    """name -> (columns, load_imu kwargs, write options)."""
    assert b.mag is not None and b.quat_ref is not None
    t, g, a, m, q = b.time, b.gyr, b.acc, b.mag, b.quat_ref
    field = float(np.median(np.linalg.norm(m, axis=1)))
    n = len(t)
    return {
        # an Arduino sketch: integer millis (3-4 ms steps at 285.7 Hz), g, deg/s, µT
        "arduino": (
            [
                ("millis", np.round(t * 1000)),
                *xyz_lower("a{}", a, G),
                *xyz_lower("g{}", g, DEG),
                *xyz_lower("m{}", m),
            ],
            {},
            {},
        ),
        # PicoQuake-style: a uint16 counter that wraps, no time, 6D, g and deg/s
        "picoquake_6d": (
            [
                ("count", (np.arange(n) + 60000) % 65536),
                *xyz_lower("a_{}", a, G),
                *xyz_lower("g_{}", g, DEG),
            ],
            {"frequency": b.frequency},
            {},
        ),
        # Physics Toolbox Sensor Suite: g-force, rad/s (too slow to tell: declared), µT
        "physics_toolbox": (
            [("time", t), *xyz_lower("gF{}", a, G), *xyz_lower("w{}", g), *xyz_lower("B{}", m)],
            {"gyr_unit": "rad/s"},
            {},
        ),
        # Axivity OMGUI export: ISO date-times, Ax(g), Gx(d/s)
        "axivity_iso": (
            [("Time", iso(t)), *xyz("A{}(g)", a, G), *xyz("G{}(d/s)", g, DEG), *xyz("M{}(uT)", m)],
            {},
            {},
        ),
        # Noraxon-style prefixed channels, German Excel: ';' and decimal commas, mG and nT
        "noraxon_semicolon": (
            [
                ("Time (s)", t),
                *xyz("Ultium IMU-Accel {} (mG)", a, G / 1000),
                *xyz("Ultium IMU-Gyro {} (deg/s)", g, DEG),
                *xyz("Ultium IMU-Mag {} (nT)", m, 0.001),
            ],
            {},
            {"sep": ";", "decimal": ","},
        ),
        # Delsys-style "<sensor>: <channel> [unit]", tab separated
        "delsys_tab": (
            [
                ("Time [s]", t),
                *xyz("Trigno IMU 1: ACC {} [g]", a, G),
                *xyz("Trigno IMU 1: GYRO {} [deg/s]", g, DEG),
                *xyz("Trigno IMU 1: MAG {} [uT]", m),
            ],
            {},
            {"sep": "\t"},
        ),
        # Xsens MT Manager: counter, 100 µs clock, m/s², rad/s (declared), a.u. field,
        # its own orientation as Quat_q0..q3 (scalar first, ENU)
        "xsens_mt_manager": (
            [
                ("PacketCounter", np.arange(n) % 65536),
                ("SampleTimeFine", np.round(t * 1e4 + 2**32 - 30000) % 2**32),
            ]
            + [(f"Quat_q{k}", q[:, k]) for k in range(4)]
            + xyz("Acc_{}", a)
            + xyz("Gyr_{}", g)
            + xyz("Mag_{}", m, field),
            {"gyr_unit": "rad/s"},
            {"preamble": "// Start Time: 0\n// Update Rate: 285.7Hz\n"},
        ),
        # a phone logger: ISO with T and Z, units in the names, gauss, reference x-first
        "phone_iso_z": (
            [
                ("timestamp", iso(t, "T", "Z")),
                *xyz_lower("acc_{}_ms2", a),
                *xyz_lower("gyro_{}_dps", g, DEG),
                *xyz_lower("mag_{}_gauss", m, UT_PER_GAUSS),
                ("qx", q[:, 1]),
                ("qy", q[:, 2]),
                ("qz", q[:, 3]),
                ("qw", q[:, 0]),
            ],
            {},
            {},
        ),
        # µs time, reference numbered scalar-last in NED: order and frame from gravity
        "ned_scalar_last": (
            [("time_us", np.round(t * 1e6))]
            + xyz_lower("acc_{}", a)
            + xyz_lower("gyr_{}", g, DEG)
            + xyz_lower("mag_{}", m)
            + [(f"q{k + 1}", v) for k, v in enumerate(_to_ned(q)[:, [1, 2, 3, 0]].T)],
            {},
            {},
        ),
    }


#: NED <- ENU for sensor-to-earth quaternions (the inverse of the reader's conversion)
_Q_NED_ENU = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])


def _to_ned(q: np.ndarray) -> np.ndarray:
    return np.asarray(quat_mul(_Q_NED_ENU, q))


NAMES = [
    "arduino",
    "picoquake_6d",
    "physics_toolbox",
    "axivity_iso",
    "noraxon_semicolon",
    "delsys_tab",
    "xsens_mt_manager",
    "phone_iso_z",
    "ned_scalar_last",
]


@pytest.mark.parametrize("name", NAMES)
def test_vendor_layouts_give_the_same_orientation(
    base: ImuRecording, truth: dict[str, Any], tmp_path: Path, name: str
) -> None:
    cols, kwargs, opts = variants(base)[name]
    p = write_csv(tmp_path / f"{name}.csv", cols, **opts)
    rec = load_imu(p, **kwargs)
    assert len(rec) == len(base)
    # the same samples in SI (the text keeps 10 digits; integer ms: ±0.5 ms)
    t_tol = 6e-4 if name == "arduino" else 2e-6
    assert np.allclose(rec.time - rec.time[0], base.time, atol=t_tol)
    assert np.allclose(rec.gyr, base.gyr, rtol=1e-8, atol=1e-9)
    assert np.allclose(rec.acc, base.acc, rtol=1e-8, atol=1e-9)
    six = name.endswith("_6d")
    assert (rec.mag is None) == six
    if rec.mag is not None and rec.meta.get("mag_unit") != "norm":
        assert np.allclose(rec.mag, base.mag, rtol=1e-8, atol=1e-9)
    assert rec.frequency == pytest.approx(base.frequency, rel=1e-3)
    assert base.quat_ref is not None
    got = errors(rec, base.quat_ref, base.movement, nine_d=not six)
    want = truth["6d" if six else "9d"]
    assert got["total_deg"] == pytest.approx(want["total_deg"], abs=0.05), (got, want)
    if rec.quat_ref is not None:  # the file's own reference, read in the right convention
        own = errors(rec, rec.quat_ref, base.movement)
        assert own["total_deg"] == pytest.approx(want["total_deg"], abs=0.01)
        assert own["heading_deg"] == pytest.approx(want["heading_deg"], abs=0.01)
    has_ref = any(c[0].lower().startswith(("q", "quat")) for c in cols)
    assert (rec.quat_ref is not None) == has_ref, rec.warnings


def test_reference_conventions_declared_or_refused(base: ImuRecording, tmp_path: Path) -> None:
    """Declared order/frame are used as given; a reference that agrees with gravity in no
    reading is set aside with a warning naming what to declare (the data still loads)."""
    assert base.quat_ref is not None
    q = base.quat_ref
    cols = (
        [("time", base.time)]
        + xyz_lower("acc_{}", base.acc)
        + xyz_lower("gyr_{}", base.gyr, DEG)
        + [(f"q{k}", v) for k, v in enumerate(_to_ned(q).T)]
    )
    p = write_csv(tmp_path / "ned.csv", cols)
    rec = load_imu(p, quat_order="wxyz", quat_frame="NED")
    assert rec.quat_ref is not None and rec.meta["quat_ref"]["frame"] == "NED"
    ok = np.all(np.isfinite(q), axis=1)
    d = np.abs(np.sum(rec.quat_ref[ok] * q[ok], axis=1))
    assert np.all(d > 1 - 1e-9)  # the same rotations as BROAD's ENU reference
    # read as ENU against the data's gravity it cannot agree: declared wins, but is odd
    with pytest.raises(InputError, match="quat_frame"):
        load_imu(p, quat_frame="up")
    # another body's orientation (the sensor frame turned 90° about X): no reading agrees
    other = quat_mul(q, np.array([np.sqrt(0.5), np.sqrt(0.5), 0.0, 0.0]))
    p = write_csv(
        tmp_path / "bad.csv", cols[:7] + [(f"q{k}", v) for k, v in enumerate(np.asarray(other).T)]
    )
    rec = load_imu(p)
    assert rec.quat_ref is None
    assert any("declare quat_order" in w for w in rec.warnings)


# ------------------------------------------------------------- sampling and timing


def _resampled(b: ImuRecording, t: np.ndarray) -> tuple[ImuRecording, np.ndarray, np.ndarray]:
    assert b.mag is not None and b.quat_ref is not None and b.movement is not None

    def f(a: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(t, b.time, a[:, k]) for k in range(3)], 1)

    ok = np.all(np.isfinite(b.quat_ref), axis=1)
    ref = interp_quat(b.time[ok], b.quat_ref[ok], t)
    lost = np.interp(t, b.time, (~ok).astype(float)) > 0
    ref[lost] = np.nan
    mov = np.interp(t, b.time, b.movement.astype(float)) > 0.5
    rec = replace(
        b,
        time=t,
        gyr=f(b.gyr),
        acc=f(b.acc),
        mag=f(b.mag),
        frequency=1.0 / float(np.median(np.diff(t))),
        quat_ref=None,
    )
    return rec, ref, mov


@pytest.mark.parametrize(("rate", "extra_deg"), [(50, 1.8), (100, 0.3), (1000, 0.7)])
def test_other_sampling_rates(
    base: ImuRecording, truth: dict[str, Any], tmp_path: Path, rate: float, extra_deg: float
) -> None:
    """The trial resampled to 50-1000 Hz, written with ms time stamps and read back.

    Not the same measurement: linear interpolation of a 3 rad/s rotation at 50 Hz
    changes the rates (the 50 Hz error is 3.7° against 2.1° at the original 285.7 Hz);
    up to 1000 Hz the filter's per-rate behaviour moves the error by 0.6° (measured
    1.1° at 100 Hz, 2.5° at 500 Hz, 2.6° at 1000 Hz). The bound is that plus a margin.
    """
    t = np.arange(0.0, base.time[-1], 1.0 / rate)
    rec, ref, mov = _resampled(base, t)
    p = write_csv(
        tmp_path / "r.csv",
        [
            ("Time (ms)", t * 1000),
            *xyz("Gyroscope {} (deg/s)", rec.gyr, DEG),
            *xyz("Accelerometer {} (g)", rec.acc, G),
            *xyz("Magnetometer {} (uT)", rec.mag),
        ],
    )
    got = load_imu(p)
    assert got.frequency == pytest.approx(rate, rel=1e-6)
    e = errors(got, ref, mov)
    assert e["total_deg"] < truth["9d"]["total_deg"] + extra_deg, e


def test_dropped_samples_are_filled(
    base: ImuRecording, truth: dict[str, Any], tmp_path: Path
) -> None:
    """1 % of the samples lost in bursts of 5 (a Bluetooth link): the filters, which
    assume a constant rate, lose the rotation of each gap — 12° instead of 2.1° — until
    :func:`fill_gaps` puts the samples back on the nominal grid."""
    rng = np.random.default_rng(0)
    keep = np.ones(len(base), bool)
    for s in rng.choice(len(base) - 10, len(base) // 500, replace=False):
        keep[s : s + 5] = False
    cols = [
        ("counter", np.flatnonzero(keep) % 256),
        *xyz_lower("acc_{}", base.acc[keep]),
        *xyz_lower("gyr_{}", base.gyr[keep], DEG),
        *xyz_lower("mag_{}", base.mag[keep]),
    ]  # type: ignore[index]
    rec = load_imu(write_csv(tmp_path / "drop.csv", cols), frequency=base.frequency)
    assert len(rec) == keep.sum() and any("gap" in w for w in rec.warnings)
    assert base.quat_ref is not None
    raw = errors(
        rec,
        base.quat_ref[keep],
        base.movement[keep],  # type: ignore[index]
    )["total_deg"]
    filled = fill_gaps(rec)
    assert len(filled) == len(base)
    assert np.allclose(filled.time, base.time - base.time[0], atol=1e-9)
    assert np.array_equal(filled.gyr[keep], rec.gyr)  # recorded samples untouched
    n_drop = int((~keep).sum())
    assert any(w.startswith(f"{n_drop} dropped samples filled") for w in filled.warnings)
    e = errors(filled, base.quat_ref, base.movement)["total_deg"]
    assert raw > truth["9d"]["total_deg"] + 3.0  # the failure the fill repairs
    assert e == pytest.approx(truth["9d"]["total_deg"], abs=0.1)
    assert fill_gaps(base) is base
    # a gap longer than 0.5 s is left empty (NaN), not invented
    cut = np.ones(len(base), bool)
    cut[10000:10300] = False
    long = fill_gaps(
        replace(
            base,
            time=base.time[cut],
            gyr=base.gyr[cut],
            acc=base.acc[cut],
            mag=base.mag[cut],  # type: ignore[index]
            quat_ref=None,
            movement=None,
        )
    )
    assert np.isnan(long.gyr[10000:10300]).all() and np.isfinite(long.gyr[:10000]).all()


def test_jittered_time_stamps_and_nan_rows(
    base: ImuRecording, truth: dict[str, Any], tmp_path: Path
) -> None:
    """Samples taken at ±30 % jittered instants (a phone's sensor events) and 20 NaN
    rows: read, warned about, and the error moves by less than 0.3° (the jitter alone:
    0.01°, the nominal rate being counted in periods — the mean of the steps under 1.5
    median steps gave 287.9 Hz for 285.7 Hz, and 0.17°; the NaN rows are skipped)."""
    rng = np.random.default_rng(1)
    dt = 1.0 / base.frequency
    tj = np.clip(base.time + rng.uniform(-0.3, 0.3, len(base)) * dt, 0, base.time[-1])
    tj[0] = 0.0
    rec, ref, mov = _resampled(base, tj)
    gyr = rec.gyr.copy()
    rows = rng.choice(np.arange(100, len(base) - 100), 20, replace=False)
    gyr[rows] = np.nan
    ns = [str(1_700_000_000_000_000_000 + int(v)) for v in np.round(tj * 1e9)]  # epoch
    cols = [
        ("timestamp_ns", ns),
        *xyz_lower("acc_{}", rec.acc),
        *xyz_lower("gyr_{}", gyr, DEG),
        *xyz_lower("mag_{}", rec.mag),
    ]
    got = load_imu(write_csv(tmp_path / "jit.csv", cols))
    assert any("20 gyroscope samples are NaN/inf" in w for w in got.warnings)
    assert fill_gaps(got) is got  # late samples, none missing: nothing to fill
    assert got.frequency == pytest.approx(base.frequency, rel=1e-4)
    e = errors(got, ref, mov)
    assert abs(e["total_deg"] - truth["9d"]["total_deg"]) < 0.3, e


def test_long_file_memory_is_bounded(base: ImuRecording, tmp_path: Path) -> None:
    """Reading keeps one float64 per cell (plus the file's lines, streamed): the peak is
    a few times the numbers' size, never a copy per parsing step."""
    cols = [
        ("time", base.time),
        *xyz_lower("acc_{}", base.acc),
        *xyz_lower("gyr_{}", base.gyr, DEG),
        *xyz_lower("mag_{}", base.mag),
    ]
    p = write_csv(tmp_path / "long.csv", cols * 1)
    numbers = len(base) * len(cols) * 8
    tracemalloc.start()
    load_imu(p)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak < 6 * numbers + 8 * 2**20, (peak, numbers)


# ------------------------------------------------------------------------- APDM


def write_apdm(path: Path, sensors: dict[str, tuple[str, ImuRecording]]) -> Path:
    """An APDM file format 5 HDF5 (Opal / Mobility Lab): id -> (label, recording)."""
    import h5py

    with h5py.File(path, "w") as f:
        f.attrs["FileFormatVersion"] = 5
        for sid, (label, r) in sensors.items():
            g = f.create_group(f"Sensors/{sid}")
            g["Accelerometer"] = r.acc.astype(np.float32)
            g["Gyroscope"] = r.gyr.astype(np.float32)
            if r.mag is not None:
                g["Magnetometer"] = r.mag.astype(np.float32)
            g["Time"] = (1_709_633_730_000_000 + np.round(r.time * 1e6)).astype(np.uint64)
            cfg = g.create_group("Configuration")
            cfg.attrs["Label 0"] = label.encode()
            cfg.attrs["Sample Rate"] = np.uint16(round(r.frequency))
            if r.quat_ref is not None:
                f[f"Processed/{sid}/Orientation"] = r.quat_ref.astype(np.float32)
    return path


def test_apdm_h5(base: ImuRecording, truth: dict[str, Any], tmp_path: Path) -> None:
    """Two Opals in one file: refused with their ids and labels until one is chosen (by
    id or label); float32 storage, its own processed orientation as the reference."""
    other = replace(base, quat_ref=None, mag=None)
    p = write_apdm(tmp_path / "opal.h5", {"XI-010284": ("Lumbar", base),
                                          "XI-010301": ("Right Foot", other)})
    with pytest.raises(InputError, match=r"XI-010284 \(Lumbar\), XI-010301 \(Right Foot\)"):
        load_imu(p)
    rec = load_imu(p, sensor="lumbar")
    assert rec.meta["format"] == "apdm-h5" and rec.meta["sensor"] == "XI-010284"
    assert rec.name == "Lumbar" and len(rec) == len(base)
    assert np.allclose(rec.time, base.time - base.time[0], atol=1e-6)
    assert np.allclose(rec.gyr, base.gyr, rtol=1e-6, atol=1e-6)  # float32 in the file
    e = errors(rec, base.quat_ref, base.movement)  # type: ignore[arg-type]
    assert e["total_deg"] == pytest.approx(truth["9d"]["total_deg"], abs=0.05)
    assert rec.quat_ref is not None
    own = errors(rec, rec.quat_ref, base.movement)
    assert own["total_deg"] == pytest.approx(truth["9d"]["total_deg"], abs=0.05)
    foot = load_imu(p, sensor="XI-010301")
    assert foot.mag is None and foot.quat_ref is None
    with pytest.raises(InputError, match="no sensor 'hand'"):
        load_imu(p, sensor="hand")


def test_one_file_per_sensor_is_named(tmp_path: Path) -> None:
    """Phone loggers (Sensor Logger) write Gyroscope.csv, Accelerometer.csv … with bare
    x, y, z: one of them alone is refused, saying to upload the app's zip (read by
    ``load_phone``, see test_foreign_imu_mvnx_phone.py) or merge them."""
    p = tmp_path / "Gyroscope.csv"
    p.write_text("time,seconds_elapsed,z,y,x\n1700000000000000000,0.0,0.1,0.2,0.3\n"
                 "1700000000010000000,0.01,0.1,0.2,0.3\n")
    with pytest.raises(InputError, match=r"one file per sensor.*upload the app's zip.*merge"):
        load_imu(p)
