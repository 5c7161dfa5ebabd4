"""Import of inertial recordings into one typed :class:`ImuRecording`.

Formats: x-IMU CSV exports (``Gyroscope X (deg/s)``, ``Accelerometer X (g)``,
``Magnetometer X (G)`` ...), Madgwick's ``ExampleData.mat``, BROAD trials (HDF5 or .mat)
and a generic CSV whose units are declared by the caller. Everything is converted to SI:
time s, gyr rad/s, acc m/s², mag µT (or left as given when declared ``"norm"``).

Problems the data itself reveals are either errors (:class:`InputError`: missing columns,
non-monotonic time, units contradicted by the magnitudes) or warnings collected in
``ImuRecording.warnings`` (NaN samples, ignored columns) — never printed.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from engine.errors import InputError

FloatArray = NDArray[np.float64]

G = 9.80665
#: unit name -> factor to SI (rad/s, m/s², µT)
GYR_UNITS = {"rad/s": 1.0, "deg/s": np.pi / 180.0, "dps": np.pi / 180.0}
ACC_UNITS = {"m/s2": 1.0, "m/s^2": 1.0, "m/s²": 1.0, "g": G}
MAG_UNITS = {"ut": 1.0, "µt": 1.0, "g": 100.0, "gauss": 100.0, "nt": 1e-3, "mt": 1e3,
             "norm": 1.0}
#: plausibility bounds for magnitude-based unit checks
_MAX_GYR_RAD = 40.0          # ≈ 2300 deg/s, above every body-worn gyroscope range
_EARTH_FIELD_UT = (15.0, 80.0)


@dataclass
class ImuRecording:
    """One inertial sensor's recording in SI units.

    Attributes:
        time: ``(T,)`` s, strictly increasing.
        gyr: ``(T, 3)`` rad/s.
        acc: ``(T, 3)`` m/s² (specific force; ≈ +9.81 up at rest).
        mag: ``(T, 3)`` µT (or normalised units, see ``meta["mag_unit"]``), or ``None``.
        frequency: nominal sampling rate, Hz (median of the time steps).
        name: sensor id / file stem.
        quat_ref: ``(T, 4)`` reference orientation (w-first, sensor-to-ENU) when the file
            has one (BROAD), else ``None``; NaN rows where the reference was lost.
        movement: ``(T,)`` bool mask of the evaluated phase (BROAD), else ``None``.
        meta: provenance (format, source path, original units ...).
        warnings: human-readable problems found while reading.
    """

    time: FloatArray
    gyr: FloatArray
    acc: FloatArray
    mag: FloatArray | None
    frequency: float
    name: str = ""
    quat_ref: FloatArray | None = None
    movement: NDArray[np.bool_] | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.time)


# ------------------------------------------------------------------------- checks


def _unit(table: dict[str, float], unit: str, what: str) -> float:
    key = unit.strip().lower().replace(" ", "")
    lowered = {k.lower(): v for k, v in table.items()}
    if key not in lowered:
        raise InputError(f"unknown {what} unit {unit!r}; use one of {sorted(table)}")
    return lowered[key]


def _finalise(
    time: FloatArray, gyr: FloatArray, acc: FloatArray, mag: FloatArray | None, name: str,
    meta: dict[str, Any], warnings: list[str], *, check_units: bool = True,
    frequency: float | None = None,
) -> ImuRecording:
    """Validate shapes, time and units; collect warnings; build the recording."""
    time = np.asarray(time, dtype=float).ravel()
    gyr = np.asarray(gyr, dtype=float)
    acc = np.asarray(acc, dtype=float)
    T = len(time)
    for arr, what in ((gyr, "gyroscope"), (acc, "accelerometer"), (mag, "magnetometer")):
        if arr is not None and np.shape(arr) != (T, 3):
            raise InputError(f"{what} data must have shape ({T}, 3), got {np.shape(arr)}")
    if T < 2:
        raise InputError(f"{name}: need at least two samples, got {T}")
    if not np.all(np.isfinite(time)):
        raise InputError(f"{name}: time column contains NaN/inf; fix or drop those rows")
    dts = np.diff(time)
    if np.any(dts <= 0):
        i = int(np.argmax(dts <= 0))
        raise InputError(
            f"{name}: time is not strictly increasing at sample {i + 1} "
            f"({time[i]:.6g} s -> {time[i + 1]:.6g} s); sort the file or remove duplicates")
    fs = float(frequency) if frequency else float(1.0 / np.median(dts))
    if np.max(dts) > 1.5 * np.median(dts) + 1e-12:
        n_gap = int(np.sum(dts > 1.5 * np.median(dts)))
        warnings.append(f"{n_gap} gap(s) in the time stamps (largest {np.max(dts):.3g} s); "
                        "the filters assume a constant rate")
    for arr, what in ((gyr, "gyroscope"), (acc, "accelerometer"), (mag, "magnetometer")):
        if arr is None:
            continue
        bad = ~np.all(np.isfinite(arr), axis=1)
        if bad.any():
            warnings.append(f"{int(bad.sum())} {what} sample(s) are NaN/inf "
                            f"(first at {time[int(np.argmax(bad))]:.4g} s); they are skipped")
    if check_units:
        _check_units(gyr, acc, mag, meta, name, warnings)
    return ImuRecording(time=time, gyr=gyr, acc=acc, mag=None if mag is None else
                        np.asarray(mag, dtype=float), frequency=fs, name=name, meta=meta,
                        warnings=warnings)


def _check_units(gyr: FloatArray, acc: FloatArray, mag: FloatArray | None,
                 meta: dict[str, Any], name: str, warnings: list[str]) -> None:
    """Detect unit mistakes from magnitudes (declared units vs. physics)."""
    gn = np.linalg.norm(gyr, axis=1)
    gn = gn[np.isfinite(gn)]
    if len(gn) and np.percentile(gn, 99) > _MAX_GYR_RAD:
        raise InputError(
            f"{name}: angular rates reach {np.percentile(gn, 99):.0f} rad/s after conversion "
            f"(declared {meta.get('gyr_unit')!r}); that is impossible for body motion — the "
            "data is probably in deg/s, declare gyr unit 'deg/s'")
    an = np.linalg.norm(acc, axis=1)
    an = an[np.isfinite(an)]
    if len(an):
        med = float(np.median(an))
        if 0.5 < med < 2.0:
            raise InputError(
                f"{name}: median acceleration is {med:.2f} m/s² after conversion (declared "
                f"{meta.get('acc_unit')!r}); gravity alone is 9.81 m/s², so the data is "
                "probably in g — declare acc unit 'g'")
        if 50.0 < med < 200.0:
            raise InputError(
                f"{name}: median acceleration is {med:.0f} m/s² after conversion (declared "
                f"{meta.get('acc_unit')!r}); the data is probably already in m/s² — "
                "declare acc unit 'm/s2'")
        if not 5.0 < med < 20.0:
            warnings.append(f"median acceleration {med:.3g} m/s² is far from gravity; "
                            "check the accelerometer unit")
    if mag is not None and meta.get("mag_unit", "").lower() != "norm":
        mn = np.linalg.norm(mag, axis=1)
        mn = mn[np.isfinite(mn)]
        if len(mn):
            med = float(np.median(mn))
            lo, hi = _EARTH_FIELD_UT
            if not lo / 3 < med < hi * 3:
                warnings.append(
                    f"median magnetic field {med:.3g} µT is far from the Earth's "
                    f"({lo:.0f}-{hi:.0f} µT); check the magnetometer unit "
                    f"(declared {meta.get('mag_unit')!r})")


# ------------------------------------------------------------------------ formats


def _read_csv(path: Path) -> tuple[list[str], FloatArray]:
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            sample = fh.read(4096)
            fh.seek(0)
            try:
                dialect: Any = csv.Sniffer().sniff(sample, delimiters=",;\t")
            except csv.Error:
                dialect = csv.excel
            rows = list(csv.reader(fh, dialect))
    except OSError as e:
        raise InputError(f"cannot read {path}: {e}") from None
    if len(rows) < 2:
        raise InputError(f"{path.name}: CSV needs a header row and data rows")
    header = [h.strip() for h in rows[0]]
    data = []
    for i, r in enumerate(rows[1:], start=2):
        if not any(c.strip() for c in r):
            continue
        if len(r) != len(header):
            raise InputError(f"{path.name}: line {i} has {len(r)} fields, header has "
                             f"{len(header)}")
        try:
            data.append([float(c) if c.strip() else np.nan for c in r])
        except ValueError:
            raise InputError(f"{path.name}: line {i} has a non-numeric value") from None
    return header, np.asarray(data, dtype=float).reshape(-1, len(header))


_XIO_GROUPS = {
    "gyr": ("Gyroscope", GYR_UNITS),
    "acc": ("Accelerometer", ACC_UNITS),
    "mag": ("Magnetometer", MAG_UNITS),
}


def load_xio_csv(path: str | Path, frequency: float | None = None) -> ImuRecording:
    """Read an x-IMU (x-io Technologies) CSV export.

    Columns are ``<Sensor> <X|Y|Z> (<unit>)`` for Gyroscope, Accelerometer and optionally
    Magnetometer, with ``Time (s)`` or ``Packet number`` for timing.

    Args:
        path: the CSV file.
        frequency: sampling rate, Hz, required when the file has no ``Time (s)`` column.

    Raises:
        InputError: missing columns, unknown units, bad timing.
    """
    p = Path(path)
    header, data = _read_csv(p)
    warnings: list[str] = []
    cols: dict[str, FloatArray] = {}
    units: dict[str, str] = {}
    used: set[int] = set()
    for key, (label, table) in _XIO_GROUPS.items():
        axes = []
        for ax in "XYZ":
            idx = [i for i, h in enumerate(header) if h.lower().startswith(f"{label} {ax}".lower())]
            if not idx:
                break
            i = idx[0]
            h = header[i]
            unit = h[h.find("(") + 1:h.rfind(")")] if "(" in h else ""
            units[key] = unit
            axes.append(data[:, i] * _unit(table, unit, f"{label.lower()}"))
            used.add(i)
        if len(axes) == 3:
            cols[key] = np.stack(axes, axis=1)
        elif key != "mag":
            raise InputError(f"{p.name}: x-IMU CSV lacks '{label} X/Y/Z (unit)' columns; "
                             f"found {header}")
    t_idx = [i for i, h in enumerate(header) if h.lower().startswith("time")]
    if t_idx:
        h = header[t_idx[0]]
        scale = 1e-3 if "(ms)" in h.lower() else 1.0
        time = data[:, t_idx[0]] * scale
        used.add(t_idx[0])
    elif frequency:
        n_idx = [i for i, h in enumerate(header) if h.lower().startswith("packet")]
        time = np.arange(len(data)) / float(frequency)
        used.update(n_idx)
    else:
        raise InputError(f"{p.name}: no 'Time (s)' column; pass the sampling frequency")
    ignored = [header[i] for i in range(len(header)) if i not in used]
    if ignored:
        warnings.append(f"ignored column(s): {', '.join(ignored)}")
    meta = {"format": "x-imu-csv", "source": str(p), "gyr_unit": units.get("gyr"),
            "acc_unit": units.get("acc"), "mag_unit": units.get("mag", "")}
    return _finalise(time, cols["gyr"], cols["acc"], cols.get("mag"), p.stem, meta, warnings,
                     frequency=frequency)


def _damaged(p: Path, e: BaseException) -> InputError:
    """The error for a file a reader library chokes on (truncated, corrupted, not what its
    extension says): readers raise anything from ``zlib.error`` to ``IndexError``."""
    kind = {".mat": "MATLAB .mat", ".hdf5": "HDF5", ".h5": "HDF5"}.get(p.suffix.lower(),
                                                                        p.suffix)
    return InputError(f"{p.name}: not a readable {kind} file — damaged, truncated or another "
                      f"format ({type(e).__name__}: {e}); export it again")


def _read_mat(p: Path, **kwargs: Any) -> dict[str, Any]:
    """``scipy.io.loadmat`` with every failure turned into :class:`InputError`."""
    import scipy.io

    try:
        return dict(scipy.io.loadmat(p, **kwargs))
    except FileNotFoundError as e:
        raise InputError(f"cannot read {p}: {e}") from None
    except Exception as e:  # a damaged file can trip any part of the reader
        raise _damaged(p, e) from None


def _as_float(p: Path, what: str, a: Any) -> FloatArray:
    """A numeric array from a file's variable (InputError if it is not numeric)."""
    try:
        return np.asarray(a, dtype=float)
    except (TypeError, ValueError) as e:
        raise InputError(f"{p.name}: variable {what!r} is not numeric ({e})") from None


def load_madgwick_mat(path: str | Path) -> ImuRecording:
    """Read Madgwick's ``ExampleData.mat`` layout (time s, deg/s, g, gauss).

    Raises:
        InputError: unreadable file or missing variables.
    """
    p = Path(path)
    d = _read_mat(p)
    need = ("time", "Gyroscope", "Accelerometer")
    if not all(k in d for k in need):
        raise InputError(f"{p.name}: expected variables {need} (+ Magnetometer); "
                         f"found {[k for k in d if not k.startswith('__')]}")
    v = {k: _as_float(p, k, d[k]) for k in (*need, "Magnetometer") if k in d}
    mag = v["Magnetometer"] * 100.0 if "Magnetometer" in v else None
    meta = {"format": "madgwick-mat", "source": str(p), "gyr_unit": "deg/s", "acc_unit": "g",
            "mag_unit": "G"}
    return _finalise(v["time"].ravel(), np.deg2rad(v["Gyroscope"]), v["Accelerometer"] * G,
                     mag, p.stem, meta, [])


def load_broad(path: str | Path) -> ImuRecording:
    """Read a BROAD trial (``.hdf5`` or ``.mat``) including its optical reference.

    Raises:
        InputError: unreadable file or missing datasets.
    """
    p = Path(path)
    keys = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement")
    if p.suffix.lower() == ".mat":
        d = _read_mat(p, squeeze_me=True)
        fs = d.get("sampling_rate")
        arrays = {k: np.asarray(d[k]) for k in keys if k in d}
    else:
        import h5py

        try:
            with h5py.File(p, "r") as f:
                arrays = {k: f[k][()] for k in keys if k in f}
                fs = f.attrs.get("sampling_rate")
        except FileNotFoundError as e:
            raise InputError(f"cannot read {p}: {e}") from None
        except Exception as e:  # a damaged file can trip any part of h5py
            raise _damaged(p, e) from None
    missing = [k for k in keys if k not in arrays]
    if missing or fs is None:
        raise InputError(f"{p.name}: not a BROAD trial; missing {missing or ['sampling_rate']}")
    try:
        fs = float(np.asarray(fs, dtype=float).ravel()[0])
    except (TypeError, ValueError, IndexError):
        raise InputError(f"{p.name}: sampling_rate is not a number") from None
    if not np.isfinite(fs) or fs <= 0:
        raise InputError(f"{p.name}: sampling_rate must be positive, got {fs}")
    arrays = {k: _as_float(p, k, a) if k != "movement" else np.asarray(a)
              for k, a in arrays.items()}
    n = len(arrays["imu_gyr"])
    meta = {"format": "broad", "source": str(p), "gyr_unit": "rad/s", "acc_unit": "m/s2",
            "mag_unit": "uT"}
    rec = _finalise(np.arange(n) / fs, arrays["imu_gyr"], arrays["imu_acc"], arrays["imu_mag"],
                    p.stem, meta, [], frequency=fs)
    rec.quat_ref = np.asarray(arrays["opt_quat"], dtype=float)
    rec.movement = np.asarray(arrays["movement"]).astype(bool).ravel()
    return rec


def load_csv(
    path: str | Path,
    *,
    gyr_unit: str,
    acc_unit: str,
    mag_unit: str | None = None,
    time_unit: str = "s",
    frequency: float | None = None,
) -> ImuRecording:
    """Read a generic CSV with columns ``time, gyr_x, gyr_y, gyr_z, acc_x, ... [mag_x ...]``.

    Units are declared by the caller and checked against the magnitudes in the data.

    Args:
        path: the CSV file (comma, semicolon or tab separated, one header row).
        gyr_unit: ``"rad/s"`` or ``"deg/s"``.
        acc_unit: ``"m/s2"`` or ``"g"``.
        mag_unit: ``"uT"``, ``"nT"``, ``"G"``, ``"norm"`` or ``None`` when there is no
            magnetometer.
        time_unit: ``"s"`` or ``"ms"``; without a ``time`` column, ``frequency`` is used.
        frequency: sampling rate, Hz, when there is no time column.

    Raises:
        InputError: missing columns, unknown units, units contradicted by the data,
            non-monotonic time.
    """
    p = Path(path)
    header, data = _read_csv(p)
    lower = [h.lower() for h in header]
    want = [f"{s}_{a}" for s in ("gyr", "acc") for a in "xyz"]
    if mag_unit is not None:
        want += [f"mag_{a}" for a in "xyz"]
    missing = [w for w in want if w not in lower]
    if missing:
        raise InputError(f"{p.name}: missing column(s) {missing}; expected "
                         f"time, {', '.join(want)} (found {header})")
    warnings: list[str] = []
    known = set(want) | {"time"}
    unknown = [h for h in header if h.lower() not in known]
    if unknown:
        warnings.append(f"ignored unknown column(s): {', '.join(unknown)}")

    def block(prefix: str) -> FloatArray:
        return np.stack([data[:, lower.index(f"{prefix}_{a}")] for a in "xyz"], axis=1)

    gyr = block("gyr") * _unit(GYR_UNITS, gyr_unit, "gyroscope")
    acc = block("acc") * _unit(ACC_UNITS, acc_unit, "accelerometer")
    mag = None if mag_unit is None else block("mag") * _unit(MAG_UNITS, mag_unit, "magnetometer")
    if "time" in lower:
        scale = {"s": 1.0, "ms": 1e-3}.get(time_unit)
        if scale is None:
            raise InputError(f"time_unit must be 's' or 'ms', got {time_unit!r}")
        time = data[:, lower.index("time")] * scale
    elif frequency:
        time = np.arange(len(data)) / float(frequency)
    else:
        raise InputError(f"{p.name}: no 'time' column; pass the sampling frequency")
    meta = {"format": "csv", "source": str(p), "gyr_unit": gyr_unit, "acc_unit": acc_unit,
            "mag_unit": mag_unit or ""}
    return _finalise(time, gyr, acc, mag, p.stem, meta, warnings, frequency=frequency)


def load_imu(path: str | Path, **kwargs: Any) -> ImuRecording:
    """Read any supported IMU file, choosing the reader from extension and content.

    ``**kwargs`` go to :func:`load_csv` (units) or :func:`load_xio_csv` (frequency).

    Raises:
        InputError: unsupported file or any reader error.
    """
    p = Path(path)
    suf = p.suffix.lower()
    if suf in (".hdf5", ".h5"):
        return load_broad(p)
    if suf == ".mat":
        import scipy.io

        try:
            names = {n for n, _, _ in scipy.io.whosmat(p)}
        except FileNotFoundError as e:
            raise InputError(f"cannot read {p}: {e}") from None
        except Exception as e:  # a damaged file can trip any part of the reader
            raise _damaged(p, e) from None
        return load_broad(p) if "imu_gyr" in names else load_madgwick_mat(p)
    if suf in (".csv", ".txt", ".tsv"):
        try:
            with p.open(encoding="utf-8-sig") as fh:
                first = fh.readline()
        except OSError as e:
            raise InputError(f"cannot read {p}: {e}") from None
        if "Gyroscope X" in first:
            return load_xio_csv(p, frequency=kwargs.get("frequency"))
        if "gyr_unit" not in kwargs or "acc_unit" not in kwargs:
            raise InputError(f"{p.name}: generic CSV needs declared units (gyr_unit, acc_unit "
                             "and mag_unit if there is a magnetometer)")
        return load_csv(p, **kwargs)
    raise InputError(f"{p.name}: unsupported IMU file type {suf!r}; use .csv, .mat or .hdf5")
