"""Xsens MVN exports (``.mvnx``, MVN Analyze / Animate XML): one :class:`ImuRecording`
per motion tracker.

Layout read: ``<mvnx><subject frameRate=…>`` with ``<segments><segment label=…>``,
``<sensors><sensor label=…>`` (the segment each tracker is strapped to) and
``<frames><frame type="normal" index=… time=…>``; the ``identity``/``tpose``/``npose``
frames before the motion are skipped. Per frame, for every sensor in ``<sensors>``
order: ``sensorOrientation`` (4 values, w-first, sensor-to-global), ``sensorFreeAcceleration``
(3, m/s², global frame, gravity removed), ``sensorMagneticField`` (3, sensor frame, a.u.:
1 = the field at calibration) and, in exports from before MVN 2018, ``sensorAcceleration``
and ``sensorAngularVelocity`` (3 each, the tracker's own readings); per segment
``angularVelocity`` (3, rad/s, global frame).

MVN's global frame is Z up, X magnetic north, Y west (NWU). The trackers' readings are
rebuilt in their own frame, as the filters need them:

* accelerometer (specific force): ``sensorAcceleration`` when the export has it (and it
  holds gravity), else ``Rᵀ (free acceleration + g ẑ)`` with ``R`` the sensor orientation;
* gyroscope: ``sensorAngularVelocity`` when present (its frame told from the
  orientation's rotation), else the strapped segment's ``angularVelocity`` rotated into
  the sensor (a tracker is rigid with its segment: same angular velocity), else the
  rotation between consecutive orientations over the frame step;
* magnetometer: ``sensorMagneticField`` as it is (unit ``"norm"``);
* reference: ``sensorOrientation`` turned into sensor-to-ENU (``q_ENU = q_ENU_NWU ⊗ q``),
  the filters' frame, in ``quat_ref``.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from array import array
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from engine.errors import InputError
from engine.geometry import quat_conj, quat_mul, quat_normalize, quat_rotate, quat_to_rotvec
from engine.imu.io import G, ImuRecording, MultipleSensorsError, _finalise

FloatArray = NDArray[np.float64]

#: largest export read (every frame is parsed; split longer takes in MVN)
MAX_MVNX_BYTES = 512 * 2**20
#: ENU <- NWU: +90° about Z (north becomes +Y, west -X)
_Q_ENU_NWU = np.array([np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)])
_SENSOR_TAGS = ("sensorOrientation", "sensorFreeAcceleration", "sensorMagneticField",
                "sensorAcceleration", "sensorAngularVelocity")
_HEADER_FRAMES = {"identity", "tpose", "tpose-isb", "npose", "tpose_isb"}
#: what a hostile file could inflate, bounded (an MVN export is ~6 levels deep, ~10
#: elements a frame, 23 segments and at most 17 trackers plus props, short labels)
MAX_DEPTH = 32
MAX_FRAME_CHILDREN = 256
MAX_LABELS = 256
MAX_LABEL_CHARS = 100
MAX_TRACKERS = 64
#: elements in a file: a real 256 MB export has < 1 M; each costs ~5 µs to walk, so a
#: file of empty elements (64 M in 256 MB, ~5 min) is stopped after ~1 min at most
MAX_ELEMENTS = 12_000_000
#: characters of one frame element's numbers (a full suit's segment data: ~4 kB)
MAX_VALUE_CHARS = 256 * 2**10
#: bytes between two ``<`` (a tag's attributes, a text node)
_MAX_RUN = 2**20
#: the XML prolog (declaration, comments) read before the root element
_PROLOG_BYTES = 2**20
_PROLOG_SPACE = re.compile(rb"[ \t\r\n]*")
_ENCODING = re.compile(rb"""encoding\s*=\s*["']([A-Za-z0-9._-]+)["']""")
_ENCODINGS = {b"utf-8", b"utf8", b"us-ascii", b"ascii", b"iso-8859-1", b"latin-1", b"latin1"}


def _local(tag: str) -> str:
    """The tag without its XML namespace (``{http://www.xsens.com/mvn/mvnx}frame``)."""
    return tag.rsplit("}", 1)[-1]


def _check_head(p: Path) -> None:
    """Refuse what is not an MVNX text file, and DTDs (entity expansion) before parsing."""
    try:
        size = p.stat().st_size
        with p.open("rb") as fh:
            head = fh.read(65536)
    except OSError as e:
        raise InputError(f"cannot read {p}: {e}") from None
    if size == 0:
        raise InputError(f"{p.name}: the file is empty")
    if size > MAX_MVNX_BYTES:
        raise InputError(f"{p.name}: {size / 2**20:.0f} MB is more than the "
                         f"{MAX_MVNX_BYTES // 2**20} MB an MVNX export may have; export a "
                         "shorter take")
    _check_prolog(p)
    _check_runs(p)
    if b"<mvnx" not in head and b"<frames" not in head:
        raise InputError(f"{p.name}: not an Xsens MVNX export (no <mvnx> element); export "
                         "the take from MVN as MVNX")


def _check_prolog(p: Path) -> None:
    """Refuse a DTD (entity expansion: billion laughs, external entities) wherever the
    prolog puts it, and encodings that could hide one from a byte scan.

    A DTD can only stand in the prolog, before the root element, between the XML
    declaration, comments and processing instructions: each is skipped by its own end
    (a comment may hold ``<mvnx``), so ``<!DOCTYPE`` after 64 kB of comment is still
    seen. UTF-16/32 (``<`` is two or four bytes) and declared encodings other than
    UTF-8/ASCII/Latin-1 are refused: MVN writes UTF-8.
    """
    with p.open("rb") as fh:
        head = fh.read(_PROLOG_BYTES)
    if head.startswith((b"\xff\xfe", b"\xfe\xff")) or b"\x00" in head[:4]:
        raise InputError(f"{p.name}: the XML is UTF-16 or UTF-32 encoded; MVN writes UTF-8 "
                         "— export the take again from MVN")
    i = 3 if head.startswith(b"\xef\xbb\xbf") else 0
    while True:
        m = _PROLOG_SPACE.match(head, i)
        i = m.end() if m else i
        end = b"?>" if head.startswith(b"<?", i) else b"-->" if head.startswith(b"<!--", i) \
            else None
        if end is not None:
            j = head.find(end, i + 2)
            if j < 0:
                raise InputError(f"{p.name}: the XML's prolog (declaration and comments "
                                 f"before <mvnx>) is longer than {_PROLOG_BYTES // 2**20} MB "
                                 "or unterminated; export the take again from MVN")
            if end == b"?>" and (enc := _ENCODING.search(head, i, j)) and \
                    enc.group(1).lower() not in _ENCODINGS:
                raise InputError(f"{p.name}: the XML declares the encoding "
                                 f"{enc.group(1).decode('ascii')!r}; MVN writes UTF-8 — "
                                 "export the take again from MVN")
            i = j + len(end)
        elif head.startswith(b"<!", i):
            raise InputError(f"{p.name}: the XML declares a DTD or entities, which MVNX "
                             "exports never do; export the take again from MVN")
        else:
            return  # the root element (or not XML: the parser says so)


def _check_runs(p: Path) -> None:
    """Refuse a run of more than :data:`_MAX_RUN` bytes without a ``<``: one start tag
    with a million attributes (``<`` may not stand in an attribute value) or one huge text
    node. Expat hands a tag's attributes over all at once: 10 MB of them took 600 MB.
    An MVN export's longest run is a frame element's numbers (a few kB). One pass in
    256 kB blocks (~0.7 s for 256 MB)."""
    run = 0
    with p.open("rb") as fh:
        while block := fh.read(2**18):  # small blocks: the pieces are many small objects
            pieces = block.split(b"<")
            run += len(pieces[0])
            longest = max(run, max(map(len, pieces[1:-1]), default=0))
            if len(pieces) > 1:
                run = len(pieces[-1])
                longest = max(longest, run)
            if longest > _MAX_RUN:
                raise InputError(f"{p.name}: more than {_MAX_RUN // 2**20} MB without an XML "
                                 "tag (one element with a huge text or a huge number of "
                                 "attributes); not an MVN export")


@dataclass
class _Column:
    """One frame element's numbers, every frame's appended (8 bytes a value: a 256 MB
    export's numbers fit in less than the file)."""

    values: array[float] = field(default_factory=lambda: array("d"))
    counts: list[int] = field(default_factory=list)

    def __bool__(self) -> bool:
        return bool(self.counts)


def _numbers(p: Path, tag: str, text: str, frame: object) -> array[float]:
    """A frame element's text as numbers, bounded in length."""
    if len(text) > MAX_VALUE_CHARS:
        raise InputError(f"{p.name}: frame {frame}: <{tag}> holds {len(text):,} characters, "
                         f"more than the {MAX_VALUE_CHARS:,} an MVN frame has; the export is "
                         "damaged")
    return array("d", map(float, text.split()))


def _read(p: Path) -> dict[str, Any]:
    """Sensor and segment labels, frame rate, and the normal frames' arrays."""
    _check_head(p)
    sensors: list[str] = []
    segments: list[str] = []
    rate: float | None = None
    index: array[float] = array("d")
    time_ms: array[float] = array("d")
    rows: dict[str, _Column] = {t: _Column() for t in (*_SENSOR_TAGS, "angularVelocity")}
    stack: list[str] = []
    elems: list[ET.Element] = []
    n_frames = 0
    n_children = 0
    n_elements = 0
    try:
        for event, el in ET.iterparse(p, events=("start", "end")):
            tag = _local(el.tag)
            if event == "start":
                parent = stack[-1] if stack else ""
                stack.append(tag)
                elems.append(el)
                n_elements += 1
                if n_elements > MAX_ELEMENTS:
                    raise InputError(f"{p.name}: more than {MAX_ELEMENTS:,} XML elements, far "
                                     "more than an MVN export of this size has; not an MVN "
                                     "export")
                if len(stack) > MAX_DEPTH:
                    raise InputError(f"{p.name}: elements nested more than {MAX_DEPTH} deep; "
                                     "not an MVN export")
                if tag == "frame":
                    n_children = 0
                elif parent == "frame":
                    n_children += 1
                    if n_children > MAX_FRAME_CHILDREN:
                        raise InputError(f"{p.name}: a frame holds more than "
                                         f"{MAX_FRAME_CHILDREN} elements; not an MVN export")
                if tag == "subject" and el.get("frameRate"):
                    rate = float(el.get("frameRate", "nan"))
                elif tag in ("sensor", "segment") and parent == f"{tag}s":
                    names = sensors if tag == "sensor" else segments
                    label = el.get("label") or f"{tag}{len(names) + 1}"
                    if len(names) >= MAX_LABELS or len(label) > MAX_LABEL_CHARS:
                        raise InputError(f"{p.name}: more than {MAX_LABELS} {tag}s or a {tag} "
                                         f"label longer than {MAX_LABEL_CHARS} characters; "
                                         "not an MVN export")
                    names.append(label)
                continue
            stack.pop()
            elems.pop()
            parent = stack[-1] if stack else ""
            if parent == "frame":
                continue  # read with its frame
            if tag == "frame" and el.get("type", "normal") == "normal":
                n_frames += 1
                frame = el.get("index", n_frames)
                got = {_local(c.tag): c.text or "" for c in el}
                for t, col in rows.items():
                    if t in got:
                        vals = _numbers(p, t, got[t], frame)
                        col.values.extend(vals)
                        col.counts.append(len(vals))
                    elif col:
                        raise InputError(f"{p.name}: frame {frame} lacks <{t}> that earlier "
                                         "frames have; the export is damaged")
                if rows["sensorOrientation"].counts[-1:] and \
                        rows["sensorOrientation"].counts[-1] > 4 * MAX_TRACKERS:
                    raise InputError(f"{p.name}: more than {MAX_TRACKERS} trackers in a frame; "
                                     "not an MVN export")
                idx, tm = el.get("index"), el.get("time")
                index.append(float(idx) if idx not in (None, "") else np.nan)
                time_ms.append(float(tm) if tm not in (None, "") else np.nan)
            # what was read is dropped: memory stays flat whatever the file holds
            el.clear()
            if elems:
                elems[-1].remove(el)
    except InputError:
        raise
    except ET.ParseError as e:
        raise InputError(f"{p.name}: not a readable MVNX (XML) file — damaged or truncated "
                         f"({e}); export the take again") from None
    except ValueError as e:
        raise InputError(f"{p.name}: a frame holds a non-numeric value ({e})") from None
    if n_frames < 2:
        raise InputError(f"{p.name}: the export holds {n_frames} motion frames; need at "
                         "least two")
    return {"sensors": sensors, "segments": segments, "rate": rate, "index": index,
            "time_ms": time_ms, "rows": rows}


def _stack(p: Path, col: _Column, tag: str, width: int) -> FloatArray:
    """Frames × values of one element; all frames must hold the same count."""
    n = set(col.counts)
    if len(n) != 1 or next(iter(n)) % width or not next(iter(n)):
        raise InputError(f"{p.name}: <{tag}> holds {sorted(n)[:8]} values per frame; expected "
                         f"the same multiple of {width} in every frame")
    return np.frombuffer(col.values, dtype=float).reshape(len(col.counts), -1).copy()


def _frame_time(p: Path, d: dict[str, Any],
                warnings: list[str]) -> tuple[FloatArray, float | None]:
    """Seconds: frame index / frame rate (exact, dropped frames visible), else the frames'
    ``time`` attribute (ms, rounded to whole ms)."""
    index = np.asarray(d["index"], dtype=float)
    rate = d["rate"]
    if rate and np.isfinite(rate) and rate > 0 and np.all(np.isfinite(index)):
        t, out_rate, what = (index - index[0]) / rate, float(rate), "index"
    else:
        ms = np.asarray(d["time_ms"], dtype=float)
        if not np.all(np.isfinite(ms)):
            raise InputError(f"{p.name}: frames carry neither an index with the subject's "
                             "frameRate nor a time; export the take again")
        warnings.append("time taken from the frames' millisecond time stamps (no frame "
                        "rate in the file)")
        t, out_rate, what = (ms - ms[0]) / 1000.0, None, "time"
    bad = np.flatnonzero(np.diff(t) <= 0)
    if len(bad):
        raise InputError(f"{p.name}: the frames' {what} does not increase at motion frame "
                         f"{int(bad[0]) + 1} (of {len(t)}); the export is damaged — export the "
                         "take again")
    return t, out_rate


def _rates_from_orientation(q: FloatArray, t: FloatArray) -> FloatArray:
    """Sensor-frame angular rate over each frame step: rotvec(q_{k-1}* ⊗ q_k) / Δt (the
    first sample repeats the second)."""
    w = np.empty((len(q), 3))
    dq = quat_mul(quat_conj(q[:-1]), q[1:])
    w[1:] = quat_to_rotvec(dq) / np.diff(t)[:, None]
    w[0] = w[1]
    return w


def _agree(a: FloatArray, b: FloatArray) -> float:
    """Median relative difference of two rate series (over samples that move)."""
    nb = np.linalg.norm(b, axis=1)
    moving = nb > max(0.05, float(np.percentile(nb, 50)) * 0.2)
    if moving.sum() < 5:
        return float(np.median(np.linalg.norm(a - b, axis=1)))
    return float(np.median(np.linalg.norm(a[moving] - b[moving], axis=1) / nb[moving]))


def sensor_labels(path: str | Path) -> list[str]:
    """The trackers of an MVNX export, in file order (``<sensors>`` labels).

    Args:
        path: The ``.mvnx`` file.

    Returns:
        The tracker labels (e.g. ``"Pelvis"``, ``"RightLowerLeg"``).

    Raises:
        InputError: not an MVNX file, or damaged XML.
    """
    return list(_read(Path(path))["sensors"])


def load_mvnx_all(path: str | Path) -> dict[str, ImuRecording]:
    """Every tracker of an Xsens MVNX export as its own recording (label -> recording).

    See the module docstring for what is read and how the readings are rebuilt.

    Args:
        path: The ``.mvnx`` file.

    Returns:
        Tracker label -> recording (SI units, time first axis, sensor frame;
        ``quat_ref`` sensor-to-ENU).

    Raises:
        InputError: not an MVNX file, damaged XML, no sensor data in the export (a
            segment-only export), inconsistent frames.
    """
    p = Path(path)
    d = _read(p)
    rows = d["rows"]
    if not rows["sensorOrientation"]:
        raise InputError(f"{p.name}: the MVNX export holds no sensor data (no "
                         "<sensorOrientation>), only segment kinematics; export again with "
                         "the sensor data (orientation, free acceleration, magnetic field) "
                         "ticked in MVN's export settings")
    warnings: list[str] = []
    time, rate = _frame_time(p, d, warnings)
    so = _stack(p, rows["sensorOrientation"], "sensorOrientation", 4)
    n_s = so.shape[1] // 4
    labels = list(d["sensors"])
    if len(labels) != n_s:
        if labels:
            warnings.append(f"{len(labels)} sensor labels for {n_s} sensors in the frames; "
                            "sensors numbered instead")
        labels = [f"sensor{k + 1}" for k in range(n_s)]
    arrays: dict[str, FloatArray] = {}
    for tag in _SENSOR_TAGS[1:]:
        if rows[tag]:
            a = _stack(p, rows[tag], tag, 3)
            if a.shape[1] != 3 * n_s:
                raise InputError(f"{p.name}: <{tag}> has {a.shape[1] // 3} sensors, "
                                 f"<sensorOrientation> {n_s}")
            arrays[tag] = a
    seg_w = None
    if rows["angularVelocity"]:
        seg_w = _stack(p, rows["angularVelocity"], "angularVelocity", 3)
    segs = list(d["segments"])
    if "sensorFreeAcceleration" not in arrays and "sensorAcceleration" not in arrays:
        raise InputError(f"{p.name}: the export has sensor orientations but no sensor "
                         "acceleration (<sensorFreeAcceleration>); tick it in MVN's export "
                         "settings")
    out: dict[str, ImuRecording] = {}
    up = np.array([0.0, 0.0, G])
    for k, label in enumerate(labels):
        w_ = list(warnings)
        q = quat_normalize(so[:, 4 * k:4 * k + 4])
        if not np.all(np.isfinite(q)):
            raise InputError(f"{p.name}: sensor {label}: orientation has zero or non-numeric "
                             "quaternions")
        meta: dict[str, Any] = {"format": "xsens-mvnx", "source": str(p), "sensor": label,
                                "sensors": labels, "gyr_unit": "rad/s", "acc_unit": "m/s2",
                                "mag_unit": "norm", "frame": "NWU (MVN global) -> ENU",
                                "quat_ref": {"order": "wxyz", "frame": "NWU", "inverse": False,
                                             "from": "declared"}}
        acc = None
        if "sensorAcceleration" in arrays:
            raw = arrays["sensorAcceleration"][:, 3 * k:3 * k + 3]
            med = float(np.median(np.linalg.norm(raw, axis=1)))
            if 0.5 * G < med < 2.0 * G:
                acc, meta["acc_from"] = raw, "sensorAcceleration"
            else:
                w_.append(f"sensorAcceleration's median magnitude is {med:.3g} m/s², not "
                          "gravity's; rebuilt from the free acceleration instead")
        if acc is None:
            if "sensorFreeAcceleration" not in arrays:
                raise InputError(f"{p.name}: sensor {label}: no usable acceleration; export "
                                 "<sensorFreeAcceleration> too")
            free = arrays["sensorFreeAcceleration"][:, 3 * k:3 * k + 3]
            acc = quat_rotate(quat_conj(q), free + up)  # specific force in the sensor frame
            meta["acc_from"] = "sensorFreeAcceleration + g, rotated into the sensor"
        w_diff = _rates_from_orientation(q, time)
        gyr = None
        if "sensorAngularVelocity" in arrays:
            raw = arrays["sensorAngularVelocity"][:, 3 * k:3 * k + 3]
            in_sensor = quat_rotate(quat_conj(q), raw)
            # the export does not say its frame: the one the orientation's rotation agrees with
            e_raw, e_rot = _agree(raw, w_diff), _agree(in_sensor, w_diff)
            gyr = raw if e_raw <= e_rot else in_sensor
            meta["gyr_from"] = ("sensorAngularVelocity (sensor frame)" if e_raw <= e_rot
                                else "sensorAngularVelocity (global frame, rotated)")
        elif seg_w is not None and label in segs and seg_w.shape[1] == 3 * len(segs):
            j = segs.index(label)
            gyr = quat_rotate(quat_conj(q), seg_w[:, 3 * j:3 * j + 3])
            meta["gyr_from"] = f"segment {label} angularVelocity, rotated into the sensor"
        else:
            gyr = w_diff
            meta["gyr_from"] = "rotation between consecutive sensor orientations"
            w_.append("gyroscope rebuilt from the orientation's frame-to-frame rotation (no "
                      "angular velocity for this sensor in the export)")
        mag = None
        if "sensorMagneticField" in arrays:
            mag = arrays["sensorMagneticField"][:, 3 * k:3 * k + 3]
            if not np.any(np.abs(mag) > 0):
                mag = None  # an Awinda take without the magnetometer exported: zeros
        if mag is None:
            meta["mag_unit"] = ""
        rec = _finalise(time, gyr, acc, mag, label, meta, w_, frequency=rate)
        ref = quat_mul(_Q_ENU_NWU, q)
        rec.quat_ref = np.where(ref[:, :1] < 0, -ref, ref)
        out[label] = rec
    return out


def load_mvnx(path: str | Path, sensor: str | None = None) -> ImuRecording:
    """One tracker of an Xsens MVNX export (see :func:`load_mvnx_all`).

    Args:
        path: the ``.mvnx`` file.
        sensor: the tracker's label (``Pelvis``, ``RightLowerLeg`` …; case ignored); may be
            omitted for an export of one tracker.

    Returns:
        The tracker's recording (SI units, time first axis, sensor frame; ``quat_ref``
        sensor-to-ENU).

    Raises:
        MultipleSensorsError: several trackers and ``sensor`` names none of them (the
            message lists the labels).
        InputError: see :func:`load_mvnx_all`.
    """
    p = Path(path)
    recs = load_mvnx_all(p)
    labels = list(recs)
    if sensor:
        hit = [n for n in labels if n.lower() == sensor.strip().lower()]
        if not hit:
            raise MultipleSensorsError(f"{p.name}: no sensor {sensor!r} in the export; it "
                                       f"holds {', '.join(labels)}", labels)
        return recs[hit[0]]
    if len(labels) == 1:
        return recs[labels[0]]
    raise MultipleSensorsError(
        f"{p.name}: the MVNX export holds {len(labels)} trackers ({', '.join(labels)}); "
        "choose the one to read with sensor (its label)", labels)
