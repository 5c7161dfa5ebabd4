"""Phone apps that write one file per sensor (Sensor Logger, phyphox …), as a zip or a
folder, merged into one :class:`ImuRecording`.

Files are told by their name (case, spaces and ``_`` ignored): ``TotalAcceleration``,
``Accelerometer``, ``Acceleration``, ``AccelerometerUncalibrated`` (acceleration),
``LinearAcceleration``/``UserAcceleration`` and ``Gravity`` (their sum is the
acceleration), ``Gyroscope`` (``…Uncalibrated`` second), ``Magnetometer``/
``MagneticField`` (``…Uncalibrated`` second), ``Orientation``/``Attitude`` (quaternions),
``Metadata`` (Sensor Logger's platform). Each file holds a time column (``time`` in ns
since the epoch and ``seconds_elapsed`` in Sensor Logger, ``Time (s)`` in phyphox) and
bare ``x, y, z`` (in any order) or ``X (m/s^2)``/``Acceleration x (m/s^2)`` columns.

**Merge.** The streams share the phone's clock but not their instants or rates (an
Android phone samples the accelerometer at 400 Hz and the gyroscope at 200 Hz; iOS
apps time-stamp each sensor event on its own). The gyroscope's time stamps are the
common time base — the filters integrate its rates sample by sample, so they stay as
recorded — cut to the span every stream covers; acceleration, gravity and field are
interpolated linearly onto it, the orientation by slerp. A magnetometer that would cut
more than 1 s off the span is dropped instead (said in the warnings).

**iOS acceleration.** Core Motion reports acceleration with the opposite sign to
Android's (a phone face up on a table reads z = −1 g, Android +9.81 m/s²); Sensor Logger
keeps that unless "Standardise Units & Frames" is on. The sign cannot be told from the
gyroscope: a fixed world direction seen from the rotating phone turns the same way
whatever its sign. It is told, in this order, from the declared ``platform``; from the
phone's own orientation quaternions (their Z-up earth frame puts gravity's reaction up:
the sign whose rest-time acceleration agrees with it); from Sensor Logger's
``Metadata.csv`` (``platform`` = ios and ``standardisation`` false); else Android's
convention is assumed, with a warning. Units: m/s² unless the header says otherwise or
the magnitudes are 1 g (iOS raw in g).
"""

from __future__ import annotations

import csv
import re
import shutil
import struct
import tempfile
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np
from numpy.typing import NDArray

from engine.errors import InputError
from engine.geometry import quat_conj, quat_rotate
from engine.imu import io as _io
from engine.imu.io import ACC_UNITS, GYR_UNITS, MAG_UNITS, G, ImuRecording

FloatArray = NDArray[np.float64]

#: members a zip may have, and their total uncompressed size (zip bombs)
MAX_ZIP_MEMBERS = 256
MAX_ZIP_UNCOMPRESSED = 256 * 2**20
#: Bytes of a zip's central directory (its file list) read at most: ``zipfile`` parses the
#: whole list into objects of ~0.5 kB each when it opens a zip, before any member count can
#: be checked (a 64 MB upload of empty entries held ~1.4 M of them). 256 members with long
#: names and extra fields fit many times over.
MAX_ZIP_DIRECTORY_BYTES = 2**20
#: bytes of a metadata file read (Sensor Logger's Metadata.csv: two lines)
_MAX_METADATA_BYTES = 64 * 2**10
#: columns of one sensor file (Sensor Logger's orientation has 9; phyphox 4)
MAX_COLUMNS = 64
#: a magnetometer whose span would shorten the merged recording by more is dropped
_MAX_MAG_CUT_S = 1.0

#: normalised file stem -> (kind, rank: 0 preferred)
_KINDS: dict[str, tuple[str, int]] = {
    "totalacceleration": ("acc", 0), "accelerometer": ("acc", 1), "acceleration": ("acc", 1),
    "accelerationwithg": ("acc", 1), "accelerometerwithg": ("acc", 1), "accel": ("acc", 1),
    "acc": ("acc", 1), "accelerometeruncalibrated": ("acc", 2),
    "uncalibratedaccelerometer": ("acc", 2), "rawaccelerometer": ("acc", 2),
    "linearacceleration": ("lin", 0), "useracceleration": ("lin", 0),
    "accelerationwithoutg": ("lin", 0), "linearaccelerometer": ("lin", 0),
    "gravity": ("grav", 0),
    "gyroscope": ("gyr", 0), "gyro": ("gyr", 0), "gyr": ("gyr", 0), "rotationrate": ("gyr", 0),
    "angularvelocity": ("gyr", 0), "gyroscopeuncalibrated": ("gyr", 1),
    "uncalibratedgyroscope": ("gyr", 1),
    "magnetometer": ("mag", 0), "magneticfield": ("mag", 0), "mag": ("mag", 0),
    "magnetometeruncalibrated": ("mag", 1), "uncalibratedmagnetometer": ("mag", 1),
    "orientation": ("quat", 0), "attitude": ("quat", 0), "rotationvector": ("quat", 1),
    "gamerotationvector": ("quat", 2),
    "metadata": ("meta", 0), "device": ("meta", 1),  # phyphox: meta/device.csv
}
#: words before the axis letter in a column name (phyphox ``Acceleration x (m/s^2)``)
_AXIS_PREFIXES = {"", "acceleration", "acc", "accel", "accelerometer", "linearacceleration",
                  "gravity", "gyroscope", "gyro", "gyr", "rotationrate", "angularvelocity",
                  "magneticfield", "magnetometer", "mag", "magnetic", "field"}
_DEFAULT_UNIT = {"acc": "m/s2", "lin": "m/s2", "grav": "m/s2", "gyr": "rad/s", "mag": "uT"}
_TABLES = {"acc": ACC_UNITS, "lin": ACC_UNITS, "grav": ACC_UNITS, "gyr": GYR_UNITS,
           "mag": MAG_UNITS}
_WHAT = {"acc": "accelerometer", "lin": "linear acceleration", "grav": "gravity",
         "gyr": "gyroscope", "mag": "magnetometer", "quat": "orientation"}


def _stem_key(name: str) -> str:
    return re.sub(r"[^a-z0-9]", "", PurePosixPath(name).stem.lower())


@dataclass
class _Stream:
    """One sensor file: time (s, phone clock) and values in SI."""

    name: str
    time: FloatArray
    values: FloatArray
    unit: str = ""


# ----------------------------------------------------------------------- files


def _safe_member(name: str) -> bool:
    """Whether a zip member's name stays inside the archive (no absolute path, drive or
    ``..``); unsafe names are refused, never written anywhere."""
    if name.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", name):
        return False
    return ".." not in re.split(r"[\\/]", name)


def _sensor_members(infos: list[zipfile.ZipInfo]) -> list[zipfile.ZipInfo]:
    """The members :func:`load_phone` unpacks: text tables, not macOS's or hidden files."""
    return [i for i in infos if not i.is_dir() and i.filename.lower().endswith(
        (".csv", ".txt", ".tsv")) and not any(part.startswith(("__MACOSX", "."))
                                              for part in i.filename.split("/"))]


def _zip_directory_bytes(path: Path) -> int | None:
    """The size of a zip's central directory as its end record declares it, read from the
    file's last 64 kB (nothing else parsed); None when no end record is found.

    ``zipfile`` reads exactly that many bytes of file list and parses all of them, so
    bounding it bounds what opening the zip costs, whatever entry count the record claims.
    """
    with path.open("rb") as f:
        f.seek(0, 2)
        size = f.tell()
        tail_len = min(size, 22 + 0xFFFF)  # the end record, then at most a 64 kB comment
        f.seek(size - tail_len)
        tail = f.read(tail_len)
        at = tail.rfind(b"PK\x05\x06")
        if at < 0 or len(tail) - at < 22:
            return None
        directory = int(struct.unpack_from("<I", tail, at + 12)[0])
        loc = at - 20  # a Zip64 archive keeps the real size in its own end record
        if directory == 0xFFFFFFFF and loc >= 0 and tail[loc:loc + 4] == b"PK\x06\x07":
            f.seek(int(struct.unpack_from("<Q", tail, loc + 8)[0]))
            rec = f.read(56)
            if len(rec) == 56 and rec[:4] == b"PK\x06\x06":
                directory = int(struct.unpack_from("<Q", rec, 40)[0])
    return directory


def _open_zip(p: Path) -> zipfile.ZipFile:
    """``zipfile.ZipFile(p)`` once its file list is known to be of a phone recording's size.

    Raises:
        InputError: The file list is longer than :data:`MAX_ZIP_DIRECTORY_BYTES`.
        zipfile.BadZipFile, OSError: As ``zipfile`` raises them.
    """
    directory = _zip_directory_bytes(p)
    if directory is not None and directory > MAX_ZIP_DIRECTORY_BYTES:
        raise InputError(f"{p.name}: the zip's list of files is {directory / 2**20:.1f} MB, "
                         f"far longer than a phone recording's (at most {MAX_ZIP_MEMBERS} "
                         "files); zip one recording")
    return zipfile.ZipFile(p)


class ZipDirectory:
    """A phone app's zip with its directory (file list) read once, kept open to unpack.

    Made by :func:`read_zip_directory`; what a caller bounds (:attr:`unpacked_bytes`) is
    what :func:`load_phone` then unpacks, from the same parsed list. Close it (or use it
    in a ``with``) when done; :func:`load_phone` leaves a directory it is given open.

    Attributes:
        path: The zip file.
        members: Every entry of the zip, in its order.
        sensor_members: The entries :func:`load_phone` unpacks (text tables, not macOS's
            or hidden files).
        unpacked_bytes: Their declared sizes together: a bound, not an estimate
            (``zipfile`` never reads more of a member than its declared size; a member
            longer than declared fails its CRC).
    """

    def __init__(self, path: Path, zf: zipfile.ZipFile) -> None:
        self.path = path
        self._zf = zf
        self.members = zf.infolist()
        self.sensor_members = _sensor_members(self.members)
        self.unpacked_bytes = sum(i.file_size for i in self.sensor_members)

    def close(self) -> None:
        """Close the zip file."""
        self._zf.close()

    def __enter__(self) -> ZipDirectory:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_zip_directory(path: str | Path) -> ZipDirectory:
    """Open a phone app's zip and read its directory, once (nothing is unpacked).

    Args:
        path: The zip file.

    Returns:
        Its members and the bytes :func:`load_phone` would unpack, the zip kept open for
        :func:`load_phone` (which takes the result in place of the path).

    Raises:
        InputError: Not a readable zip, or a file list longer than
            :data:`MAX_ZIP_DIRECTORY_BYTES`.
    """
    p = Path(path)
    try:
        zf = _open_zip(p)
    except (zipfile.BadZipFile, OSError) as e:
        raise InputError(f"{p.name}: not a readable zip archive ({e}); zip the recording's "
                         "files again") from None
    try:
        return ZipDirectory(p, zf)
    except BaseException:
        zf.close()
        raise


def zip_unpacked_bytes(path: str | Path) -> int | None:
    """Bytes :func:`load_phone` would unpack from a phone app's zip, from its directory
    alone (:attr:`ZipDirectory.unpacked_bytes` of :func:`read_zip_directory`).

    Args:
        path: The zip file.

    Returns:
        The total, or None when the file is not a readable zip (:func:`load_phone` then
        says why).
    """
    try:
        with read_zip_directory(path) as d:
            return d.unpacked_bytes
    except (zipfile.BadZipFile, OSError, ValueError, EOFError, InputError):
        return None


def _unzip(d: ZipDirectory, dest: Path) -> dict[str, list[tuple[str, Path]]]:
    """The CSV members of a zip, from its directory read once, copied to ``dest`` under
    generated names, grouped by their folder in the archive: folder -> [(member name,
    copy)]."""
    p, zf, infos = d.path, d._zf, d.members
    if len(infos) > MAX_ZIP_MEMBERS:
        raise InputError(f"{p.name}: {len(infos)} files in the zip, more than the "
                         f"{MAX_ZIP_MEMBERS} a phone recording has; zip one recording")
    bad = [i.filename for i in infos if not _safe_member(i.filename)]
    if bad:
        raise InputError(f"{p.name}: unsafe file name in the zip ({bad[0][:60]!r}: an "
                         "absolute path or '..'); zip the recording's files again")
    total = d.unpacked_bytes
    if total > MAX_ZIP_UNCOMPRESSED:
        raise InputError(f"{p.name}: the zip's files unpack to {total / 2**20:.0f} MB, "
                         f"more than {MAX_ZIP_UNCOMPRESSED // 2**20} MB; split the "
                         "recording")
    groups: dict[str, list[tuple[str, Path]]] = {}
    written = 0
    for k, info in enumerate(d.sensor_members):
        out = dest / f"m{k}{Path(info.filename).suffix.lower()}"
        try:
            with zf.open(info) as src, out.open("wb") as dst:
                while chunk := src.read(1 << 20):
                    written += len(chunk)
                    if written > MAX_ZIP_UNCOMPRESSED:  # sizes in the header may lie
                        raise InputError(f"{p.name}: the zip unpacks to more than "
                                         f"{MAX_ZIP_UNCOMPRESSED // 2**20} MB; split the "
                                         "recording")
                    dst.write(chunk)
        except InputError:
            raise
        except (zipfile.BadZipFile, RuntimeError, OSError, EOFError, NotImplementedError,
                zlib.error) as e:  # damaged data, a password, an unknown compression
            raise InputError(f"{p.name}: cannot unpack {info.filename!r} ({e}); zip the "
                             "files again (without a password)") from None
        folder = str(PurePosixPath(info.filename.replace("\\", "/")).parent)
        groups.setdefault(folder, []).append((info.filename, out))
    return groups


def _folder_files(p: Path) -> dict[str, list[tuple[str, Path]]]:
    groups: dict[str, list[tuple[str, Path]]] = {}
    for f in sorted(p.rglob("*")):
        if f.is_file() and f.suffix.lower() in (".csv", ".txt", ".tsv") and not any(
                part.startswith(".") for part in f.relative_to(p).parts):
            rel = f.relative_to(p).as_posix()
            groups.setdefault(str(PurePosixPath(rel).parent), []).append((rel, f))
    return groups


def _recording_files(name: str, groups: dict[str, list[tuple[str, Path]]]
                     ) -> dict[str, list[tuple[int, str, Path]]]:
    """Sensor files of the one recording in the archive/folder: kind -> [(rank, name,
    path)], best first. Metadata (``meta/device.csv`` in phyphox) may sit in a sub-folder."""
    per_folder: dict[str, dict[str, list[tuple[int, str, Path]]]] = {}
    for folder, files in groups.items():
        for member, path in files:
            kind = _KINDS.get(_stem_key(member))
            if kind is not None:
                per_folder.setdefault(folder, {}).setdefault(kind[0], []).append(
                    (kind[1], member, path))
    with_motion = [f for f, kinds in per_folder.items() if {"gyr", "acc", "lin"} & set(kinds)]
    if len(with_motion) > 1:
        raise InputError(f"{name}: holds several recordings (folders "
                         f"{', '.join(sorted(with_motion))}); upload one recording per zip")
    if not with_motion:
        found = sorted(m for files in groups.values() for m, _ in files)
        raise InputError(f"{name}: no accelerometer or gyroscope file (found "
                         f"{', '.join(found[:12]) or 'no CSV files'}); expected a phone app's "
                         "export with Accelerometer.csv and Gyroscope.csv (Sensor Logger, "
                         "phyphox)")
    kinds = per_folder[with_motion[0]]
    for folder, other in per_folder.items():  # metadata next to or below the recording
        if folder != with_motion[0] and "meta" in other and "meta" not in kinds:
            kinds["meta"] = other["meta"]
    for ranked in kinds.values():
        ranked.sort()
    return kinds


# ---------------------------------------------------------------------- reading


def _columns(header: list[str]) -> tuple[dict[str, int], dict[str, str]]:
    """Axis columns (x/y/z -> index) and their units from the header."""
    axes: dict[str, int] = {}
    units: dict[str, str] = {}
    for i, h in enumerate(header):
        name, unit = _io._split_header(h)
        key = re.sub(r"[^a-z0-9]", "", name.lower())
        if key and key[-1] in "xyz" and key[:-1] in _AXIS_PREFIXES and key[-1] not in axes:
            axes[key[-1]] = i
            if unit:
                units[key[-1]] = unit
    return axes, units


def _time_column(header: list[str]) -> tuple[int | None, str]:
    """Index and unit of the time column: ``time``/``timestamp`` (unit from the header or
    the step), else ``seconds_elapsed`` / ``Time (s)``."""
    keyed = [(i, re.sub(r"[^a-z0-9]", "", _io._split_header(h)[0].lower()),
              _io._split_header(h)[1]) for i, h in enumerate(header)]
    for want in (("time", "timestamp", "timens", "timestampns"),
                 ("secondselapsed", "elapsedtime", "t")):
        for i, key, unit in keyed:
            if key in want:
                if key == "secondselapsed":
                    return i, "s"
                return i, unit or ("ns" if key.endswith("ns") else "")
    return None, ""


def _some(header: list[str], n: int = 12) -> str:
    """The first columns of a header for a message (a hostile one may have a million)."""
    cut = [h[:40] for h in header[:n]]
    return ", ".join(cut) + (f" … ({len(header):,} columns)" if len(header) > n else "")


def _read_stream(name: str, path: Path, kind: str, time_unit: str | None,
                 warnings: list[str]) -> tuple[_Stream, str | None]:
    """One sensor file read into SI (kind ``acc``/``lin``/``grav``/``gyr``/``mag`` or
    ``quat``), and the time unit used (the next files reuse it: one clock)."""
    disp = Path(name)
    try:
        header, data, units_row, text = _io._read_csv(path)
    except InputError as e:  # the reader names its copy of a zip member: name the member
        raise InputError(str(e).replace(path.name, name)) from None
    except csv.Error as e:  # a cell longer than the csv module's field limit (128 kB)
        raise InputError(f"{name}: not a sensor CSV ({e}); export the recording again"
                         ) from None
    if len(header) > MAX_COLUMNS:
        raise InputError(f"{name}: {len(header):,} columns, more than the {MAX_COLUMNS} a "
                         f"phone sensor file has (first: {_some(header)}); export the "
                         "recording again")
    t_idx, t_unit = _time_column(header)
    if t_idx is None:
        raise InputError(f"{name}: no time column (time, seconds_elapsed or Time (s)); "
                         f"found {_some(header)}")
    meta: dict[str, Any] = {}
    w: list[str] = []
    try:
        time = _io._csv_time(disp, data, t_idx, t_unit, None,
                             time_unit if not t_unit else None, None, meta, w)
    except InputError as e:
        raise InputError(str(e).replace(disp.name, name)) from None
    if meta.get("time_from") == "detected":
        warnings.extend(f"{name}: {x}" for x in w)
    unit_used = meta.get("time_unit")
    if kind == "quat":
        q_idx, named = _io._quat_columns(header, "")
        if not q_idx or not named:
            raise InputError(f"{name}: no qw, qx, qy, qz columns; found {_some(header)}")
        _io._text_error(disp, text, {t_idx, *q_idx})
        vals = data[:, q_idx]
        return _Stream(name, time, vals), unit_used
    axes, col_units = _columns(header)
    if set(axes) != {"x", "y", "z"}:
        raise InputError(f"{name}: no x, y, z columns; found {_some(header)}")
    idx = [axes[a] for a in "xyz"]
    _io._text_error(disp, text, {t_idx, *idx})
    raw = data[:, idx]
    unit = next((col_units[a] for a in "xyz" if a in col_units), "")
    if not unit and units_row:
        unit = _io._unbracket(units_row[idx[0]])
    if not unit:
        unit = _DEFAULT_UNIT[kind]
        if kind == "acc":  # iOS raw (uncalibrated) acceleration is in g
            found = _io._detect("acc", raw)
            if found is not None:
                unit = found[0]
    try:
        factor = _io._unit(_TABLES[kind], unit, _WHAT[kind])
    except InputError as e:
        raise InputError(f"{name}: {e}") from None
    return _Stream(name, time, raw * factor, unit), unit_used


def _interp(s: _Stream, t: FloatArray) -> FloatArray:
    out = np.empty((len(t), s.values.shape[1]))
    for c in range(s.values.shape[1]):
        ok = np.isfinite(s.values[:, c])
        out[:, c] = np.interp(t, s.time[ok], s.values[ok, c]) if ok.sum() >= 2 else np.nan
    return out


def _sorted(s: _Stream) -> _Stream:
    """Samples in time order, exact repeats dropped (loggers write an event twice)."""
    order = np.argsort(s.time, kind="stable")
    t, v = s.time[order], s.values[order]
    keep = np.r_[True, np.diff(t) > 0]
    return _Stream(s.name, t[keep], v[keep], s.unit)


def _metadata(path: Path) -> dict[str, str]:
    """Key/value pairs of a metadata CSV: one header row and one value row (Sensor
    Logger), or ``property,value`` rows (phyphox ``meta/device.csv``). Only its first
    64 kB are read (a few lines in every app; a hostile one may be 256 MB), and a file
    the csv module cannot split tells nothing."""
    try:
        with path.open("rb") as fh:
            head = fh.read(_MAX_METADATA_BYTES).decode("utf-8-sig", errors="replace")
        rows = list(csv.reader(head.splitlines()))
    except (OSError, csv.Error):
        return {}
    rows = [r for r in rows if r]
    if len(rows) >= 2 and len(rows[0]) > 2 and len(rows[0]) == len(rows[1]):
        return {k.strip().lower(): v.strip() for k, v in zip(rows[0], rows[1], strict=True)}
    return {r[0].strip().lower(): r[1].strip() for r in rows if len(r) >= 2}


def _sign_from_orientation(acc: FloatArray, q: FloatArray) -> tuple[float, float, float] | None:
    """(sign, agreeing angle, other sign's angle) when the phone's orientation tells the
    acceleration's sign, else ``None``.

    Phone orientations are given in a Z-up earth frame (Android's ENU rotation vector,
    Core Motion's Z-vertical frames): gravity's reaction, +Z up, seen from the phone must
    lie along the specific force. Both quaternion directions are tried."""
    an = np.linalg.norm(acc, axis=1)
    ok = np.all(np.isfinite(q), axis=1) & np.isfinite(an) & (an > 0)
    quiet = ok & (np.abs(an - G) < 0.1 * G)
    use = quiet if quiet.sum() >= 20 else ok
    if use.sum() < 5:
        return None
    qq = q[use] / np.linalg.norm(q[use], axis=1, keepdims=True)
    a_dir = acc[use] / an[use, None]
    best: dict[float, float] = {}
    for qs in (qq, quat_conj(qq)):
        up_s = quat_rotate(quat_conj(qs), np.array([0.0, 0.0, 1.0]))
        for sign in (1.0, -1.0):
            cos = np.clip(np.sum(up_s * sign * a_dir, axis=1), -1.0, 1.0)
            ang = float(np.median(np.degrees(np.arccos(cos))))
            best[sign] = min(best.get(sign, 180.0), ang)
    s = min(best, key=lambda k: best[k])
    if best[s] > 20.0 or best[-s] < 2.0 * best[s] + 1.0:
        return None
    return s, best[s], best[-s]


# ------------------------------------------------------------------------ merge


def load_phone(path: str | Path | ZipDirectory, *, platform: str | None = None
               ) -> ImuRecording:
    """Read a phone app's one-file-per-sensor export (a ``.zip`` or a folder) as one
    recording; see the module docstring for the files, the merge and the iOS sign.

    Args:
        path: the zip archive or the folder, or a zip's directory already read
            (:func:`read_zip_directory`: the zip is not opened again; left open).
        platform: ``"ios"`` (Core Motion's sign: face up reads z = −1 g) or ``"android"``
            (face up reads +9.81 m/s²): the convention of the acceleration files when the
            data and metadata cannot tell (declared: it overrides both).

    Returns:
        One recording in SI units on the gyroscope's time stamps (time first axis).

    Raises:
        InputError: no accelerometer or gyroscope file, several recordings in one
            archive, an unsafe or oversized zip, unreadable files, no common time span.
    """
    given, p = (path, path.path) if isinstance(path, ZipDirectory) else (None, Path(path))
    if platform is not None and platform.strip().lower() not in ("ios", "android"):
        raise InputError(f"unknown platform {platform!r}; use 'ios' or 'android'")
    if given is None and not p.exists():
        raise InputError(f"cannot read {p}: no such file or folder")
    tmp = Path(tempfile.mkdtemp(prefix="gaitrig-phone-"))
    try:
        if given is not None:
            groups = _unzip(given, tmp)
        elif p.is_dir():
            groups = _folder_files(p)
        else:
            with read_zip_directory(p) as d:
                groups = _unzip(d, tmp)
        return _merge(p, _recording_files(p.name, groups), platform)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _merge(p: Path, kinds: dict[str, list[tuple[int, str, Path]]],
           platform: str | None) -> ImuRecording:
    warnings: list[str] = []
    if "gyr" not in kinds:
        raise InputError(f"{p.name}: no gyroscope file (Gyroscope.csv) beside "
                         f"{', '.join(sorted(m for f in kinds.values() for _, m, _ in f))}; "
                         "record with the gyroscope on and export again")
    unit: str | None = None
    gyr, unit = _read_stream(kinds["gyr"][0][1], kinds["gyr"][0][2], "gyr", unit, warnings)
    read: dict[str, _Stream] = {"gyr": _sorted(gyr)}
    used = [kinds["gyr"][0][1]]
    grav = None
    if "grav" in kinds:
        g_s, unit = _read_stream(kinds["grav"][0][1], kinds["grav"][0][2], "grav", unit,
                                 warnings)
        grav = _sorted(g_s)
    acc = None
    why: list[str] = []
    for kind in ("acc", "lin"):
        for _, member, path in kinds.get(kind, []):
            s, unit = _read_stream(member, path, kind, unit, warnings)
            s = _sorted(s)
            med = float(np.nanmedian(np.linalg.norm(s.values, axis=1)))
            if med > 0.4 * G:  # holds gravity
                acc = s
            elif grav is not None:  # user acceleration + gravity = specific force
                acc = _Stream(s.name, s.time, s.values + _interp(grav, s.time), s.unit)
                used.append(grav.name)
                warnings.append(f"acceleration = {member} + {grav.name} (the first holds no "
                                "gravity)")
            else:
                why.append(f"{member} holds no gravity (median {med:.2g} m/s²)")
                continue
            used.append(member)
            break
        if acc is not None:
            break
    if acc is None:
        names = ", ".join(m for f in kinds.values() for _, m, _ in f)
        raise InputError(
            f"{p.name}: no accelerometer file with gravity ("
            + ("; ".join(why) + ", and no Gravity.csv to add" if why else f"found {names}")
            + "); export TotalAcceleration.csv (Sensor Logger on Android) or Accelerometer.csv"
            " with Gravity.csv")
    read["acc"] = acc
    if "mag" in kinds:
        m, unit = _read_stream(kinds["mag"][0][1], kinds["mag"][0][2], "mag", unit, warnings)
        read["mag"] = _sorted(m)
        used.append(kinds["mag"][0][1])
    quat = None
    if "quat" in kinds:
        try:
            q, unit = _read_stream(kinds["quat"][0][1], kinds["quat"][0][2], "quat", unit,
                                   warnings)
        except InputError as e:  # the reference is optional: the motion still loads
            warnings.append(f"orientation file ignored ({e})")
        else:
            quat = _sorted(q)
            used.append(kinds["quat"][0][1])
    # the common span: every stream's; a magnetometer that cuts much is dropped instead
    t0 = max(read["gyr"].time[0], read["acc"].time[0])
    t1 = min(read["gyr"].time[-1], read["acc"].time[-1])
    if "mag" in read:
        m = read["mag"]
        cut = max(0.0, m.time[0] - t0) + max(0.0, t1 - m.time[-1])
        if cut > _MAX_MAG_CUT_S:
            warnings.append(f"magnetometer ({m.name}) dropped: it covers {cut:.1f} s less than "
                            "the accelerometer and gyroscope")
            used.remove(m.name)
            del read["mag"]
        else:
            t0, t1 = max(t0, m.time[0]), min(t1, m.time[-1])
    if t1 <= t0:
        raise InputError(f"{p.name}: the accelerometer ({read['acc'].name}) and gyroscope "
                         f"({read['gyr'].name}) files cover no common time span")
    g = read["gyr"]
    inside = (g.time >= t0) & (g.time <= t1)
    t = g.time[inside]
    if len(t) < 2:
        raise InputError(f"{p.name}: fewer than two gyroscope samples in the span the "
                         "accelerometer covers")
    gyr_v = g.values[inside]
    acc_v = _interp(read["acc"], t)
    mag_v = _interp(read["mag"], t) if "mag" in read else None
    rates = {k: _io._nominal_rate(s.time) for k, s in read.items() if len(s.time) > 2}
    merge = ("on the gyroscope's time stamps; "
             + ", ".join(f"{_WHAT[k]} {r:.4g} Hz" for k, r in rates.items())
             + " (the others interpolated linearly)")
    if rates and max(rates.values()) > 1.05 * min(rates.values()):
        warnings.append(f"streams at different rates merged {merge}")
    q_ref = None
    if quat is not None:
        from engine.imu.fusion import interp_quat

        ok = np.all(np.isfinite(quat.values), axis=1)
        if ok.sum() >= 2:
            qv = quat.values[ok] / np.linalg.norm(quat.values[ok], axis=1, keepdims=True)
            q_ref = interp_quat(quat.time[ok], _continuous(qv), t)
    meta_file = _metadata(kinds["meta"][0][2]) if "meta" in kinds else {}
    sign, sign_from = _acc_sign(p.name, acc_v, q_ref, meta_file, platform, warnings)
    acc_v = sign * acc_v
    meta: dict[str, Any] = {"format": "phone-files", "source": str(p), "files": used,
                            "gyr_unit": g.unit, "acc_unit": read["acc"].unit,
                            "mag_unit": read["mag"].unit if "mag" in read else "",
                            "acc_sign": "ios" if sign < 0 else "android",
                            "acc_sign_from": sign_from, "time_base": g.name, "merge": merge}
    if meta_file.get("platform"):
        meta["platform"] = meta_file["platform"]
    if meta_file.get("device name") or meta_file.get("devicemodel"):
        meta["device"] = meta_file.get("device name") or meta_file.get("devicemodel")
    rec = _io._finalise(t - t[0], gyr_v, acc_v, mag_v, p.stem, meta, warnings)
    rec.meta["start_time_s"] = float(t[0])
    if q_ref is not None:
        rec.quat_ref = _io._reference_quaternions(p.name, q_ref, True, gyr_v, acc_v, None,
                                                  "ENU", rec.meta, rec.warnings)
    return rec


def _continuous(q: FloatArray) -> FloatArray:
    """Quaternions flipped into one hemisphere step to step (q and −q are one rotation),
    so interpolation between neighbours takes the short way."""
    flip = np.r_[1.0, np.where(np.sum(q[1:] * q[:-1], axis=1) < 0, -1.0, 1.0)]
    return q * np.cumprod(flip)[:, None]


def _acc_sign(name: str, acc: FloatArray, q: FloatArray | None, meta: dict[str, str],
              platform: str | None, warnings: list[str]) -> tuple[float, str]:
    """The factor that turns the files' acceleration into specific force, and why."""
    if platform is not None:
        return (-1.0 if platform.strip().lower() == "ios" else 1.0), "declared"
    told = _sign_from_orientation(acc, q) if q is not None else None
    plat = meta.get("platform", "").strip().lower()
    standard = meta.get("standardisation", meta.get("standardization", "")).strip().lower()
    from_meta = None
    if plat in ("ios", "android"):
        from_meta = -1.0 if plat == "ios" and standard not in ("true", "1", "yes") else 1.0
    if told is not None:
        s, good, bad = told
        if from_meta is not None and from_meta != s:
            warnings.append(f"the metadata says {plat} (standardisation {standard or 'unset'}),"
                            " but gravity against the phone's orientation says the "
                            f"acceleration follows {'iOS' if s < 0 else 'Android'}'s sign "
                            f"({good:.0f}° against {bad:.0f}°); the data is followed")
        elif s < 0:
            warnings.append("acceleration in iOS Core Motion's sign (gravity against the "
                            f"phone's orientation: {good:.0f}° against {bad:.0f}°); negated "
                            "to specific force")
        return s, "orientation"
    if from_meta is not None:
        if from_meta < 0:
            warnings.append("acceleration in iOS Core Motion's sign (Metadata: platform ios, "
                            "not standardised); negated to specific force")
        return from_meta, "metadata"
    warnings.append("acceleration sign assumed Android's (face up reads +9.81 m/s²): no "
                    "orientation file or platform in the export to tell; declare platform "
                    "'ios' if the files hold Core Motion's raw sign")
    return 1.0, "assumed"
