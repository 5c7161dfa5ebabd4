"""Server-side storage of recordings: layout, reading parts, disk usage, deletion, exports.

Layout under the server's data folder (see ``docs/storage.md``)::

    recordings/<rec_id>/<node_id>/manifest.json   # the node's manifest (sizes, SHA-256)
    recordings/<rec_id>/<node_id>/meta.json       # part parameters (clock model, times)
    recordings/<rec_id>/<node_id>/frames.bin      # the node's records, byte-identical
    recordings/<rec_id>/<node_id>/index.json      # [t_local, offset, kind] per record
    recordings/<rec_id>/<node_id>/.incoming/      # only while a transfer is unfinished
    references/<rec_id>/<n>.<c3d|trc|csv>         # imported reference recordings
    deletions.json                                # recordings being deleted (tombstones)

A part folder is complete exactly when ``manifest.json`` exists and ``.incoming`` does
not (:meth:`app.transfer.TransferSink.is_complete`). Reading a part converts node-local
times to server time with the clock model the part carries, so parts of one recording
share one time axis.
"""

from __future__ import annotations

import contextlib
import functools
import io
import json
import os
import shutil
import stat
import tempfile
import threading
import time
import zipfile
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.nodes.protocol import ProtocolError, decode_skeletons
from app.nodes.store import NodeStore
from app.server.clock import ClockEstimate
from app.transfer import TransferSink
from engine.errors import GaitrigError, InputError, InsufficientDataError
from engine.integration import SensorStream, integrate_skeletons, resample_stream
from engine.io.c3d import read_c3d, skeleton_to_markers, write_skeleton_c3d
from engine.io.csv import read_skeleton_csv, write_skeleton_csv
from engine.io.markers import MarkerEvent, MarkerTrajectories
from engine.io.trc import read_trc, write_trc
from engine.skeleton import JOINT_SETS, SkeletonSeries, TrackingState
from engine.wording import named

_SAFE = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_.-")
MAX_EXPORT_FRAMES = 3000  # depth frames per PNG/NPZ export (≈ 100 s at 30 Hz)


def check_id(value: str, what: str = "id") -> str:
    """A recording or node id that is safe as a folder name (no path traversal).

    Raises:
        InputError: empty, too long, or with characters other than A-Z a-z 0-9 _ . -
    """
    if not value or len(value) > 64 or set(value) - _SAFE or value in (".", ".."):
        raise InputError(f"{what} {value!r} must be 1-64 characters of A-Z a-z 0-9 _ . -")
    return value


_TOMBSTONE_LOCK = threading.Lock()  # deletions run in worker threads


@dataclass(frozen=True)
class StorageLayout:
    """Paths of the server's data folder."""

    data_dir: Path

    @property
    def recordings(self) -> Path:
        return self.data_dir / "recordings"

    @property
    def references(self) -> Path:
        return self.data_dir / "references"

    def recording_dir(self, rec_id: str) -> Path:
        return self.recordings / check_id(rec_id, "recording id")

    def part_dir(self, rec_id: str, node_id: str) -> Path:
        return self.recording_dir(rec_id) / check_id(node_id, "node id")

    def reference_dir(self, rec_id: str) -> Path:
        return self.references / check_id(rec_id, "recording id")

    def complete_parts(self, rec_id: str) -> list[str]:
        """Node ids whose part of ``rec_id`` is completely and verifiably on the server."""
        d = self.recording_dir(rec_id)
        if not d.is_dir():
            return []
        return sorted(p.name for p in d.iterdir() if p.is_dir() and TransferSink.is_complete(p))

    def recording_bytes(self, rec_id: str) -> int:
        """Bytes used by a recording (parts, finished transfers and references), as the
        data folder's :class:`UsageIndex` knows them (measured again when they changed)."""
        return usage_index(self.data_dir).recording_bytes(rec_id)

    def measure_bytes(self, rec_id: str) -> int:
        """Bytes used by a recording now, read from every file (parts, unfinished
        transfers and references)."""
        return dir_bytes(self.recording_dir(rec_id)) + dir_bytes(self.reference_dir(rec_id))

    def delete_recording(self, rec_id: str) -> None:
        """Remove every file of a recording on the server (parts and references)."""
        for d in (self.recording_dir(rec_id), self.reference_dir(rec_id)):
            if d.exists():
                shutil.rmtree(d)
        usage_index(self.data_dir).changed(rec_id)

    @property
    def tombstone_file(self) -> Path:
        return self.data_dir / "deletions.json"

    def tombstones(self) -> dict[str, list[str]]:
        """Recordings whose deletion started: recording id → nodes holding a part.

        Written before the database rows are deleted and cleared once the files are gone,
        so a server that dies in between finishes (or, if the rows survived, forgets)
        the deletion when it starts again.
        """
        try:
            raw = json.loads(self.tombstone_file.read_text())
        except (OSError, ValueError):
            return {}
        if not isinstance(raw, dict):
            return {}
        return {str(k): [str(n) for n in v] for k, v in raw.items() if isinstance(v, list)}

    def add_tombstones(self, entries: dict[str, list[str]]) -> None:
        """Add tombstones (two deletions at once must not lose each other's)."""
        with _TOMBSTONE_LOCK:
            self.set_tombstones({**self.tombstones(), **entries})

    def drop_tombstones(self, rec_ids: Iterable[str]) -> None:
        """Remove the tombstones of ``rec_ids``."""
        gone = set(rec_ids)
        with _TOMBSTONE_LOCK:
            self.set_tombstones({k: v for k, v in self.tombstones().items() if k not in gone})

    def set_tombstones(self, entries: dict[str, list[str]]) -> None:
        """Replace the tombstones (atomically and durably: written, synced, renamed)."""
        self.data_dir.mkdir(parents=True, exist_ok=True)
        tmp = self.tombstone_file.with_suffix(".tmp")
        with open(tmp, "w") as fh:
            json.dump(entries, fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, self.tombstone_file)

    def disk(self) -> dict[str, int]:
        """Total / used / free bytes of the file system holding the data folder."""
        self.data_dir.mkdir(parents=True, exist_ok=True)
        u = shutil.disk_usage(self.data_dir)
        return {"total": u.total, "used": u.used, "free": u.free}


Stamp = tuple[int, int]  # mtime_ns of a recording's folder and of its references' folder


def _mtime_ns(path: Path) -> int:
    try:
        return os.stat(path).st_mtime_ns
    except OSError:
        return 0


def _folders(root: Path) -> dict[str, int]:
    """The folders in ``root`` with their mtime_ns (one listing, no walk)."""
    out: dict[str, int] = {}
    try:
        with os.scandir(root) as it:
            for e in it:
                if e.is_dir(follow_symlinks=False):
                    with contextlib.suppress(OSError):
                        out[e.name] = e.stat(follow_symlinks=False).st_mtime_ns
    except OSError:
        pass
    return out


class UsageIndex:
    """The bytes each recording uses on the server, kept between requests instead of read
    from every file each time (``GET /api/storage`` read every recording folder: seconds
    at clinic size).

    A recording's bytes are measured when first asked for (or by :meth:`rescan`) and kept
    with the modification times of its folder and of its references' folder, which every
    file put in or taken out at their top changes (a reference uploaded or deleted, the
    report's reference, ``sensors.json``, the whole recording deleted). What changes
    deeper is reported: a part whose transfer ended (:mod:`app.server.transfer`), an
    analysis written (:mod:`app.server.analysis`), a deletion (:meth:`StorageLayout.
    delete_recording`), a settled recording found damaged (:mod:`app.server.datasync`)
    call :meth:`changed`. A transfer under way is counted when it ends. A full
    :meth:`rescan` runs in the background at start-up and on request
    (``GET /api/storage?rescan=true``), for what changed by hand.

    Args:
        data_dir: the server's data folder.
    """

    def __init__(self, data_dir: Path) -> None:
        self.layout = StorageLayout(Path(data_dir))
        self._known: dict[str, tuple[Stamp, int]] = {}
        self._lock = threading.Lock()
        self._changed_in_scan: set[str] | None = None  # reported while a rescan runs
        self._scan_lock = threading.Lock()
        #: grows whenever a kept size may have changed (measured, reported changed,
        #: rescanned): an answer built from the index is still right while it and the
        #: folders' stamps are the same (``GET /api/storage`` keeps its answer so)
        self.version = 0
        #: when the last full rescan ended (time.time()), None before the first
        self.scanned_at: float | None = None

    def _stamp(self, rec_id: str) -> Stamp:
        return (_mtime_ns(self.layout.recording_dir(rec_id)),
                _mtime_ns(self.layout.reference_dir(rec_id)))

    def _measure(self, rec_id: str, stamp: Stamp) -> int:
        # the stamp was read before the files: a change while they are read is seen by
        # the next look (its stamp differs)
        n = self.layout.measure_bytes(rec_id)
        with self._lock:
            self._known[rec_id] = (stamp, n)
            self.version += 1
        return n

    def recording_bytes(self, rec_id: str) -> int:
        """Bytes of one recording (measured again only when its stamp changed)."""
        stamp = self._stamp(rec_id)
        if stamp == (0, 0):
            return 0
        hit = self._known.get(rec_id)
        if hit is not None and hit[0] == stamp:
            return hit[1]
        return self._measure(rec_id, stamp)

    def stamps(self) -> tuple[dict[str, int], dict[str, int]]:
        """The recordings' and the references' folders with their mtime_ns (two folder
        listings): what :meth:`many` compares the kept sizes with."""
        return _folders(self.layout.recordings), _folders(self.layout.references)

    def many(self, rec_ids: Iterable[str],
             stamps: tuple[dict[str, int], dict[str, int]] | None = None) -> dict[str, int]:
        """Bytes of each of ``rec_ids``: two folder listings (or ``stamps``, from
        :meth:`stamps`), then only the recordings whose stamp changed are read."""
        recs, refs = stamps if stamps is not None else self.stamps()
        out: dict[str, int] = {}
        for rec_id in rec_ids:
            stamp = (recs.get(rec_id, 0), refs.get(rec_id, 0))
            if stamp == (0, 0):
                out[rec_id] = 0
                continue
            hit = self._known.get(rec_id)
            out[rec_id] = hit[1] if hit is not None and hit[0] == stamp else \
                self._measure(rec_id, stamp)
        return out

    def changed(self, rec_id: str) -> None:
        """Something below a recording's folder changed: measure it again when asked."""
        with self._lock:
            self._known.pop(rec_id, None)
            self.version += 1
            if self._changed_in_scan is not None:
                self._changed_in_scan.add(rec_id)

    def rescan(self) -> int:
        """Measure every recording on the server again (blocking: run it in a worker
        thread; one at a time). Returns the recordings measured."""
        with self._scan_lock:
            return self._rescan()

    def _rescan(self) -> int:
        with self._lock:
            self._changed_in_scan = set()
        recs, refs = _folders(self.layout.recordings), _folders(self.layout.references)
        fresh: dict[str, tuple[Stamp, int]] = {}
        for rec_id in sorted(set(recs) | set(refs)):
            try:
                check_id(rec_id)
            except InputError:
                continue  # not a recording's folder
            stamp = (recs.get(rec_id, 0), refs.get(rec_id, 0))
            fresh[rec_id] = (stamp, self.layout.measure_bytes(rec_id))
            time.sleep(RESCAN_PAUSE_S)  # the event loop's requests come first
        with self._lock:
            for rec_id in self._changed_in_scan or ():  # maybe measured before it changed
                fresh.pop(rec_id, None)
            self._known, self._changed_in_scan = fresh, None
            self.version += 1
        self.scanned_at = time.time()
        return len(fresh)


#: Pause of a background rescan after each recording: a thread reading files without a
#: break takes the interpreter from the event loop for milliseconds at every switch,
#: which made the server's answers ten times slower while it ran.
RESCAN_PAUSE_S = 0.002

_INDEXES: dict[Path, UsageIndex] = {}
_INDEXES_LOCK = threading.Lock()


def usage_index(data_dir: Path) -> UsageIndex:
    """The :class:`UsageIndex` of a data folder (one per folder and process)."""
    key = Path(data_dir).absolute()
    with _INDEXES_LOCK:
        idx = _INDEXES.get(key)
        if idx is None:
            idx = _INDEXES[key] = UsageIndex(key)
        return idx


def note_changed(path: Path) -> None:
    """A file at ``path``, below ``<data_dir>/recordings/<rec_id>/`` or
    ``<data_dir>/references/<rec_id>/``, was written or removed: the data folder's
    :class:`UsageIndex` (if one is in use) measures that recording again when asked."""
    p = Path(path).absolute()
    for data_dir, idx in list(_INDEXES.items()):
        for top in ("recordings", "references"):
            try:
                rel = p.relative_to(data_dir / top)
            except ValueError:
                continue
            if rel.parts:
                idx.changed(rel.parts[0])
            return


def dir_bytes(path: Path) -> int:
    """Bytes of every file below ``path`` (0 if it does not exist).

    A file or folder that vanishes while it is counted counts 0: a transfer renames its
    temporary files into place (and a deletion removes them) while the storage pages are
    read — ``rglob`` then ``stat`` of a renamed file answered a poll with a 500.
    """
    total = 0
    for base, _dirs, files in os.walk(path):  # os.walk skips a folder gone meanwhile
        for name in files:
            with contextlib.suppress(OSError):
                st = os.stat(os.path.join(base, name), follow_symlinks=False)
                total += st.st_size if stat.S_ISREG(st.st_mode) else 0  # no link followed
    return total


# --------------------------------------------------------------------------- reading parts


def _records(part_dir: Path) -> Iterator[tuple[dict[str, Any], bytes]]:
    # The node store's reader: same record format, stops at the first damaged record.
    it = NodeStore(part_dir.parent).read(part_dir.name)
    while True:
        try:
            yield next(it)
        except (StopIteration, ProtocolError):
            return


def part_meta(part_dir: Path) -> dict[str, Any]:
    """The part's ``meta.json``.

    Raises:
        InputError: the part is not (completely) on the server.
    """
    if not TransferSink.is_complete(part_dir):
        raise InputError(f"part {part_dir.name} of {part_dir.parent.name} is not completely on "
                         "the server yet; transfer it first")
    try:
        meta: dict[str, Any] = json.loads((part_dir / "meta.json").read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"part {part_dir.name}: unreadable meta.json ({exc})") from exc
    return meta


def _clock(meta: dict[str, Any]) -> ClockEstimate | None:
    c = meta.get("clock_start") or meta.get("clock_stop")
    if not c or "offset_s" not in c:
        return None
    return ClockEstimate(float(c["offset_s"]), float(c.get("drift", 0.0)),
                         float(c.get("t_ref", 0.0)), float(c.get("uncertainty_s", 0.0)), 0, 0.0)


def read_part_skeleton(part_dir: Path) -> SkeletonSeries:
    """One node's skeleton of a recording, in the sensor frame, on the server clock.

    Several bodies in view: each frame keeps the body with the most TRACKED joints (a gait
    recording has one subject; bystanders are rarely tracked as well).

    Raises:
        InputError: the part is not on the server.
        InsufficientDataError: it holds no skeleton frame.
    """
    meta = part_meta(part_dir)
    clock = _clock(meta)
    times: list[float] = []
    pos: list[NDArray[np.float32]] = []
    st: list[NDArray[np.uint8]] = []
    for header, payload in _records(part_dir):
        if header.get("kind") != "skeleton":
            continue
        p, s = decode_skeletons(header, payload)
        t = float(header["t"])
        t = clock.to_server(t) if clock is not None else t
        if times and t <= times[-1]:
            continue  # a replayed ring-buffer frame: keep time strictly increasing
        J = int(header["joints"])
        if p.shape[0] == 0:
            pos.append(np.full((J, 3), np.nan, np.float32))
            st.append(np.zeros(J, np.uint8))
        else:
            best = int(np.argmax((s == TrackingState.TRACKED).sum(axis=1)))
            pos.append(p[best])
            st.append(s[best])
        times.append(t)
    if not times:
        raise InsufficientDataError(f"part {part_dir.name} of {part_dir.parent.name} has no "
                                    "skeleton frame")
    J = len(pos[0])
    js = next((j for j in JOINT_SETS.values() if len(j.joints) == J), None)
    if js is None:
        raise InputError(f"part {part_dir.name}: skeletons with {J} joints match no known "
                         "joint set")
    positions = np.asarray(pos, dtype=float)
    states = np.asarray(st, dtype=np.uint8)
    positions[states == TrackingState.NOT_TRACKED] = np.nan
    return SkeletonSeries(np.asarray(times), positions, states, js,
                          {"sensor": part_dir.name, "recording": part_dir.parent.name,
                           "frame": "sensor", "clock": "server"})


def depth_frames(part_dir: Path, t0: float | None, t1: float | None,
                 limit: int = MAX_EXPORT_FRAMES) -> list[tuple[float, NDArray[np.uint16]]]:
    """Recorded depth images (server time, 16-bit millimetres) between ``t0`` and ``t1``.

    Raises:
        InputError: not on the server, no depth stream recorded, or too many frames.
    """
    meta = part_meta(part_dir)
    clock = _clock(meta)
    out: list[tuple[float, NDArray[np.uint16]]] = []
    for header, payload in _records(part_dir):
        if header.get("kind") != "image" or header.get("stream") != "depth":
            continue
        t = float(header["t"])
        t = clock.to_server(t) if clock is not None else t
        if (t0 is not None and t < t0) or (t1 is not None and t > t1):
            continue
        if len(out) >= limit:
            raise InputError(f"more than {limit} depth frames in the range; choose a shorter "
                             "time range")
        import cv2  # here: the server's start needs no image codec

        img = cv2.imdecode(np.frombuffer(payload, np.uint8), cv2.IMREAD_UNCHANGED)
        if img is None or img.dtype != np.uint16:
            continue  # a preview JPEG is not depth data
        out.append((t, np.asarray(img, dtype=np.uint16)))
    if not out:
        raise InputError(f"no depth frames of {part_dir.name} in that range (record with the "
                         "depth stream enabled to export depth)")
    return out


def depth_zip(frames: list[tuple[float, NDArray[np.uint16]]]) -> bytes:
    """16-bit PNGs (millimetres) in a zip, named by frame number and server time."""
    import cv2

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as z:
        for k, (t, img) in enumerate(frames):
            ok, png = cv2.imencode(".png", img)
            if ok:
                z.writestr(f"depth_{k:05d}_{t:.4f}.png", png.tobytes())
    return buf.getvalue()


def depth_npz(frames: list[tuple[float, NDArray[np.uint16]]]) -> bytes:
    """``times`` (s, server clock) and ``depth_mm`` ``(N, H, W)`` uint16 in one NPZ."""
    buf = io.BytesIO()
    np.savez_compressed(buf, times=np.array([t for t, _ in frames]),
                        depth_mm=np.stack([d for _, d in frames]))
    return buf.getvalue()


# --------------------------------------------------------------------------- exports


def uniform_series(series: SkeletonSeries, rate_hz: float | None = None) -> SkeletonSeries:
    """A sensor's skeleton on a uniform time grid (C3D and TRC need one rate).

    TRACKED samples are interpolated across gaps ≤ 0.2 s (those become INFERRED); longer
    gaps stay NaN / NOT_TRACKED.
    """
    if len(series) < 2:
        raise InsufficientDataError("need at least two skeleton frames to export")
    rate = rate_hz or float(round(1.0 / float(np.median(np.diff(series.times)))))
    grid = series.times[0] + np.arange(int((series.times[-1] - series.times[0]) * rate) + 1) / rate
    P, bridged, _ = resample_stream(SensorStream(series, np.eye(4), sensor_id="s"), grid)
    states = np.where(np.isfinite(P[..., 0]), TrackingState.TRACKED, TrackingState.NOT_TRACKED)
    states[bridged & np.isfinite(P[..., 0])] = TrackingState.INFERRED
    return SkeletonSeries(grid, P, states.astype(np.uint8), series.joint_set, dict(series.meta))


def live_poses(layout: StorageLayout, registry: Any) -> dict[str, Any]:
    """Sensor poses known now: the active calibration's, else those the nodes report."""
    from app.server.calibration import active_poses

    live: dict[str, Any] = dict(active_poses(layout.data_dir))
    for node_id, s in registry.nodes.items():
        T = s.sensor.T_world_sensor
        if T is not None and node_id not in live:
            live[node_id] = {"T_world_sensor": T, "source": "node"}
    return live


def recording_poses(layout: StorageLayout, registry: Any, rec_id: str
                    ) -> dict[str, NDArray[np.float64] | None]:
    """The recording's own sensor poses (``T_world_sensor``) for every part on the server.

    The first use snapshots the poses known now (the active calibration, else the poses
    the nodes report) into ``sensors.json`` in the recording folder, as the analysis does
    (:func:`app.server.analysis.sensor_poses`); :class:`app.server.datasync.DataSync`
    does so as soon as a recording is complete. Later uses read that snapshot, so a
    recalibration never changes an old recording's exports or analyses silently. A
    sensor without a pose maps to None.
    """
    from app.server import analysis as an

    saved = an.sensor_poses(layout.recording_dir(rec_id), live_poses(layout, registry))
    return {n: (np.asarray(saved[n]["T_world_sensor"], dtype=float) if n in saved else None)
            for n in layout.complete_parts(rec_id)}


def sensor_streams(layout: StorageLayout, rec_id: str,
                   poses: dict[str, NDArray[np.float64] | None]) -> list[SensorStream]:
    """Every complete part of a recording with its sensor's pose (for fusion), its
    back-facing frames un-mirrored.

    Raises:
        InputError: no part on the server, or a part's sensor has no calibrated pose.
    """
    nodes = layout.complete_parts(rec_id)
    if not nodes:
        raise InputError(f"no part of recording {rec_id} is on the server yet")
    missing = [n for n in nodes if poses.get(n) is None]
    if missing:
        raise InputError(f"{named('sensor', missing, 'has', 'have')} no calibrated pose; calibrate "
                         "the rig (Calibrate page) or export the sensors one by one")
    from app.server.analysis import unmirror_in_sensor_frame

    out = []
    for n in nodes:
        pose = poses[n]
        assert pose is not None
        T = np.asarray(pose, dtype=float)
        # as the reports do: a sensor that sees the subject's back labels the left leg
        # right (read_part_skeleton's times are already on the server clock)
        series, _ = unmirror_in_sensor_frame(read_part_skeleton(layout.part_dir(rec_id, n)), T)
        out.append(SensorStream(series, T, sensor_id=n))
    return out


def fused_skeleton(streams: list[SensorStream]) -> tuple[SkeletonSeries, list[MarkerEvent]]:
    """Fused world-frame skeleton (30 Hz) and its gait events when a walk is detected."""
    # here, not at the top: gait analysis pulls scipy.signal/stats, which the server's
    # start (this module is on its import path) must not pay
    from engine.gait import GaitAnalysis

    fused, _report = integrate_skeletons(streams)
    try:
        events = GaitAnalysis().fit(fused).marker_events()
    except GaitrigError:
        events = []  # no walk in the recording (e.g. a calibration pose): no events
    return fused, events


def export_skeleton(series: SkeletonSeries, fmt: str, events: list[MarkerEvent] | None = None
                    ) -> bytes:
    """A skeleton as C3D (mm, labelled points, events), TRC (mm) or CSV (m, states).

    Raises:
        InputError: unknown format.
    """
    if fmt not in ("c3d", "trc", "csv"):
        raise InputError(f"export format {fmt!r} is not c3d, trc or csv")
    with tempfile.TemporaryDirectory(prefix="gaitrig-export-") as d:
        path = Path(d) / f"export.{fmt}"
        if fmt == "csv":
            write_skeleton_csv(path, series)
        elif fmt == "c3d":
            write_skeleton_c3d(path, series, events or [])
        else:
            write_trc(path, skeleton_to_markers(series, units="mm"), "mm")
        return path.read_bytes()


def read_reference(path: Path, fmt: str) -> MarkerTrajectories:
    """Parse an uploaded reference recording (C3D, TRC or skeleton CSV) as markers.

    Raises:
        InputError: the file is not a valid file of that format.
    """
    return reference_markers(parse_reference(path, fmt))


def parse_reference(path: Path, fmt: str) -> MarkerTrajectories | SkeletonSeries:
    """Parse an uploaded reference recording as its reader returns it: a C3D or TRC
    file's markers, a skeleton CSV's skeleton. Both :func:`reference_markers` (what is
    stored of it) and the gait analysis (``app.server.analysis.reference_steps(...,
    data=)``) take the result, so an upload is parsed once.

    Raises:
        InputError: the file is not a valid file of that format.
    """
    if fmt == "c3d":
        return read_c3d(path)
    if fmt == "trc":
        return read_trc(path)
    if fmt == "csv":
        return read_skeleton_csv(path)
    raise InputError(f"reference format {fmt!r} is not c3d, trc or csv")


def reference_markers(data: MarkerTrajectories | SkeletonSeries) -> MarkerTrajectories:
    """The markers of a reference :func:`parse_reference` read (a skeleton's joints as
    markers, in metres)."""
    if isinstance(data, SkeletonSeries):
        return skeleton_to_markers(data, units="m")
    return data


# --------------------------------------------------------------------------- subject export

EXPORT_CHUNK = 1 << 20  # bytes read and sent at a time: the export's memory bound
_DEFLATE = (".json", ".csv", ".txt", ".trc")

EXPORT_README = """gaitrig export of one subject (right of access / data portability)
==================================================================

subject.json              the subject (pseudonym code, height and leg length in metres,
                          sex, birth year, notes), its project, sessions and recordings
                          with their states, node parts and attached references
export-notes.json         what could not be exported and why (empty when complete)
recordings/<rec_id>/      one folder per recording, as stored on the server:
  sensors.json            sensor poses used for this recording (T_world_sensor, 4x4, metres,
                          world frame Z up)
  analysis/*.json         gait analyses (method, estimator, sensors in the file name):
                          spatio-temporal parameters, events, placements
  reference/              a reference recording attached for the report's agreement section
  <node_id>/              one sensor's part, byte-identical to what the node recorded:
    manifest.json         files, sizes, SHA-256 (check with sha256sum)
    meta.json             part parameters, clock model (node time -> server time)
    index.json            [t_local, offset, kind] per record of frames.bin
    frames.bin            records: uint32 length, uint32 crc32, payload (one binary message
                          of the gaitrig node protocol: skeletons, depth/colour images)
    skeleton.csv          the same skeletons, readable anywhere: time (s, server clock),
                          <Joint>_x/_y/_z in metres in the sensor's camera frame
                          (OpenCV: +Z forward, +X right, +Y down), <Joint>_state
                          (0 not tracked, 1 inferred, 2 tracked), Kinect v2 joint names
references/<rec_id>/      reference recordings uploaded for a recording (C3D, TRC, CSV);
                          subject.json gives each file's original name
reports/                  the subject's gait reports (PDF), rendered from these recordings
                          when the export was made: one per session and, with several
                          sessions, one of all; export-notes.json says why one is missing

The server stores no report: the console renders them from these recordings and
analyses when asked (Reports page). Times are seconds, lengths metres unless a file says
otherwise. Formats: docs/storage.md and docs/gait-json.md of gaitrig.
"""


class _ZipSink(io.RawIOBase):
    """Where :func:`stream_zip`'s zip writer puts its bytes until they are sent."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.pos = 0

    def writable(self) -> bool:
        return True

    def write(self, b: Any) -> int:
        n = len(b)
        self.buf += b
        self.pos += n
        return n

    def tell(self) -> int:
        return self.pos

    def take(self) -> bytes:
        out = bytes(self.buf)
        self.buf.clear()
        return out


ExportEntry = tuple[str, "Path | bytes | Callable[[], bytes | None]"]


def stream_zip(entries: Iterable[ExportEntry]) -> Iterator[bytes]:
    """A zip archive written and handed out piece by piece (never whole in memory).

    Args:
        entries: ``(name in the archive, source)``; a source is a file, bytes, or a
            function called when its turn comes that gives bytes (None: left out).

    Yields:
        The archive's bytes, at most about :data:`EXPORT_CHUNK` at a time.
    """
    sink = _ZipSink()
    with zipfile.ZipFile(sink, "w", allowZip64=True) as z:
        for name, src in entries:
            info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = (zipfile.ZIP_DEFLATED if name.endswith(_DEFLATE)
                                  else zipfile.ZIP_STORED)
            if isinstance(src, Path):
                st = src.stat()
                info.file_size = st.st_size  # a part over 4 GiB needs ZIP64: say so first
                info.date_time = max(time.localtime(st.st_mtime)[:6], (1980, 1, 1, 0, 0, 0))
                with src.open("rb") as f, z.open(info, "w") as out:
                    while chunk := f.read(EXPORT_CHUNK):
                        out.write(chunk)
                        yield sink.take()
            else:
                data = src() if callable(src) else src
                if data is None:
                    continue
                z.writestr(info, data)
            yield sink.take()
    yield sink.take()


def recording_files(layout: StorageLayout, rec_id: str) -> list[tuple[str, Path]]:
    """Every finished file of a recording on the server (parts, poses, analyses, the
    reports' reference) and its uploaded references, with their names in an export."""
    out: list[tuple[str, Path]] = []
    for root, prefix in ((layout.recording_dir(rec_id), f"recordings/{rec_id}"),
                         (layout.reference_dir(rec_id), f"references/{rec_id}")):
        if not root.is_dir():
            continue
        for p in sorted(root.rglob("*")):
            rel = p.relative_to(root)
            if p.is_file() and ".incoming" not in rel.parts and not p.name.endswith(".tmp"):
                out.append((f"{prefix}/{rel.as_posix()}", p))
    return out


def subject_export(layout: StorageLayout, info: dict[str, Any], rec_ids: list[str],
                   live: dict[str, Any] | None = None,
                   reports: Callable[[list[str]], Iterable[ExportEntry]] | None = None
                   ) -> Iterator[ExportEntry]:
    """The entries of a subject's export (see :data:`EXPORT_README`).

    Args:
        layout: the server's storage layout.
        info: ``subject.json`` (the subject, its project, sessions and recordings).
        rec_ids: the subject's recordings.
        live: sensor poses known now, for a recording analysed the first time.
        reports: given the export's notes (to append to), the entries of the reports
            (``reports/...``), after the recordings.
    """
    from app.server import analysis as an

    notes: list[str] = []
    yield "README.txt", EXPORT_README.encode()
    yield "subject.json", json.dumps(info, indent=1, default=str).encode()
    for rec_id in rec_ids:
        rec_dir = layout.recording_dir(rec_id)
        parts = layout.complete_parts(rec_id)
        if parts:
            try:  # the default analysis, so the export has one (cached on the server)
                an.analyse_recording(rec_dir, an.AnalysisOptions(), live)
            except GaitrigError as exc:
                notes.append(f"recording {rec_id}: no analysis ({exc})")
        elif not rec_dir.is_dir():
            notes.append(f"recording {rec_id}: no data on the server (never transferred)")
        yield from recording_files(layout, rec_id)
        for node in parts:
            yield (f"recordings/{rec_id}/{node}/skeleton.csv",
                   functools.partial(_skeleton_csv, layout.part_dir(rec_id, node), notes))
    if reports is not None:
        yield from reports(notes)
    yield "export-notes.json", lambda: json.dumps(notes, indent=1).encode()


def _skeleton_csv(part_dir: Path, notes: list[str]) -> bytes | None:
    try:
        return export_skeleton(read_part_skeleton(part_dir), "csv")
    except GaitrigError as exc:
        notes.append(f"recording {part_dir.parent.name}, sensor {part_dir.name}: no "
                     f"skeleton.csv ({exc})")
        return None
