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

import xml.etree.ElementTree as ET
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
    if b"<!DOCTYPE" in head or b"<!ENTITY" in head:
        raise InputError(f"{p.name}: the XML declares a DTD or entities, which MVNX exports "
                         "never do; export the take again from MVN")
    if b"<mvnx" not in head and b"<frames" not in head:
        raise InputError(f"{p.name}: not an Xsens MVNX export (no <mvnx> element); export "
                         "the take from MVN as MVNX")


def _read(p: Path) -> dict[str, Any]:
    """Sensor and segment labels, frame rate, and the normal frames' arrays."""
    _check_head(p)
    sensors: list[str] = []
    segments: list[str] = []
    rate: float | None = None
    index: list[float] = []
    time_ms: list[float] = []
    rows: dict[str, list[FloatArray]] = {t: [] for t in (*_SENSOR_TAGS, "angularVelocity")}
    stack: list[str] = []
    frames_el: ET.Element | None = None
    n_frames = 0
    try:
        for event, el in ET.iterparse(p, events=("start", "end")):
            tag = _local(el.tag)
            if event == "start":
                parent = stack[-1] if stack else ""
                stack.append(tag)
                if tag == "subject" and el.get("frameRate"):
                    rate = float(el.get("frameRate", "nan"))
                elif tag == "sensor" and parent == "sensors":
                    sensors.append(el.get("label") or f"sensor{len(sensors) + 1}")
                elif tag == "segment" and parent == "segments":
                    segments.append(el.get("label") or f"segment{len(segments) + 1}")
                elif tag == "frames":
                    frames_el = el
                continue
            stack.pop()
            if tag != "frame":
                continue
            if el.get("type", "normal") == "normal" and el.get("type") not in _HEADER_FRAMES:
                n_frames += 1
                got = {_local(c.tag): c.text or "" for c in el}
                for t in rows:
                    if t in got:
                        rows[t].append(np.array(got[t].split(), dtype=float))
                    elif rows[t]:
                        raise InputError(f"{p.name}: frame {el.get('index', n_frames)} lacks "
                                         f"<{t}> that earlier frames have; the export is "
                                         "damaged")
                idx, tm = el.get("index"), el.get("time")
                index.append(float(idx) if idx not in (None, "") else np.nan)
                time_ms.append(float(tm) if tm not in (None, "") else np.nan)
            if frames_el is not None:
                frames_el.remove(el)  # frames are read once: keep memory flat
            else:
                el.clear()
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


def _stack(p: Path, rows: list[FloatArray], tag: str, width: int) -> FloatArray:
    """Frames × values of one element; all frames must hold the same count."""
    n = {len(r) for r in rows}
    if len(n) != 1 or next(iter(n)) % width:
        raise InputError(f"{p.name}: <{tag}> holds {sorted(n)} values per frame; expected "
                         f"the same multiple of {width} in every frame")
    return np.vstack(rows)


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
