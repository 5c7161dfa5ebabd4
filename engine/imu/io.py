"""Import of inertial recordings into one typed :class:`ImuRecording`.

Formats: x-IMU CSV exports (``Gyroscope X (deg/s)``, ``Accelerometer X (g)``,
``Magnetometer X (G)`` ...), Shimmer Consensys CSVs (``Shimmer_8C4F_Gyro_X_CAL`` with a
units row; ``sep=`` line), Xsens / Movella DOT CSVs (metadata lines, ``PacketCounter``,
``SampleTimeFine``, ``Acc_X``, ``Gyr_X``, ``Mag_X``), Madgwick's ``ExampleData.mat``, BROAD
trials (HDF5 or .mat), APDM HDF5, Xsens MVN ``.mvnx`` exports (one recording per tracker,
:func:`load_mvnx`), phone apps' one-file-per-sensor zips or folders (Sensor Logger,
phyphox: :func:`load_phone`) and a generic CSV whose units are declared by the caller or
read from the header. A CSV with several sensors' columns (prefixed per sensor) is read one
sensor at a time (``sensor=``). Everything is converted to SI: time s, gyr rad/s,
acc m/s², mag µT (or left as given when ``"norm"``: declared, or arbitrary units such as
Shimmer's ``local_flux`` and Xsens' a.u.).

Problems the data itself reveals are either errors (:class:`InputError`: missing columns,
non-monotonic time, units contradicted by the magnitudes) or warnings collected in
``ImuRecording.warnings`` (NaN samples, ignored columns) — never printed.
"""

from __future__ import annotations

import csv
import itertools
import re
from array import array
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from engine.errors import InputError
from engine.geometry import quat_conj, quat_mul, quat_rotate
from engine.wording import count

if TYPE_CHECKING:  # _phone imports this module
    from engine.imu._phone import ZipDirectory

FloatArray = NDArray[np.float64]

G = 9.80665
#: unit name -> factor to SI (rad/s, m/s², µT); matched case-insensitively, spaces ignored
GYR_UNITS = {"rad/s": 1.0, "rad/sec": 1.0, "rads": 1.0, "rads-1": 1.0, "deg/s": np.pi / 180.0,
             "deg/sec": np.pi / 180.0, "degs-1": np.pi / 180.0, "°/s": np.pi / 180.0,
             "dps": np.pi / 180.0, "d/s": np.pi / 180.0, "degree/s": np.pi / 180.0,
             "degrees/s": np.pi / 180.0, "deg.s-1": np.pi / 180.0, "mrad/s": 1e-3}
ACC_UNITS = {"m/s2": 1.0, "m/s^2": 1.0, "m/s²": 1.0, "m/s/s": 1.0, "ms-2": 1.0,
             "m*s-2": 1.0, "m/(s^2)": 1.0, "m/s**2": 1.0, "g": G, "mg": G / 1000.0}
#: units written into column names (``gyr_x_dps``, ``acc_x_ms2``) -> unit
_NAME_UNITS = {"dps": "deg/s", "degs": "deg/s", "deg": "deg/s", "rads": "rad/s", "rad": "rad/s",
               "ms2": "m/s2", "g": "g", "mg": "mg", "ut": "uT", "gauss": "G", "nt": "nT",
               "mt": "mT"}
MAG_UNITS = {"ut": 1.0, "µt": 1.0, "μt": 1.0, "g": 100.0, "gauss": 100.0, "mg": 0.1,
             "mgauss": 0.1, "nt": 1e-3, "mt": 1e3, "norm": 1.0}
#: time unit -> factor to s
TIME_UNITS = {"s": 1.0, "sec": 1.0, "ms": 1e-3, "msec": 1e-3, "msecs": 1e-3, "us": 1e-6,
              "µs": 1e-6, "μs": 1e-6, "100us": 1e-4, "ns": 1e-9}
#: magnetometer units scaled to the local field (Shimmer, Xsens): read as ``"norm"``
_ARBITRARY_MAG_UNITS = {"local_flux", "localflux", "a.u.", "a.u", "au", "arb.unit",
                        "arbitrary"}
#: the warnings :func:`fill_gaps` and the quaternion columns replace are found by these
#: words, which stay the same whatever the count ("1 gap"/"2 gaps", "column"/"columns")
_GAPS_WARNING = " in the time stamps (largest "
_IGNORED_WARNING = "ignored column"
#: largest CSV read (the whole file is parsed in memory); split bigger recordings
MAX_CSV_BYTES = 256 * 2**20
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
    _check_rounded_time(name, time)
    if np.any(dts <= 0):
        i = int(np.argmax(dts <= 0))
        raise InputError(
            f"{name}: time is not strictly increasing at sample {i + 1} "
            f"({time[i]:.6g} s -> {time[i + 1]:.6g} s); sort the file or remove duplicates")
    fs = float(frequency) if frequency else _nominal_rate(time)
    if np.max(dts) > 1.5 * np.median(dts) + 1e-12:
        n_gap = int(np.sum(dts > 1.5 * np.median(dts)))
        warnings.append(f"{count(n_gap, 'gap')}{_GAPS_WARNING}{np.max(dts):.3g} s); "
                        "the filters assume a constant rate")
    for arr, what in ((gyr, "gyroscope"), (acc, "accelerometer"), (mag, "magnetometer")):
        if arr is None:
            continue
        bad = ~np.all(np.isfinite(arr), axis=1)
        if bad.any():
            one = int(bad.sum()) == 1
            warnings.append(f"{count(int(bad.sum()), what + ' sample')} "
                            f"{'is' if one else 'are'} NaN/inf (first at "
                            f"{time[int(np.argmax(bad))]:.4g} s); "
                            f"{'it is' if one else 'they are'} skipped")
    for arr, what in ((gyr, "gyroscope"), (acc, "accelerometer"), (mag, "magnetometer")):
        if arr is not None:
            _check_channels(np.asarray(arr, dtype=float), what, warnings)
    if check_units:
        _check_units(gyr, acc, mag, meta, name, warnings)
    return ImuRecording(time=time, gyr=gyr, acc=acc, mag=None if mag is None else
                        np.asarray(mag, dtype=float), frequency=fs, name=name, meta=meta,
                        warnings=warnings)


def _nominal_rate(time: FloatArray) -> float:
    """Sampling rate, Hz: (samples - 1 + missing samples) / duration.

    A gap is a step of at least 1.75 median steps; each counts its missing periods. A
    plain mean step is biased by gaps, the mean of the steps under 1.5 median steps by
    jitter (±30 % jittered steps: 287.9 Hz for 285.7 Hz, an integration error of 0.8 %);
    this is neither, and equals the mean step of a regular or rounded clock (integer ms
    stamps at 285.7 Hz).
    """
    dts = np.diff(time)
    med = float(np.median(dts))
    gaps = dts >= 1.75 * med
    missing = float(np.sum(np.round(dts[gaps] / med) - 1.0))
    return float((len(dts) + missing) / (time[-1] - time[0]))


def _check_rounded_time(name: str, time: FloatArray, unit: str = "s") -> None:
    """InputError when many time steps are 0: a clock rounded coarser than the sampling
    step (32-bit floats keep 24 bits, so epoch seconds fall on a 128-s grid)."""
    dts = np.diff(time[np.isfinite(time)])
    n_same = int(np.sum(dts == 0))
    if n_same > max(2, len(dts) // 20):
        raise InputError(
            f"{name}: {n_same} of {len(dts)} time steps are 0 — the time stamps are rounded "
            f"more coarsely than the sampling step (values reach {np.max(np.abs(time)):.6g} "
            f"{unit}; stored as 32-bit floats or with too few digits?); export time in double "
            "precision or relative to the start, or drop the time column and pass the "
            "sampling frequency")


def _saturates(arr: FloatArray) -> bool:
    """Whether an axis sticks at its extreme value (the check of :func:`_check_channels`)."""
    w: list[str] = []
    _check_channels(np.asarray(arr, dtype=float), "accelerometer", w)
    return any("saturates" in x for x in w)


def _check_channels(arr: FloatArray, what: str, warnings: list[str]) -> None:
    """Warn about dead (constant) and saturated (clipped at the range) axes."""
    for k, ax in enumerate("XYZ"):
        c = arr[:, k]
        c = c[np.isfinite(c)]
        if len(c) < 10:
            continue
        if np.ptp(c) == 0:
            warnings.append(f"{what} {ax} is constant ({c[0]:.4g}) — a dead channel?")
            continue
        if what == "magnetometer":
            continue  # a slow, coarsely quantised field dwells on its extreme values
        top = np.max(np.abs(c))
        at = np.abs(c) == top
        # the longest run of samples stuck at the extreme value: a clipped sensor
        run = np.diff(np.flatnonzero(np.diff(np.r_[0, at.astype(np.int8), 0])))[::2]
        if len(run) and int(run.max()) >= 5:
            warnings.append(f"{what} {ax} saturates at ±{top:.4g} ({int(at.sum())} samples); "
                            "the sensor range was exceeded, values there are wrong")


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
        if med < 4.0:  # no worn accelerometer feels less than 0.4 g on median
            raise InputError(
                f"{name}: median acceleration is {med:.2f} m/s² after conversion (declared "
                f"{meta.get('acc_unit')!r}); gravity alone is 9.81 m/s²: "
                + ("the data is probably in g — declare acc unit 'g' — or "
                   if 0.5 < med < 2.0 else "")
                + "gravity was removed (a 'linear acceleration' export): the filters need "
                "the raw accelerometer")
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


_COMMENTS = ("#", "//", "%")
_NAN_CELLS = {"", "nan", "na", "n/a", "null", "none", "-"}


def _text_lines(path: Path) -> Iterator[str]:
    """The file's lines (BOM and line ends removed), or InputError for an unreadable,
    empty, oversized or binary file."""
    try:
        size = path.stat().st_size
        with path.open("rb") as fh:
            head = fh.read(4096)
    except OSError as e:
        raise InputError(f"cannot read {path}: {e}") from None
    if size == 0 or not head.strip():
        raise InputError(f"{path.name}: the file is empty")
    if size > MAX_CSV_BYTES:
        raise InputError(f"{path.name}: {size / 2**20:.0f} MB is more than the "
                         f"{MAX_CSV_BYTES // 2**20} MB a CSV may have; split the recording")
    control = sum(1 for c in head if c < 32 and c not in (9, 10, 13))
    if control > len(head) // 100:
        raise InputError(f"{path.name}: not a text CSV (binary content); export the "
                         "recording as CSV text")
    encoding = "utf-8-sig"
    try:
        with path.open(encoding=encoding) as fh:
            for _ in fh:
                pass
    except UnicodeDecodeError:
        encoding = "latin-1"  # Windows exports write '°' and 'µ' in cp1252/latin-1
    except OSError as e:
        raise InputError(f"cannot read {path}: {e}") from None
    with path.open(encoding=encoding, newline="") as fh:
        for line in fh:
            yield line.rstrip("\r\n")


def _read_csv(path: Path, dates: set[int] | None = None
              ) -> tuple[list[str], FloatArray, list[str], dict[int, tuple[int, str]]]:
    """Parse a numeric CSV with one header row.

    Accepts comma, semicolon or tab separators (chosen from the header), a decimal comma
    (with ``;`` or tab separators), comment lines (``#``, ``//``, ``%``), blank lines, a BOM,
    CRLF, empty/NaN cells and one units row under the header.

    Args:
        path: the file.
        dates: filled with the columns with a time-like name whose cells are ISO 8601
            date-times (``2024-03-05 10:15:30.123``, ``…T…Z``, ``…+01:00``): those are
            read as POSIX seconds (a naive time as UTC; only differences matter).

    Returns:
        header, ``(N, C)`` data, the units row (``[]`` when there is none) and the
        columns holding text: index -> (row number, first text cell); NaN in the data.
    """
    lines: Iterator[str] = (ln for ln in _text_lines(path)
                            if ln.strip() and not ln.lstrip().startswith(_COMMENTS))
    # Excel's "sep=<c>" first line (Shimmer Consensys exports) names the separator
    head = list(itertools.islice(lines, _PREAMBLE_LINES))
    forced = None
    if head and (m := re.fullmatch(r'"?sep=(\\t|.?)"?', head[0].strip("\r\n "),
                                   re.IGNORECASE)):
        forced = "\t" if m.group(1) in ("", "\\t") else m.group(1)
        head = head[1:]
    # metadata lines before the header without a comment mark (Movella DOT's
    # "DeviceTag: 3"): the header is the first line with three or more fields
    start = next((i for i, ln in enumerate(head) if _n_fields(ln, forced) >= 3), 0)
    lines = itertools.chain(head[start + 1:], lines)
    first = head[start] if head else None
    if first is None:
        raise InputError(f"{path.name}: the file holds no header row or data")
    delim = forced or ("\t" if "\t" in first else ";" if ";" in first else ",")
    header = [h.strip().strip('"').strip() for h in next(csv.reader([first], delimiter=delim))]
    while header and not header[-1]:
        header.pop()  # a trailing separator
    n = len(header)
    if n < 2:
        raise InputError(f"{path.name}: the header has {count(n, 'column')}; expected a separated "
                         "header such as time,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z")
    # fast path: every remaining cell a plain number (most exports) is parsed by numpy's
    # C reader, ~4x faster than a Python float() per cell (bench/imu_import.py); any
    # other file (units row, text, empty cells, ragged rows) is read by the loop below,
    # which says what is wrong
    rest = list(lines)
    if delim != " " and rest:
        # with ';' or tab separators a comma is a decimal comma (German/French Excel)
        cells = rest if delim == "," else [ln.replace(",", ".") for ln in rest]
        try:
            fast = np.loadtxt(cells, delimiter=delim, comments=None, ndmin=2, dtype=float)
        except ValueError:
            fast = None
        if fast is not None and fast.shape == (len(rest), n):
            return header, fast, [], {}
    lines = iter(rest)
    values = array("d")
    units: list[str] = []
    text: dict[int, tuple[int, str]] = {}
    fmt_row = False
    rows = 0
    timelike = {k for k, h in enumerate(header) if _time_like(h)}
    found_dates: set[int] = set()
    for i, r in enumerate(csv.reader(lines, delimiter=delim), start=2):
        if len(r) > n and not any(c.strip() for c in r[n:]):
            r = r[:n]
        if len(r) != n:
            hint = ("; decimal commas need ';' or tab separators" if delim == "," and len(r) > n
                    else "")
            raise InputError(f"{path.name}: data row {i} has {len(r)} fields, header has {n}"
                             + hint)
        mark = len(values)
        try:
            values.extend(float(c.replace(",", ".")) if c.strip().lower() not in _NAN_CELLS
                          else np.nan for c in r)
        except ValueError:
            del values[mark:]  # the cells read before the bad one
            if rows == 0 and not units and not fmt_row and r and all(
                    c.strip().upper() in ("CAL", "RAW", "UNCAL") for c in r):
                # Shimmer's older three-row header: names, CAL/RAW, units
                header = [f"{h}_{c.strip()}" for h, c in zip(header, r, strict=True)]
                fmt_row = True
                continue
            if rows == 0 and not units and all(not _is_number(c) for c in r):
                units = [_unbracket(c) for c in r]  # a units row under the header
                continue
            # a text cell (Shimmer's formatted date column): NaN here; an error only if
            # the column is one the reader uses (see _text_error); an ISO date-time in a
            # time column: POSIX seconds
            for k, c in enumerate(r):
                if _is_number(c):
                    values.append(float(c.replace(",", ".")))
                elif k in timelike and k not in text and (sec := _iso_seconds(c)) is not None:
                    values.append(sec)
                    found_dates.add(k)
                else:
                    values.append(np.nan)
                    if c.strip().lower() not in _NAN_CELLS:
                        text.setdefault(k, (i, c))
        rows += 1
    if rows == 0:
        raise InputError(f"{path.name}: CSV needs a header row and data rows")
    for k in found_dates - set(text):
        if dates is not None:
            dates.add(k)
    # a view on the array's buffer (writable, kept alive by the view): no second copy
    return header, np.frombuffer(values, dtype=float).reshape(rows, n), units, text


def _iso_seconds(cell: str) -> float | None:
    """POSIX seconds of an ISO 8601 date-time cell, or None when it is not one."""
    c = cell.strip().strip('"')
    if len(c) < 10 or not c[:4].isdigit() or c[4] != "-":
        return None
    if c.endswith(("Z", "z")):
        c = c[:-1] + "+00:00"
    if "," in c[10:]:
        c = c[:10] + c[10:].replace(",", ".")  # 10:15:30,123 (ISO allows a decimal comma)
    try:
        t = datetime.fromisoformat(c)
    except ValueError:
        return None
    if t.tzinfo is None:
        t = t.replace(tzinfo=UTC)
    return t.timestamp()


def _time_like(h: str) -> bool:
    """Whether a header cell names a time column (an ISO date-time there is read)."""
    key = _parse_column(h, "").key
    return any(key == a or (key.startswith(a) and key[len(a):] in TIME_UNITS)
               for a in _TIME_ALIASES)


def _text_error(path: Path, text: dict[int, tuple[int, str]], used: set[int]) -> None:
    """InputError for the first text cell in a column the reader uses."""
    bad = sorted((row, c) for k, (row, c) in text.items() if k in used)
    if bad:
        row, c = bad[0]
        raise InputError(f"{path.name}: data row {row} has a non-numeric value {c[:40]!r}")


#: lines looked at for a "sep=" line and a metadata preamble before the header
_PREAMBLE_LINES = 64


def _n_fields(line: str, delim: str | None) -> int:
    """Non-empty-ended field count of a line with its own (or the forced) separator."""
    d = delim or ("\t" if "\t" in line else ";" if ";" in line else ",")
    cells = next(csv.reader([line], delimiter=d))
    while cells and not cells[-1].strip():
        cells.pop()
    return len(cells)


def _unbracket(c: str) -> str:
    """``"(deg/s)"`` -> ``"deg/s"``; ``"m/(s^2)"`` keeps its brackets."""
    c = c.strip()
    if len(c) > 1 and (c[0], c[-1]) in (("(", ")"), ("[", "]"), ("{", "}")):
        c = c[1:-1].strip()
    return c


def _is_number(c: str) -> bool:
    try:
        float(c.replace(",", "."))
    except ValueError:
        return False
    return True


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

    Returns:
        The recording in SI units (rad/s, m/s², µT), time first axis.

    Raises:
        InputError: missing columns, unknown units, bad timing.
    """
    p = Path(path)
    header, data, _, text = _read_csv(p)
    _text_error(p, text, set(range(len(header))))
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
        warnings.append(_ignored_warning(ignored))
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


@contextmanager
def _open_h5(p: Path) -> Iterator[Any]:
    """Open an HDF5 file for reading, refusing one that points outside itself.

    HDF5 lets a file take its data from elsewhere: a dataset's raw data in any file named
    in it (external storage, read as numbers whatever that file is), a link to an object
    in another HDF5 file, a virtual dataset mapped onto other files. An uploaded file
    must not make the server read its own files (other subjects' data, its database), so
    only self-contained files are read; nothing is read before the check.
    """
    import h5py

    with h5py.File(p, "r") as f:
        elsewhere: list[str] = []

        def link(name: str, lnk: Any) -> None:
            if isinstance(lnk, h5py.ExternalLink):
                elsewhere.append(f"{name} (a link to another file)")

        def obj(name: str, o: Any) -> None:
            if isinstance(o, h5py.Dataset) and (o.external or o.is_virtual):
                what = "data kept in other files" if o.external else "a virtual dataset"
                elsewhere.append(f"{name} ({what})")

        f.visititems_links(link)
        f.visititems(obj)  # (hard links only: objects in this file, each once)
        if elsewhere:
            raise InputError(
                f"{p.name}: the file takes data from other files ({', '.join(elsewhere[:3])}"
                f"{', …' if len(elsewhere) > 3 else ''}), which is not accepted; save it as "
                "one self-contained HDF5 file (e.g. h5py's copy, or h5repack) and upload that")
        yield f


#: MATLAB classes (``scipy.io.whosmat``'s names) that load as plain numeric arrays
_MAT_NUMERIC = frozenset({"double", "single", "int8", "uint8", "int16", "uint16", "int32",
                          "uint32", "int64", "uint64", "logical"})
#: the variables each reader takes from a file (the others are never unpacked)
_MADGWICK_VARS = ("time", "Gyroscope", "Accelerometer", "Magnetometer")
_BROAD_KEYS = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement")
_BROAD_MAT_VARS = (*_BROAD_KEYS, "sampling_rate")


def _mat_variables(p: Path) -> list[tuple[str, tuple[int, ...], str]]:
    """A .mat file's variables (name, shape, MATLAB class) from their headers alone
    (``scipy.io.whosmat``: a compressed variable's header is unpacked, not its data)."""
    import scipy.io

    try:
        return [(str(n), tuple(int(k) for k in shape), str(c))
                for n, shape, c in scipy.io.whosmat(p)]
    except FileNotFoundError as e:
        raise InputError(f"cannot read {p}: {e}") from None
    except Exception as e:  # a damaged file can trip any part of the reader
        raise _damaged(p, e) from None


def _mat_reader_vars(names: set[str]) -> tuple[str, ...]:
    """The variables :func:`load_imu` reads from a .mat holding ``names``."""
    return _BROAD_MAT_VARS if "imu_gyr" in names else _MADGWICK_VARS


def _read_mat(p: Path, wanted: tuple[str, ...], **kwargs: Any) -> dict[str, Any]:
    """``scipy.io.loadmat`` of the ``wanted`` variables only, every failure turned into
    :class:`InputError`. The others are skipped unread, and a wanted one that is not a
    numeric array (a cell, struct, object) is refused before it is read: its header does
    not tell how much it unpacks to (:func:`estimate_memory_bytes` bounds the rest)."""
    import scipy.io

    for name, _, cls in _mat_variables(p):
        if name in wanted and cls not in _MAT_NUMERIC:
            raise InputError(f"{p.name}: variable {name!r} is not numeric (a MATLAB {cls}, "
                             "not a numeric array); save it as a plain matrix")
    try:
        return dict(scipy.io.loadmat(p, variable_names=list(wanted), **kwargs))
    except FileNotFoundError as e:
        raise InputError(f"cannot read {p}: {e}") from None
    except Exception as e:  # a damaged file can trip any part of the reader
        raise _damaged(p, e) from None


def _h5_numbers(p: Path, name: str, ds: Any) -> Any:
    """An HDF5 dataset's numbers, refused unread unless they are plain numbers.

    The upload budget counts a dataset at its shape times its item size; a
    variable-length or object dataset's item is a pointer, and its data could unpack to
    any size when read, so it is refused before anything is read.

    Raises:
        InputError: not a dataset, or not of booleans, integers or floats.
    """
    import h5py

    if not isinstance(ds, h5py.Dataset):
        raise InputError(f"{p.name}: {name!r} is not a dataset of numbers")
    if ds.dtype.kind not in "biuf":
        what = ("variable-length data" if h5py.check_vlen_dtype(ds.dtype) is not None
                else f"data of type {ds.dtype}")
        raise InputError(f"{p.name}: dataset {name!r} holds {what}, not numbers; save it as "
                         "an array of numbers")
    return ds[()]


def _as_float(p: Path, what: str, a: Any) -> FloatArray:
    """A numeric array from a file's variable (InputError if it is not numeric)."""
    try:
        return np.asarray(a, dtype=float)
    except (TypeError, ValueError) as e:
        raise InputError(f"{p.name}: variable {what!r} is not numeric ({e})") from None


def load_madgwick_mat(path: str | Path) -> ImuRecording:
    """Read Madgwick's ``ExampleData.mat`` layout (time s, deg/s, g, gauss).

    Args:
        path: The ``.mat`` file.

    Returns:
        The recording in SI units (rad/s, m/s², µT), time first axis.

    Raises:
        InputError: unreadable file or missing variables.
    """
    p = Path(path)
    d = _read_mat(p, _MADGWICK_VARS)
    need = ("time", "Gyroscope", "Accelerometer")
    if not all(k in d for k in need):
        raise InputError(f"{p.name}: expected variables {need} (+ Magnetometer); "
                         f"found {[n for n, _, _ in _mat_variables(p)]}")
    v = {k: _as_float(p, k, d[k]) for k in (*need, "Magnetometer") if k in d}
    mag = v["Magnetometer"] * 100.0 if "Magnetometer" in v else None
    meta = {"format": "madgwick-mat", "source": str(p), "gyr_unit": "deg/s", "acc_unit": "g",
            "mag_unit": "G"}
    return _finalise(v["time"].ravel(), np.deg2rad(v["Gyroscope"]), v["Accelerometer"] * G,
                     mag, p.stem, meta, [])


def load_broad(path: str | Path) -> ImuRecording:
    """Read a BROAD trial (``.hdf5`` or ``.mat``) including its optical reference.

    Args:
        path: A BROAD trial file (``.hdf5`` or ``.mat``).

    Returns:
        The recording (SI units, time first axis) with ``quat_ref`` (the optical
        sensor-to-ENU reference, NaN where lost) and ``movement`` (the evaluated phase).

    Raises:
        InputError: unreadable file or missing datasets.
    """
    p = Path(path)
    keys = _BROAD_KEYS
    if p.suffix.lower() == ".mat":
        d = _read_mat(p, _BROAD_MAT_VARS, squeeze_me=True)
        fs = d.get("sampling_rate")
        arrays = {k: np.asarray(d[k]) for k in keys if k in d}
    else:
        try:
            with _open_h5(p) as f:
                arrays = {k: _h5_numbers(p, k, f[k]) for k in keys if k in f}
                fs = f.attrs.get("sampling_rate")
        except InputError:
            raise
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


_GROUP_ALIASES = {
    "gyr": ("gyr", "gyro", "gyros", "gyroscope", "angvel", "angularvelocity", "angularrate",
            "rotationrate", "omega", "w", "g"),  # Arduino sketches: ax, ay, az, gx, gy, gz
    "acc": ("acc", "accel", "accelerometer", "acceleration", "a", "gf"),  # gFx: g-force
    "mag": ("mag", "magn", "magnetometer", "magneticfield", "compass", "m", "b"),
}
#: names that say "time" (+ a unit: ``time_s``); Shimmer's ``Timestamp_Unix_CAL``, Xsens'
#: ``SampleTimeFine`` (a wrapping uint32 clock: µs on Movella DOT, 100 µs ticks on MTi)
_TIME_ALIASES = ("time", "timestamp", "sampletime", "elapsedtime", "timestampunix",
                 "unixtimestamp", "timestampsync", "timestampsyncunix", "systemtimestamp",
                 "sampletimefine", "millis", "micros", "secondselapsed", "datetime", "date",
                 "loggingtime", "utc")
#: a bare ``t`` is time only when it increases: some exports call the temperature ``T``
_WEAK_TIME_ALIASES = ("t",)
_COUNTER_ALIASES = ("packetnumber", "packetcounter", "packet", "sample", "samplenumber",
                    "samplecounter", "counter", "index", "idx", "frame", "framenumber")
_GROUP_NAMES = {"gyr": "gyroscope", "acc": "accelerometer", "mag": "magnetometer"}
#: units that mark a column as a temperature: never the time
_TEMPERATURE_UNITS = {"c", "°c", "degc", "degreesc", "celsius", "℃", "k", "kelvin", "°f",
                      "degf", "f"}
#: name tokens that qualify a channel: Shimmer's calibrated/raw suffixes, and its two
#: accelerometers, low-noise (``Accel_LN``, preferred) and wide-range (``Accel_WR``)
_CAL_TOKENS = ("cal", "calibrated")
_RAW_TOKENS = ("raw", "uncal", "uncalibrated")
_ACC_VARIANTS = {"ln": 0, "wr": 1}


def _split_header(h: str) -> tuple[str, str]:
    """``"Gyro X (deg/s)"`` -> ``("Gyro X", "deg/s")``: the name and the unit in trailing
    brackets (``""`` when there is none)."""
    m = re.search(r"[(\[{]([^)\]}]*)[)\]}]\s*$", h)
    if m:
        return h[:m.start()], m.group(1).strip()
    return h, ""


def _is_channel(key: str) -> bool:
    """Whether a lower-case alphanumeric key names a channel this reader knows."""
    for aliases in _GROUP_ALIASES.values():
        for a in aliases:
            if len(key) > len(a) and key.startswith(a) and key[len(a)] in "xyz" and (
                    len(key) == len(a) + 1 or key[len(a) + 1:] in _NAME_UNITS):
                return True
    if key in _COUNTER_ALIASES:
        return True
    return any(key == a or (key.startswith(a) and key[len(a):] in TIME_UNITS)
               for a in _TIME_ALIASES + _WEAK_TIME_ALIASES)


@dataclass(frozen=True)
class _Column:
    """One header cell read as ``<sensor prefix> <channel> [qualifiers] (unit)``."""

    prefix: str   # the sensor it belongs to as written (``Shimmer_8C4F``), "" for none
    key: str      # lower-case alphanumeric channel (``accelx``, ``timestampunix``)
    unit: str
    rank: int     # 0 = preferred; 1 = second choice (a wide-range accelerometer)
    raw: bool     # uncalibrated counts: never used


def _parse_column(h: str, unit_cell: str) -> _Column:
    name, unit = _split_header(h)
    words = re.findall(r"[A-Za-z0-9]+", name)
    low = [w.lower() for w in words]
    raw = bool(low) and low[-1] in _RAW_TOKENS
    while low and low[-1] in _CAL_TOKENS + _RAW_TOKENS:
        low.pop()
    unit = unit or unit_cell
    # the shortest sensor prefix that leaves a known channel: Shimmer_8C4F_Gyro_X_CAL
    for i in range(len(low)):
        tail = low[i:]
        key = "".join(w for w in tail if w not in _ACC_VARIANTS or len(tail) == 1)
        if key and _is_channel(key):
            rank = max((_ACC_VARIANTS.get(w, 0) for w in tail), default=0)
            return _Column("_".join(words[:i]), key, unit, rank, raw)
    return _Column("", "".join(low), unit, 0, raw)


@dataclass
class _Layout:
    """Where one sensor's channels are in a CSV."""

    groups: dict[str, list[int]]
    t_idx: int | None
    t_unit: str
    c_idx: int | None
    units: dict[int, str]
    sensor: str = ""
    sensors: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    second: dict[str, list[int]] = field(default_factory=dict)  # see _groups_of


class MultipleSensorsError(InputError):
    """A CSV holds several sensors' channels and none was chosen.

    Attributes:
        sensors: the sensors found (their column-name prefixes), in file order.
    """

    def __init__(self, message: str, sensors: list[str]) -> None:
        super().__init__(message)
        self.sensors = sensors


def _groups_of(cols: list[_Column], prefix: str) -> tuple[
        dict[str, list[int]], dict[int, str], dict[str, list[int]]]:
    """Column indices of each complete X/Y/Z group of one sensor, units named in keys, and
    second-choice groups (Shimmer's wide-range accelerometer beside the low-noise one)."""
    groups: dict[str, list[int]] = {}
    name_units: dict[int, str] = {}
    second: dict[str, list[int]] = {}
    mine = [(i, c) for i, c in enumerate(cols) if c.prefix == prefix and not c.raw]
    mine.sort(key=lambda ic: ic[1].rank)  # the low-noise accelerometer first
    for g, aliases in _GROUP_ALIASES.items():
        idx = [next((i for i, c in mine if c.key in {a + ax for a in aliases}), -1)
               for ax in "xyz"]
        if not all(i >= 0 for i in idx):  # a unit in the name: gyr_x_dps, acc_x_ms2
            found = [next(((i, c.key[len(a) + 1:]) for i, c in mine for a in aliases
                           if c.key.startswith(a + ax) and c.key[len(a) + 1:] in _NAME_UNITS),
                          (-1, "")) for ax in "xyz"]
            idx = [i for i, _ in found]
            for i, u in found:
                if i >= 0:
                    name_units[i] = _NAME_UNITS[u]
        if all(i >= 0 for i in idx):
            groups[g] = idx
            alt = [next((i for i, c in mine if c.rank == 1 and c.key in {a + ax for a in aliases}),
                        -1) for ax in "xyz"]
            if all(i >= 0 for i in alt) and alt != idx:
                second[g] = alt
    return groups, name_units, second


def _is_temperature(c: _Column) -> bool:
    return "temp" in c.key or c.unit.strip().lower().replace(" ", "") in _TEMPERATURE_UNITS


def _increasing(v: FloatArray) -> bool:
    """Time-like values: finite, never decreasing, rising on most steps."""
    d = np.diff(v)
    return bool(len(d) and np.all(np.isfinite(v)) and np.all(d >= 0) and np.mean(d > 0) > 0.5)


def _find_columns(header: list[str], units_row: list[str], data: FloatArray, name: str,
                  sensor: str | None = None,
                  text: dict[int, tuple[int, str]] | None = None,
                  dates: set[int] | None = None) -> _Layout:
    """Which columns hold the chosen sensor's X/Y/Z groups, its time and sample counter.

    Columns may carry a sensor prefix (``Shimmer_8C4F_Gyro_X_CAL``, ``S2_acc_x``); a file
    with several sensors needs ``sensor`` (a prefix, or its last part such as ``8C4F``).

    Raises:
        MultipleSensorsError: several sensors and no (or no matching) choice.
    """
    cols = [_parse_column(h, units_row[i] if i < len(units_row) else "")
            for i, h in enumerate(header)]
    prefixes = list(dict.fromkeys(c.prefix for c in cols))
    complete = [p for p in prefixes if {"gyr", "acc"} <= set(_groups_of(cols, p)[0])]
    chosen = ""
    if sensor:
        want = sensor.strip().lower()
        hits = [p for p in complete if p.lower() == want] or [
            p for p in complete if p.lower().split("_")[-1] == want
            or p.lower().endswith("_" + want)]
        if len(hits) != 1:
            raise MultipleSensorsError(
                f"{name}: no sensor {sensor!r} in the file; it holds "
                + (", ".join(p or "(unprefixed columns)" for p in complete) or "no complete "
                   "gyroscope + accelerometer set") + "; choose one of those", complete)
        chosen = hits[0]
    elif len(complete) > 1:
        listing = ", ".join(p or "(unprefixed columns)" for p in complete)
        raise MultipleSensorsError(
            f"{name}: the file holds {len(complete)} sensors ({listing}); choose the one to "
            f"read with sensor (e.g. {complete[-1]!r})", complete)
    elif complete:
        chosen = complete[0]
    groups, name_units, second = _groups_of(cols, chosen)
    units = {i: c.unit for i, c in enumerate(cols) if c.unit}
    for i, u in name_units.items():
        units.setdefault(i, u)
    notes: list[str] = []
    # time: the sensor's own column, else a shared (unprefixed) one; a strong name first,
    # a bare 't' only when it increases; never a temperature
    t_idx, t_unit = None, ""
    # ISO date-time columns last: a numeric clock beside them is the finer one
    for strong, as_date in ((True, False), (False, False), (True, True)):
        for p in dict.fromkeys((chosen, "")):
            for i, c in enumerate(cols):
                if t_idx is not None or c.prefix != p or c.raw or _is_temperature(c):
                    continue
                if (i in (dates or ())) != as_date:
                    continue
                aliases = _TIME_ALIASES if strong else _WEAK_TIME_ALIASES
                base = next((a for a in aliases if c.key == a or (
                    c.key.startswith(a) and c.key[len(a):] in TIME_UNITS)), None)
                if base is None:
                    continue
                suffix = c.key[len(base):]
                if text and i in text:  # a formatted date ("2021/01/02 15:23:28.123")
                    notes.append(f"column {header[i]!r} holds text ({text[i][1][:30]!r}), "
                                 "so it is not taken for the time")
                    continue
                said = c.unit.strip().lower() in TIME_UNITS  # "T (s)": time by its unit
                if not strong and not suffix and not said and not _increasing(data[:, i]):
                    notes.append(f"column {header[i]!r} does not increase, so it is not "
                                 "taken for the time")
                    continue
                t_idx, t_unit = i, suffix
    if t_idx is not None:
        t_unit = units.get(t_idx, t_unit)
    c_idx = next((i for p in dict.fromkeys((chosen, "")) for i, c in enumerate(cols)
                  if c.prefix == p and c.key in _COUNTER_ALIASES), None)
    return _Layout(groups, t_idx, t_unit, c_idx, units, chosen, complete, notes, second)


def _detect(g: str, raw: FloatArray) -> tuple[str, str] | None:
    """Guess a group's unit from its magnitudes: ``(unit, why)`` or ``None`` if ambiguous.

    Gravity fixes the accelerometer unit and the Earth's field (25-65 µT) the
    magnetometer's; a gyroscope is only sure to be in deg/s when its rates would be
    impossible in rad/s — a slow walk in deg/s looks like a fast one in rad/s.
    """
    norm = np.linalg.norm(raw, axis=1)
    norm = norm[np.isfinite(norm)]
    if not len(norm):
        return None
    med = float(np.median(norm))
    if g == "gyr":
        p99 = float(np.percentile(norm, 99))
        if p99 > _MAX_GYR_RAD:
            return "deg/s", f"rates reach {p99:.0f}, impossible in rad/s"
        return None
    if g == "acc":
        # gravity: the median magnitude within 25 % of 1 g, and rarely far below it — a
        # 'linear acceleration' (gravity removed) of ~1 m/s² must not pass for g
        p10 = float(np.percentile(norm, 10))
        for unit, one_g in (("g", 1.0), ("m/s2", G), ("mg", 1000.0)):
            if 0.8 * one_g < med < 1.25 * one_g and p10 > 0.5 * one_g:
                return unit, f"median magnitude {med:.3g}"
        return None
    # "norm": Xsens' a.u. (1 = the field at calibration); gauss stays below 0.7 on Earth
    bands = {"uT": (20.0, 70.0), "G": (0.2, 0.7), "norm": (0.75, 1.5), "mT": (0.02, 0.07),
             "nT": (2e4, 7e4)}
    for unit, (lo, hi) in bands.items():
        if lo < med < hi:
            return unit, f"median magnitude {med:.3g}"
    return None


def load_csv(
    path: str | Path,
    *,
    gyr_unit: str | None = None,
    acc_unit: str | None = None,
    mag_unit: str | None = None,
    time_unit: str | None = None,
    frequency: float | None = None,
    sensor: str | None = None,
    quat_order: str | None = None,
    quat_frame: str | None = None,
) -> ImuRecording:
    """Read a generic IMU CSV: time (or a sample counter), gyroscope, accelerometer and
    optionally magnetometer X/Y/Z columns, as other labs name them.

    Column names are matched ignoring case, spaces, ``_`` and a unit in brackets:
    ``gyr_x``, ``Gyr_X``, ``gyro x (deg/s)``, ``GyroscopeX``, ``wx``; ``acc_x``,
    ``Accelerometer X (g)``, ``ax``; ``mag_x``, ``Magnetometer X (uT)``, ``mx``; ``time``,
    ``t``, ``timestamp``, ``time_ms``; ``Packet number``, ``sample``, ``counter``. Other
    columns (quaternions, temperature ...) are ignored with a warning.

    Each unit is taken, in this order, from the argument (an explicit override), from the
    header (``(deg/s)`` or a units row under it), or from the magnitudes: gravity tells g
    from m/s², the Earth's field µT from gauss, mT or nT, the median step the time unit,
    rates above 40 rad/s mean deg/s. What was assumed is said in ``warnings`` and
    ``meta["units_from"]``; a slow recording whose gyroscope unit cannot be told is refused
    until ``gyr_unit`` is given.

    Args:
        path: the CSV file (comma, semicolon or tab separated, decimal point or comma).
        gyr_unit: ``"rad/s"`` or ``"deg/s"``; ``None`` = header or detection.
        acc_unit: ``"m/s2"``, ``"g"`` or ``"mg"``; ``None`` = header or detection.
        mag_unit: ``"uT"``, ``"nT"``, ``"mT"``, ``"G"``, ``"mG"``, ``"norm"``, ``"none"``
            (ignore the magnetometer) or ``None`` (header or detection; no magnetometer
            when the file has none).
        time_unit: ``"s"``, ``"ms"``, ``"us"`` or ``"ns"``; ``None`` = header or detection.
        frequency: sampling rate, Hz: needed without a time column (with a sample counter,
            dropped samples keep their place).
        sensor: which sensor to read from a file with several (columns prefixed per
            sensor: ``Shimmer_8C4F_Gyro_X_CAL``, ``S2_Acc_X``): the prefix
            (``Shimmer_8C4F``) or its last part (``8C4F``); ``None`` for a one-sensor file.
        quat_order: order of reference quaternion columns numbered ``q1..q4``:
            ``"wxyz"`` (scalar first) or ``"xyzw"`` (scalar last); ``None`` = told from
            gravity (see :func:`_reference_quaternions`). Named components (``qw, qx …``,
            ``Quat_W``) and ``q0..q3`` (scalar q0) need none.
        quat_frame: earth frame of the reference quaternions, ``"ENU"`` or ``"NED"``
            (converted to ENU, the filters' frame); ``None`` = told from gravity.

    Returns:
        The recording in SI units, time first axis; what was assumed is in ``warnings``
        and ``meta["units_from"]``, a reference orientation in ``quat_ref``
        (sensor-to-ENU).

    Raises:
        MultipleSensorsError: several sensors in the file and ``sensor`` names none of
            them (the message and ``.sensors`` list those found).
        InputError: missing columns, unknown or undeterminable units, units contradicted
            by the data, bad timing.
    """
    p = Path(path)
    dates: set[int] = set()
    header, data, units_row, text = _read_csv(p, dates)
    if len(data) < 2:
        raise InputError(f"{p.name}: need at least two samples, got {len(data)}")
    lay = _find_columns(header, units_row, data, p.name, sensor, text, dates)
    groups, t_idx, t_unit, c_idx, col_units = (lay.groups, lay.t_idx, lay.t_unit, lay.c_idx,
                                               lay.units)
    if t_idx is not None and t_idx in dates:  # ISO date-times, read as POSIX seconds
        t_unit, time_unit = "s", None
        col_units.pop(t_idx, None)
    _text_error(p, text, {i for idx in groups.values() for i in idx}
                | {i for i in (t_idx, c_idx) if i is not None})
    declared = {"gyr": gyr_unit, "acc": acc_unit, "mag": mag_unit}
    need = ["gyr", "acc"] + (["mag"] if mag_unit not in (None, "none") else [])
    missing = [g for g in need if g not in groups]
    if missing:
        bare = {h.strip().lower() for h in header} >= {"x", "y", "z"}
        raise InputError(
            f"{p.name}: missing columns: no {' or '.join(_GROUP_NAMES[g] for g in missing)} "
            "X/Y/Z; "
            + ("the file holds one sensor's x, y, z (phone apps such as Sensor Logger write "
               "one file per sensor): upload the app's zip (or read its folder) instead, or "
               "merge them into one CSV with " if bare else "name them e.g. ")
            + "time, gyr_x, gyr_y, gyr_z, acc_x, acc_y, acc_z[, mag_x, mag_y, "
            f"mag_z] (found {header})")
    if mag_unit == "none":
        groups.pop("mag", None)
    warnings: list[str] = list(lay.notes)
    if "acc" in lay.second and _saturates(data[:, groups["acc"]]):
        # Shimmer3's low-noise accelerometer ends at ±2 g: a shank's heel strikes exceed it
        warnings.append(f"the low-noise accelerometer ({header[groups['acc'][0]]} …) "
                        "saturates; the wide-range one "
                        f"({header[lay.second['acc'][0]]} …) is read instead")
        groups["acc"] = lay.second["acc"]
    meta: dict[str, Any] = {"format": "csv", "source": str(p), "units_from": {},
                            "columns": header}
    if lay.sensor:
        meta["sensor"] = lay.sensor
        meta["sensors"] = lay.sensors
    tables = {"gyr": GYR_UNITS, "acc": ACC_UNITS, "mag": MAG_UNITS}
    out: dict[str, FloatArray] = {}
    for g, idx in groups.items():
        raw = data[:, idx]
        what = _GROUP_NAMES[g]
        in_header = next((col_units[i] for i in idx if i in col_units), "")
        unit, source = declared[g], "declared"
        if unit is None and in_header:
            unit, source = in_header, "header"
        if unit is None:
            found = _detect(g, raw)
            if found is None:
                hint = {"gyr": "rad/s or deg/s",
                        "acc": "m/s2, g or mg; gravity must not be removed",
                        "mag": "uT, G, mT, nT or norm"}[g]
                raise InputError(
                    f"{p.name}: generic CSV needs declared units — cannot tell the {what} "
                    f"unit from the data; declare {g}_unit ({hint})")
            unit, source = found[0], "detected"
            warnings.append(f"assumed {what} in {unit} ({found[1]}); declare {g}_unit if "
                            "that is wrong")
        if g == "mag" and unit.strip().lower().replace(" ", "") in _ARBITRARY_MAG_UNITS:
            # Shimmer 'local_flux', Xsens 'a.u.': scaled to the local field, direction only
            unit = "norm"
        elif source == "declared" and in_header and not np.isclose(
                _unit(tables[g], in_header, what) if _known(tables[g], in_header) else -1.0,
                _unit(tables[g], unit, what)):
            warnings.append(f"declared {what} unit {unit!r} overrides the header's "
                            f"{in_header!r}")
        try:
            factor = _unit(tables[g], unit, what)
        except InputError as e:
            raise InputError(f"{p.name}: {e} (from the {source} units"
                             + (f"; declare {g}_unit)" if source == "header" else ")")) from None
        out[g] = raw * factor
        meta[f"{g}_unit"] = unit
        meta["units_from"][g] = source
    meta.setdefault("mag_unit", "")
    used = {i for idx in groups.values() for i in idx}
    clock = t_idx is not None and _parse_column(header[t_idx], "").key == "sampletimefine"
    time = _csv_time(p, data, t_idx, t_unit, c_idx, time_unit, frequency, meta, warnings,
                     clock=clock)
    used |= {i for i in (t_idx, c_idx) if i is not None}
    ignored = [h for i, h in enumerate(header) if i not in used]
    if ignored:
        warnings.append(_ignored_warning(ignored))
    gyr, acc, mag = out["gyr"], out["acc"], out.get("mag")
    q_idx, named = _quat_columns(header, lay.sensor)
    quat = None
    if q_idx:
        used |= set(q_idx)
        warnings[:] = [w for w in warnings if not w.startswith(_IGNORED_WARNING)]
        ignored = [h for i, h in enumerate(header) if i not in used]
        if ignored:
            warnings.append(_ignored_warning(ignored))
        quat = _reference_quaternions(p.name, data[:, q_idx], named, gyr, acc, quat_order,
                                      quat_frame, meta, warnings)
    time, keep = _drop_repeated_rows(time, np.column_stack([a for a in (gyr, acc, mag)
                                                           if a is not None]), warnings)
    rec = _finalise(time, gyr[keep], acc[keep], None if mag is None else mag[keep], p.stem,
                    meta, warnings, frequency=frequency)
    if quat is not None:
        rec.quat_ref = quat[keep]
    return rec


_QUAT_RE = re.compile(r"^(?P<pre>.*?)(quaternion|quat|q)(?P<c>[wxyz]|q[0-4]|[0-4])$")


def _quat_columns(header: list[str], sensor: str) -> tuple[list[int], bool]:
    """Columns of a reference orientation quaternion of ``sensor`` (its prefix; "" for
    unprefixed): ``([w, x, y, z] indices, True)`` for named components and ``q0..q3``
    (Xsens' ``Quat_q0``: the scalar is q0), ``(indices in number order, False)`` for
    ``q1..q4`` (whose scalar may be q1 or q4), ``([], False)`` when there are none."""
    want = re.sub(r"[^a-z0-9]", "", sensor.lower())
    comps: dict[str, int] = {}
    for i, h in enumerate(header):
        key = "".join(re.findall(r"[a-z0-9]+", _split_header(h)[0].lower()))
        m = _QUAT_RE.match(key)
        if m and m.group("pre") in (want, ""):
            comps.setdefault(m.group("c").lstrip("q") or m.group("c"), i)
    if all(c in comps for c in "wxyz"):
        return [comps[c] for c in "wxyz"], True
    if all(d in comps for d in "0123"):  # q0 is the scalar wherever numbering starts at 0
        return [comps[d] for d in "0123"], True
    if all(d in comps for d in "1234"):  # q1..q4: scalar first or last, both are used
        return [comps[d] for d in "1234"], False
    return [], False


#: ENU <- NED: x_enu = y_ned (east), y_enu = x_ned (north), z_enu = -z_ned; a half turn
#: about (1, 1, 0)/√2
_Q_ENU_NED = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])


def _reference_quaternions(
    name: str, raw: FloatArray, named: bool, gyr: FloatArray, acc: FloatArray,
    order: str | None, frame: str | None, meta: dict[str, Any], warnings: list[str],
) -> FloatArray | None:
    """A file's reference orientation as w-first sensor-to-ENU quaternions (what the
    filters estimate and :func:`engine.imu.metrics.orientation_errors` compares).

    What a file does not say is told from gravity: the accelerometer of a sensor at rest
    measures the earth's up direction, which a correct reading of the quaternion must
    rotate into the sensor frame. Candidates: scalar first or last (numbered columns
    only), an ENU (up = +Z) or NED (up = -Z) earth frame, sensor-to-earth or the inverse.
    The one whose up agrees with the accelerometer (median angle over near-rest samples
    under 15°, the next candidate at least twice as far off) is taken and said. ENU and
    another Z-up frame (NWU) differ in heading only and cannot be told apart: Z-up files
    are read as ENU.

    Returns ``None`` (with a warning saying what to declare) when no candidate, or more
    than one, agrees with gravity: the reference is optional, the recording still loads.

    Raises:
        InputError: unknown ``order``/``frame``.
    """
    orders = ["wxyz"] if named else ["wxyz", "xyzw"]
    if order is not None:
        o = order.strip().lower()
        if o not in ("wxyz", "xyzw"):
            raise InputError(f"unknown quat_order {order!r}; use 'wxyz' (scalar first) or "
                             "'xyzw' (scalar last)")
        orders = ["wxyz"] if named else [o]
    frames = ["ENU", "NED"]
    if frame is not None:
        f = frame.strip().upper()
        if f not in ("ENU", "NED"):
            raise InputError(f"unknown quat_frame {frame!r}; use 'ENU' (Z up) or 'NED' "
                             "(Z down)")
        frames = [f]
    an = np.linalg.norm(acc, axis=1)
    ok = np.all(np.isfinite(raw), axis=1) & np.isfinite(an) & (an > 0)
    # near-gravity samples anywhere in the recording, not only at rest: the rests are
    # often one pose, where two readings can agree by chance (w-first ENU and x-first NED
    # within 1° on a BROAD trial's 26 s rest)
    quiet = ok & (np.abs(an - G) < 0.1 * G)
    use = quiet if quiet.sum() >= 20 else ok
    scored: list[tuple[float, str, str, bool]] = []
    a_dir = acc[use] / an[use, None]
    for o in orders:
        q = raw[use] if o == "wxyz" else raw[use][:, [3, 0, 1, 2]]
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
        for f in frames:
            up = np.array([0.0, 0.0, 1.0 if f == "ENU" else -1.0])
            for inverse in (False, True):
                qs = quat_conj(q) if inverse else q  # sensor-to-earth
                up_s = quat_rotate(quat_conj(qs), up)
                ang = np.degrees(np.arccos(np.clip(np.sum(up_s * a_dir, axis=1), -1, 1)))
                scored.append((float(np.median(ang)) if len(ang) else 180.0, o, f, inverse))
    # order and frame first (each with its better direction), then the direction: a
    # sensor turning about the vertical only looks the same both ways, and is then read
    # as sensor-to-earth (the usual convention), with a warning
    groups = sorted({(o, f): min(a for a, o2, f2, _ in scored if (o2, f2) == (o, f))
                     for _, o, f, _ in scored}.items(), key=lambda kv: kv[1])
    told = len(groups) > 1
    (o, f), best_deg = groups[0]
    if told and (best_deg > 15.0 or groups[1][1] < 2.0 * best_deg + 1.0):
        listing = "; ".join(f"{o2} {f2}: {a:.0f}°" for (o2, f2), a in groups[:3])
        warnings.append(
            "reference quaternion columns ignored: cannot tell how they are meant (their up "
            f"direction against the accelerometer's: {listing}); declare quat_order "
            "('wxyz' or 'xyzw') and quat_frame ('ENU' or 'NED') to use them")
        return None
    fwd = next(a for a, o2, f2, inv in scored if (o2, f2, inv) == (o, f, False))
    back = next(a for a, o2, f2, inv in scored if (o2, f2, inv) == (o, f, True))
    inverse = back < 0.5 * fwd - 1.0
    if not inverse and fwd > 0.5 * back - 1.0:
        warnings.append("the reference quaternions' direction cannot be told from gravity "
                        "(the sensor turned about the vertical only); read as "
                        "sensor-to-earth")
    best = (min(fwd, back), o, f, inverse)
    q = raw if o == "wxyz" or named else raw[:, [3, 0, 1, 2]]
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    if inverse:
        q = quat_conj(q)
    if f == "NED":
        q = quat_mul(_Q_ENU_NED, q)
    q = np.where(q[:, :1] < 0, -q, q)  # one hemisphere, as a reference is usually kept
    meta["quat_ref"] = {"order": o, "frame": f, "inverse": inverse,
                        "from": "detected" if told else "declared",
                        "gravity_deg": round(best[0], 2)}
    if told:
        warnings.append(
            f"reference quaternions read as {'scalar-first' if o == 'wxyz' else 'scalar-last'}"
            f", {'earth-to-sensor' if inverse else 'sensor-to-earth'}, {f} frame (their up "
            f"agrees with the accelerometer within {best[0]:.1f}°); declare quat_order and "
            "quat_frame if that is wrong")
    return np.asarray(q, dtype=float)


def _known(table: dict[str, float], unit: str) -> bool:
    return unit.strip().lower().replace(" ", "") in {k.lower() for k in table}


def _csv_time(p: Path, data: FloatArray, t_idx: int | None, t_unit: str, c_idx: int | None,
              time_unit: str | None, frequency: float | None, meta: dict[str, Any],
              warnings: list[str], *, clock: bool = False) -> FloatArray:
    """Time in s from a time column (unit declared, in the header or from the step), a
    sample counter and the rate, or the rate alone.

    ``clock``: the column is Xsens' ``SampleTimeFine``, a uint32 clock that wraps after
    2³² ticks — µs on Movella DOT, 100 µs ticks on MTi/MTw (told apart by the rate)."""
    if t_idx is None:
        if not frequency:
            why = "".join(f" ({w})" for w in warnings if w.endswith("taken for the time"))
            raise InputError(f"{p.name}: no time column{why}; pass the sampling frequency")
        if c_idx is None:
            meta["time_from"] = "frequency"
            return np.arange(len(data)) / float(frequency)
        c = data[:, c_idx]
        if not np.all(np.isfinite(c)):
            raise InputError(f"{p.name}: the sample counter {c_idx + 1} has empty cells")
        d = np.diff(c)
        if np.any(d < 0) and c.max() > 0:  # a wrapping packet counter (uint8/16/32)
            d[d < 0] += 2.0 ** np.ceil(np.log2(c.max() + 1))
        meta["time_from"] = "counter"
        return np.r_[0.0, np.cumsum(d)] / float(frequency)
    raw = data[:, t_idx]
    _check_rounded_time(p.name, raw, "(file units)")
    if clock and np.all(np.isfinite(raw)):
        d = np.diff(raw)
        wrap = d < -(2.0 ** 31)
        if wrap.any():
            raw = raw + np.r_[0.0, np.cumsum(wrap)] * 2.0 ** 32
    dts = np.diff(raw[np.isfinite(raw)])
    step = float(np.median(dts[dts > 0])) if np.any(dts > 0) else 0.0
    if clock and not t_unit and time_unit is None and step:
        t_unit = "us" if step >= 250 else "100us"  # 4 kHz in µs: no IMU rate is faster
    unit, source = time_unit, "declared"
    if unit is None and t_unit:
        unit, source = t_unit, "header"
    if unit is None:
        # IMUs sample at 4 Hz-4 kHz: each unit's step range is one decade band of its own
        unit = next((u for u, f in (("s", 1.0), ("ms", 1e-3), ("us", 1e-6), ("ns", 1e-9))
                     if step and 1 / 4000 <= step * f < 1 / 4), None)
        if unit is None:
            raise InputError(f"{p.name}: cannot tell the time unit from the median step "
                             f"{step:g}; declare time_unit (s, ms, us or ns)")
        source = "detected"
        warnings.append(f"assumed time in {unit} (median step {step:g} = "
                        f"{1 / (step * TIME_UNITS[unit]):.4g} Hz); declare time_unit if "
                        "that is wrong")
    scale = TIME_UNITS.get(unit.strip().lower())
    if scale is None:
        raise InputError(f"{p.name}: unknown time unit {unit!r}; use one of s, ms, us, ns")
    if step and not 0.5 <= 1 / (step * scale) <= 20000:
        better = next((u for u, f in (("s", 1.0), ("ms", 1e-3), ("us", 1e-6), ("ns", 1e-9))
                       if 1 / 4000 <= step * f < 1 / 4), None)
        raise InputError(
            f"{p.name}: with time in {unit} ({source}) the samples are "
            f"{step * scale:g} s apart ({1 / (step * scale):.3g} Hz), not an IMU rate"
            + (f"; the time is probably in {better}, declare time_unit {better!r}"
               if better else "; check the time column"))
    meta["time_unit"], meta["time_from"] = unit, source
    return raw * scale


def _ignored_warning(ignored: list[str]) -> str:
    """The warning naming the columns a reader left unused ("ignored columns: a, b")."""
    return f"{_IGNORED_WARNING}{'' if len(ignored) == 1 else 's'}: {', '.join(ignored)}"


def _drop_repeated_rows(time: FloatArray, values: FloatArray,
                        warnings: list[str]) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Drop rows that repeat the previous row exactly (same time, same values): loggers
    write them when a packet is sent twice. A repeated time with other values stays an
    error (in :func:`_finalise`)."""
    same = np.r_[False, (time[1:] == time[:-1])
                 & np.all((values[1:] == values[:-1]) | (np.isnan(values[1:])
                                                         & np.isnan(values[:-1])), axis=1)]
    if same.any():
        warnings.append(f"dropped {count(int(same.sum()), 'repeated row')} (same time and "
                        "values)")
    return time[~same], ~same


#: The options :func:`load_imu` passes on to :func:`load_csv`.
_CSV_OPTIONS = frozenset({"gyr_unit", "acc_unit", "mag_unit", "time_unit", "frequency",
                          "sensor", "quat_order", "quat_frame"})


def load_imu(path: str | Path, **kwargs: Any) -> ImuRecording:
    """Read any supported IMU file, choosing the reader from extension and content.

    ``**kwargs`` go to :func:`load_csv` (units, frequency) for text files; an APDM
    ``.h5`` takes ``sensor`` (and ``quat_order``/``quat_frame``), see :func:`load_apdm`; an
    Xsens ``.mvnx`` takes ``sensor`` (:func:`load_mvnx`); a ``.zip`` or a folder of a
    phone app's per-sensor files takes ``platform`` (:func:`load_phone`).

    Args:
        path: The recording (file, or a folder of a phone app's files).
        **kwargs: Reader options as above (all of them are :func:`load_csv`'s for a
            CSV; the other readers ignore the options they do not take).

    Returns:
        The recording in SI units (rad/s, m/s², µT), time first axis, with ``warnings``.

    Raises:
        InputError: unsupported file or any reader error.
    """
    p = Path(path)
    suf = p.suffix.lower()
    if p.is_dir() or suf == ".zip":  # a phone app's one file per sensor
        return load_phone(p, platform=kwargs.get("platform"))
    if suf == ".mvnx":
        return load_mvnx(p, sensor=kwargs.get("sensor"))
    if suf in (".xls", ".xlsx"):
        raise InputError(f"{p.name}: Excel workbooks are not read; export the recording as "
                         "CSV (phyphox: 'CSV (Comma, decimal point)', zipped)")
    if suf in (".hdf5", ".h5"):
        if _is_apdm(p):
            return load_apdm(p, sensor=kwargs.get("sensor"),
                             quat_frame=kwargs.get("quat_frame"))
        return load_broad(p)
    if suf == ".mat":
        names = {n for n, _, _ in _mat_variables(p)}
        if _is_sensorlog(names):
            # MATLAB Mobile's sensorlog: timetables, MATLAB objects no other reader opens
            raise InputError(
                f"{p.name}: a MATLAB Mobile sensor log — its timetables (Acceleration, "
                "AngularVelocity, MagneticField) can only be opened in MATLAB. There, write "
                "each as CSV with seconds from one start, e.g. t0 = Acceleration.Timestamp(1);"
                " T = timetable2table(Acceleration); T.t = seconds(T.Timestamp - t0); "
                "writetable(T(:, {'t','X','Y','Z'}), 'Accelerometer.csv') — the same t0 for "
                "AngularVelocity (Gyroscope.csv) and MagneticField (Magnetometer.csv) — zip "
                "the files and upload the zip")
        return load_broad(p) if _mat_reader_vars(names) == _BROAD_MAT_VARS else \
            load_madgwick_mat(p)
    if suf in (".csv", ".txt", ".tsv"):
        # x-IMU exports are one case of the generic reader (their headers carry the units)
        unknown = sorted(set(kwargs) - _CSV_OPTIONS)
        if unknown:
            raise InputError(f"{p.name}: the CSV reader has no option {', '.join(unknown)}"
                             f" (it takes {', '.join(sorted(_CSV_OPTIONS))}; 'platform' "
                             "is for a phone app's .zip or folder)")
        rec = load_csv(p, **kwargs)
        if any(h.startswith("Gyroscope X") for h in rec.meta.get("columns", ())):
            rec.meta["format"] = "x-imu-csv"
        return rec
    raise InputError(f"{p.name}: unsupported IMU file type {suf!r}; use .csv, .mat, .hdf5, "
                     ".mvnx (Xsens MVN) or .zip (a phone app's files)")


def load_mvnx(path: str | Path, sensor: str | None = None) -> ImuRecording:
    """One tracker of an Xsens MVN ``.mvnx`` export, readings in the sensor frame and its
    MVN orientation as the sensor-to-ENU reference (:func:`engine.imu._mvnx.load_mvnx`).

    Args:
        path: The ``.mvnx`` file.
        sensor: Tracker label (e.g. ``"RightLowerLeg"``); None for a one-tracker file.

    Returns:
        The tracker's recording: SI units, time first axis, sensor frame; ``quat_ref``
        sensor-to-ENU.

    Raises:
        MultipleSensorsError: several trackers and ``sensor`` names none of them.
        InputError: not an MVNX export, no sensor data, damaged XML.
    """
    from engine.imu._mvnx import load_mvnx as _load

    return _load(path, sensor)


def load_mvnx_all(path: str | Path) -> dict[str, ImuRecording]:
    """Every tracker of an Xsens MVN ``.mvnx`` export: label -> recording (time first axis,
    SI, sensor frame; ``quat_ref`` sensor-to-ENU). See :mod:`engine.imu._mvnx`.

    Args:
        path: The ``.mvnx`` file.

    Returns:
        Tracker label -> its recording, in file order.

    Raises:
        InputError: not an MVNX export, no sensor data, damaged XML.
    """
    from engine.imu._mvnx import load_mvnx_all as _load

    return _load(path)


def load_phone(path: str | Path | ZipDirectory, *, platform: str | None = None
               ) -> ImuRecording:
    """A phone app's one-file-per-sensor export (zip or folder: Sensor Logger, phyphox)
    merged on the gyroscope's time stamps, acceleration as specific force (iOS sign
    handled). See :mod:`engine.imu._phone`.

    Args:
        path: The app's ``.zip`` export or the folder of its per-sensor CSVs, or a zip's
            directory already read (``engine.imu._phone.read_zip_directory``: the zip is
            not opened again, and left open).
        platform: ``"ios"`` or ``"android"`` (the accelerometer's sign convention); None:
            told from the phone's orientation quaternions or Sensor Logger's metadata,
            else Android's convention with a warning.

    Returns:
        One recording in SI units on the gyroscope's time stamps (time first axis).

    Raises:
        InputError: no accelerometer or gyroscope file, an unsafe or oversized zip.
    """
    from engine.imu._phone import load_phone as _load

    return _load(path, platform=platform)


#: dropped-sample gaps up to this long are interpolated by :func:`fill_gaps`; longer
#: ones are left as NaN samples (the filters then hold the orientation)
MAX_FILLED_GAP_S = 0.5


def fill_gaps(rec: ImuRecording, max_gap_s: float = MAX_FILLED_GAP_S) -> ImuRecording:
    """The recording on a uniform time grid at its nominal rate, dropped samples filled.

    The orientation filters assume one sample every ``1 / frequency`` s: samples lost in
    transmission (Bluetooth IMUs, phone loggers) make them skip the rotation of the gap —
    on the BROAD fast-rotation trial, 1 % of the samples dropped in bursts of 5 raise the
    orientation error from 2.1° to 12°. Gaps up to ``max_gap_s`` are filled by linear
    interpolation of the rates, accelerations and field (the error is then 2.1° again);
    samples of longer gaps are NaN (skipped by the filters). A gap is a step of at least
    1.75 median steps (time-stamp jitter up to ±35 % is none); the grid's rate counts the
    missing periods. Grid points within half a step of a recorded sample take that
    sample's values, and a recording without gaps is returned unchanged (the same
    object). The reference
    quaternion and the movement mask take the nearest recorded sample's value, NaN/False
    in filled gaps.

    Args:
        rec: A recording (SI units, time first axis).
        max_gap_s: Longest gap filled by interpolation, s.

    Returns:
        The filled recording, with a warning saying how many samples were filled.
    """
    t = rec.time
    dts = np.diff(t)
    if len(dts) < 2:
        return rec
    # a gap is a step of 1.75 median steps or more: time-stamp jitter up to ±35 % is not
    # one. The grid's rate counts each gap's missing periods: (samples - 1 + missing) /
    # duration, unbiased by gaps and jitter (recording.frequency is not, with jitter)
    if not np.any(dts >= 1.75 * float(np.median(dts))):
        return rec
    fs = _nominal_rate(t)
    n = round((t[-1] - t[0]) * fs) + 1
    grid = t[0] + np.arange(n) / fs
    k = np.clip(np.searchsorted(t, grid), 1, len(t) - 1)
    near = np.where(np.abs(t[k - 1] - grid) <= np.abs(t[k] - grid), k - 1, k)
    gap = t[k] - t[k - 1]  # the recorded interval each grid point falls in
    hole = np.abs(t[near] - grid) > 0.5 / fs
    long_hole = hole & (gap > max_gap_s)
    if not hole.any():  # late samples (jitter), none missing: nothing to fill
        return rec

    def channels(a: FloatArray | None) -> FloatArray | None:
        if a is None:
            return None
        out = np.empty((n, 3))
        for c in range(3):
            ok = np.isfinite(a[:, c])
            out[:, c] = np.interp(grid, t[ok], a[ok, c]) if ok.sum() >= 2 else np.nan
        out[~hole] = a[near[~hole]]  # recorded samples as they are (NaN stays NaN)
        out[long_hole] = np.nan
        return out

    gyr, acc, mag = channels(rec.gyr), channels(rec.acc), channels(rec.mag)
    assert gyr is not None and acc is not None
    quat = None
    if rec.quat_ref is not None:
        quat = rec.quat_ref[near].copy()
        quat[hole] = np.nan
    movement = None
    if rec.movement is not None:
        movement = rec.movement[near] & ~hole
    n_fill = int((hole & ~long_hole).sum())
    warnings = [w for w in rec.warnings if _GAPS_WARNING not in w]
    warnings.append(f"{count(n_fill, 'dropped sample')} filled by interpolation"
                    + (f", {int(long_hole.sum())} in gaps longer than {max_gap_s:g} s left "
                       "empty" if long_hole.any() else "")
                    + f" (uniform {fs:.4g} Hz grid for the filters)")
    meta = {**rec.meta, "filled_samples": n_fill}
    return ImuRecording(time=grid, gyr=gyr, acc=acc, mag=mag, frequency=fs, name=rec.name,
                        quat_ref=quat, movement=movement, meta=meta, warnings=warnings)


def _is_sensorlog(names: set[str]) -> bool:
    """Whether a .mat's variables are MATLAB Mobile's sensor log (refused unread)."""
    return {"Acceleration", "AngularVelocity"} <= names and "Gyroscope" not in names


def _is_apdm(p: Path) -> bool:
    """Whether an HDF5 file has APDM's (Opal, Mobility Lab, Moveo) ``Sensors`` layout."""

    try:
        with _open_h5(p) as f:
            return _is_apdm_file(f)
    except Exception:  # not HDF5 at all: load_broad gives the error
        return False


def _is_apdm_file(f: Any) -> bool:
    """:func:`_is_apdm` of an open ``h5py.File``."""
    return "Sensors" in f and "imu_gyr" not in f


def load_apdm(path: str | Path, sensor: str | None = None,
              quat_frame: str | None = None) -> ImuRecording:
    """Read one sensor of an APDM HDF5 recording (file format 5: Opal, Mobility Lab,
    Moveo Explorer).

    Layout: ``Sensors/<id>/Accelerometer`` (m/s²), ``Gyroscope`` (rad/s), ``Magnetometer``
    (µT, optional), ``Time`` (µs since 1970), ``Sensors/<id>/Configuration`` attributes
    ``Label 0`` (e.g. ``Lumbar``) and ``Sample Rate``; ``Processed/<id>/Orientation``
    (quaternions, scalar first), when present, becomes the reference (its earth frame and
    direction told from gravity as for CSV columns, or ``quat_frame`` declared).

    Args:
        path: the ``.h5`` file.
        sensor: the sensor id or its label, for a file with several sensors.
        quat_frame: ``"ENU"`` or ``"NED"`` for the processed orientation.

    Returns:
        The sensor's recording in SI units, time first axis, with the device's own
        orientation estimate as ``quat_ref`` (sensor-to-ENU) when stored.

    Raises:
        MultipleSensorsError: several sensors and ``sensor`` names none of them (the
            message lists ids and labels).
        InputError: damaged file or missing datasets.
    """

    p = Path(path)
    try:
        with _open_h5(p) as f:
            sensors = f["Sensors"]
            ids = list(sensors.keys())
            labels = {}
            for i in ids:
                cfg = sensors[i].get("Configuration")
                lab = cfg.attrs.get("Label 0", b"") if cfg is not None else b""
                labels[i] = lab.decode() if isinstance(lab, bytes) else str(lab)
            listing = ", ".join(f"{i} ({labels[i]})" if labels[i] else i for i in ids)
            if sensor:
                want = sensor.strip().lower()
                hits = [i for i in ids if i.lower() == want or labels[i].lower() == want]
                if len(hits) != 1:
                    raise MultipleSensorsError(f"{p.name}: no sensor {sensor!r} in the file; "
                                               f"it holds {listing}", ids)
                sid = hits[0]
            elif len(ids) == 1:
                sid = ids[0]
            else:
                raise MultipleSensorsError(
                    f"{p.name}: the file holds {len(ids)} sensors ({listing}); choose the "
                    "one to read with sensor (its id or label)", ids)
            g = sensors[sid]
            missing = [k for k in ("Accelerometer", "Gyroscope", "Time") if k not in g]
            if missing:
                raise InputError(f"{p.name}: sensor {sid} lacks {', '.join(missing)}; not "
                                 "an APDM recording (file format 5)?")
            acc = _as_float(p, "Accelerometer", _h5_numbers(p, "Accelerometer",
                                                            g["Accelerometer"]))
            gyr = _as_float(p, "Gyroscope", _h5_numbers(p, "Gyroscope", g["Gyroscope"]))
            mag = (_as_float(p, "Magnetometer", _h5_numbers(p, "Magnetometer",
                                                            g["Magnetometer"]))
                   if "Magnetometer" in g else None)
            t_us = np.asarray(_h5_numbers(p, "Time", g["Time"]), dtype=np.int64)
            cfg = g.get("Configuration")
            rate = cfg.attrs.get("Sample Rate") if cfg is not None else None
            quat = None
            proc = f.get("Processed")
            if proc is not None and sid in proc and "Orientation" in proc[sid]:
                quat = _as_float(p, "Orientation", _h5_numbers(p, "Orientation",
                                                               proc[sid]["Orientation"]))
    except InputError:
        raise
    except FileNotFoundError as e:
        raise InputError(f"cannot read {p}: {e}") from None
    except Exception as e:  # a damaged file can trip any part of h5py
        raise _damaged(p, e) from None
    # µs integers relative to the start: float64 epoch µs would keep them too, but the
    # difference is exact
    time = (t_us - t_us[0]).astype(float) * 1e-6 if len(t_us) else t_us.astype(float)
    meta: dict[str, Any] = {"format": "apdm-h5", "source": str(p), "sensor": sid,
                            "label": labels[sid], "sensors": ids, "gyr_unit": "rad/s",
                            "acc_unit": "m/s2", "mag_unit": "uT" if mag is not None else "",
                            "start_unix_s": float(t_us[0]) * 1e-6 if len(t_us) else None}
    warnings: list[str] = []
    q_ref = None
    if quat is not None and quat.shape == (len(time), 4):
        q_ref = _reference_quaternions(p.name, quat, True, gyr, acc, None, quat_frame, meta,
                                       warnings)
    rec = _finalise(time, gyr, acc, mag, labels[sid] or sid, meta, warnings,
                    frequency=float(rate) if rate else None)
    rec.quat_ref = q_ref
    return rec


#: APDM datasets :func:`load_apdm` reads of one sensor (``Sensors/<id>/...``)
_APDM_DATASETS = ("Accelerometer", "Gyroscope", "Magnetometer", "Time")


def estimate_memory_bytes(path: str | Path) -> int:
    """Bytes a file's numbers take in memory once :func:`load_imu` reads them, told
    before reading any, from the file's size and its datasets' shapes: at least the
    file's size.

    A compressed HDF5 dataset or ``.mat`` variable can unpack to far more than the file
    (zeros a thousandfold), so for ``.h5``/``.hdf5`` and ``.mat`` the datasets the
    reader takes are counted at 8 bytes a number (they are converted to float64) from
    their headers: BROAD's five, an APDM sensor's (the largest sensor: one is read), a
    Madgwick ``.mat``'s four (a non-numeric one is refused unread, see ``_read_mat``).
    Any other file counts at its size: CSVs are parsed as they are, an ``.mvnx`` is
    parsed frame by frame keeping only the sensor data, and a phone ``.zip`` should be
    counted at its unpacked size (``engine.imu._phone.read_zip_directory``). A file
    that cannot be opened counts at its size: the reader then says why.

    Args:
        path: The uploaded file.

    Returns:
        The estimate in bytes.

    Raises:
        InputError: the file does not exist.
    """
    p = Path(path)
    try:
        size = p.stat().st_size
    except OSError as e:
        raise InputError(f"cannot read {p}: {e}") from None
    suf = p.suffix.lower()
    try:
        if suf == ".mat":
            listed = _mat_variables(p)
            names = {n for n, _, _ in listed}
            wanted = set() if _is_sensorlog(names) else set(_mat_reader_vars(names))
            numbers = sum(_numbers(shape) for n, shape, c in listed
                          if n in wanted and c in _MAT_NUMERIC)
            return max(size, 8 * numbers)
        if suf in (".h5", ".hdf5"):
            return max(size, _hdf5_bytes(p))
    except Exception:  # damaged: its reader says so in the file's turn
        return size
    return size


def _numbers(shape: tuple[int, ...] | None) -> int:
    out = 1
    for k in shape or (0,):
        out *= max(int(k), 0)
    return out


def _hdf5_bytes(p: Path) -> int:
    """Bytes of the datasets the BROAD or APDM reader takes (the larger of 8 and the
    item size a number), from their dataspaces: nothing is read."""
    import h5py

    def nbytes(obj: object) -> int:
        if not isinstance(obj, h5py.Dataset):
            return 0
        return _numbers(obj.shape) * max(8, obj.dtype.itemsize)

    with _open_h5(p) as f:
        if not _is_apdm_file(f):
            return sum(nbytes(f.get(k)) for k in _BROAD_KEYS)
        sensors = f["Sensors"]
        proc = f.get("Processed")
        largest = 0
        for sid in sensors:
            g = sensors[sid]
            n = sum(nbytes(g.get(k)) for k in _APDM_DATASETS) if isinstance(g, h5py.Group) \
                else 0
            if isinstance(proc, h5py.Group) and isinstance(proc.get(sid), h5py.Group):
                n += nbytes(proc[sid].get("Orientation"))
            largest = max(largest, n)
        return largest
