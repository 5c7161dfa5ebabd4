"""C3D read/write through ``ezc3d``.

Time axis convention (the one Vicon Nexus and kineticstoolkit use): frame ``i`` of the
file is at ``(first_frame + i) / rate`` seconds with ``first_frame`` zero-based as
``ezc3d`` reports it, which is the time axis of the ``EVENT:TIMES`` annotations.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from engine.errors import InputError
from engine.io.markers import (
    MarkerEvent,
    MarkerTrajectories,
    file_units,
    normalise_event,
    normalise_units,
    unit_scale,
)
from engine.skeleton import SkeletonSeries, TrackingState

#: POINT parameters that list model outputs (angles, forces ...) stored as points.
_NON_MARKER_GROUPS = ("ANGLES", "FORCES", "MOMENTS", "POWERS", "SCALARS", "REACTIONS")

#: What to do about a file that is not readable as C3D (said with the reason).
C3D_ADVICE = "export it again from the motion-capture software, as C3D"

#: What to do about a C3D file that is cut short (a copy or download that stopped).
C3D_CUT_ADVICE = "copy or export it again"

#: C3D processor types (the parameter section's 4th byte): 84 Intel, 85 DEC, 86 MIPS.
_PROCESSOR_MIPS, _PROCESSOR_DEC = 86, 85

_EVENT_LABELS = {"foot_strike": "Foot Strike", "foot_off": "Foot Off"}
_SIDE_CONTEXT = {"L": "Left", "R": "Right", "": "General"}


def _param(params: dict[str, Any], group: str, name: str) -> list[Any]:
    """A parameter's values as a list (empty when the parameter is absent)."""
    try:
        v = params[group][name]["value"]
    except KeyError:
        return []
    return list(np.asarray(v).ravel()) if not isinstance(v, list) else v


def _first_frame(header_first: int, params: dict[str, Any]) -> int:
    """Zero-based first frame; the header's is 16-bit, so a trial starting after frame
    65535 of the capture keeps its real start in ``TRIAL:ACTUAL_START_FIELD`` (low and
    high 16-bit words, one-based; Vicon Nexus)."""
    asf = _param(params, "TRIAL", "ACTUAL_START_FIELD")
    if len(asf) >= 2:
        full = int(asf[0]) % 65536 + 65536 * int(asf[1]) - 1
        # trust it only where it agrees with the header's (wrapped or saturated) value
        if full >= 0 and (full % 65536 == header_first % 65536 or header_first >= 65534):
            return full
    return header_first


def _subject_length_m(params: dict[str, Any], name: str) -> float | None:
    """A ``PROCESSING`` subject measurement (Plug-in Gait ``LAnkleWidth`` ...) in metres.

    Vicon Nexus writes them in millimetres whatever ``POINT:UNITS`` says; a value of
    0.02-0.2 is taken as metres (other exporters). 0 (not measured) or anything outside
    a human ankle's or marker's range gives None.
    """
    v = _param(params, "PROCESSING", name)
    try:
        x = float(v[0]) if v else float("nan")
    except (TypeError, ValueError):
        return None
    if 2.0 <= x <= 200.0:
        return x * 1e-3
    if 0.002 <= x <= 0.2:
        return x
    return None


def _frames_held(path: Path) -> tuple[int, int] | None:
    """(frames the file's data section holds, frames its header announces), from the
    512-byte header and the file's size; None when the header gives no such count (no
    full header, not a C3D header, no points or analogs, or nonsense values).

    The data section starts at the header's 512-byte block (word 9) and holds, per frame,
    4 values per point (word 2) plus the analog samples (word 3), each of 4 bytes (float,
    a negative scale factor, words 7-8) or 2 (integer). A file longer than that (padding
    to a whole block, data after the points) holds them all. A header saturated at 65535
    frames (a longer trial) announces fewer frames than it holds, never more.
    """
    try:
        with open(path, "rb") as f:
            head = f.read(512)
            if len(head) < 512 or head[1] != 0x50 or head[0] < 2:
                return None
            f.seek((head[0] - 1) * 512 + 3)  # the parameter section's processor type
            proc = f.read(1)
            size = f.seek(0, 2)
    except OSError:  # (unreadable: said as ezc3d fails on it)
        return None
    big = proc == bytes([_PROCESSOR_MIPS])  # (a file cut before it: Intel's, the usual)
    w = struct.unpack(">10H" if big else "<10H", head[2:22])
    n_points, n_analog, first, last, data_start = w[0], w[1], w[2], w[3], w[7]
    # sign bit of the scale factor: IEEE big- or little-endian, or DEC (VAX) floats,
    # whose sign is bit 15 of the first little-endian word
    sign = head[12] if big else head[13] if proc == bytes([_PROCESSOR_DEC]) else head[15]
    value_bytes = 4 if sign & 0x80 else 2
    frame_bytes = (4 * n_points + n_analog) * value_bytes
    announced = last - first + 1
    if frame_bytes == 0 or announced <= 0 or data_start <= head[0]:
        return None
    data = size - (data_start - 1) * 512
    return min(max(data, 0) // frame_bytes, announced), announced


def _whole_by_parameters(params: dict[str, Any], size: int, announced: int) -> bool:
    """Whether a file of ``size`` bytes holds ``announced`` frames by its parameters:
    ``POINT:DATA_START`` (512-byte block), ``POINT:USED`` points of 4 values,
    ``ANALOG:USED`` channels at ``ANALOG:RATE / POINT:RATE`` samples a frame, 4-byte
    values when ``POINT:SCALE`` is negative, else 2. False when they do not say."""
    try:
        start = int(_param(params, "POINT", "DATA_START")[0])
        n_points = int(_param(params, "POINT", "USED")[0])
        scale = float(_param(params, "POINT", "SCALE")[0])
        channels = int((_param(params, "ANALOG", "USED") or [0])[0])
        ratio = 0
        if channels:
            ratio = round(float(_param(params, "ANALOG", "RATE")[0])
                          / float(_param(params, "POINT", "RATE")[0]))
    except (IndexError, TypeError, ValueError, ZeroDivisionError, OverflowError):
        return False
    frame_bytes = (4 * n_points + channels * ratio) * (4 if scale < 0 else 2)
    if start < 2 or frame_bytes <= 0:
        return False
    return size - (start - 1) * 512 >= announced * frame_bytes


def read_c3d(path: str | Path, markers_only: bool = True) -> MarkerTrajectories:
    """Read the 3-D points, labels, rate, units and events of a C3D file.

    Args:
        path: the ``.c3d`` file.
        markers_only: drop points that the file lists as model outputs (joint angles,
            forces, moments, powers) in ``POINT:ANGLES`` etc.

    Returns:
        Marker trajectories in metres (file axes), NaN where a marker is missing
        (negative residual or an exact 0,0,0). Plug-in Gait's ``PROCESSING`` ankle widths
        and marker diameter, when the file has them, are in ``meta["ankle_width_m"]``
        (``{"L": m, "R": m}``) and ``meta["marker_diameter_m"]``.

    Raises:
        InputError: the file cannot be read, is cut short (holds fewer frames than its
            header announces) or has no 3-D points.
    """
    import ezc3d

    p = Path(path)
    if not p.is_file():
        raise InputError(f"C3D file not found: {p}")
    # A copy or download that stopped leaves a file that starts right: ezc3d reads it
    # without a word, the missing frames as gaps (or drops them, or fails on them).
    held = _frames_held(p)
    cut = held is not None and held[0] < held[1]

    def cut_short() -> InputError:
        assert held is not None
        return InputError(f"cannot read {p.name} as C3D: the file is cut short (it holds "
                          f"{held[0]} of the {held[1]} frames its header announces); "
                          f"{C3D_CUT_ADVICE}")

    try:
        c = ezc3d.c3d(str(p), extract_forceplat_data=False)
    except Exception:  # ezc3d raises plain RuntimeError/IOError on corrupt files
        if cut:
            raise cut_short() from None
        # (its own words — "File must be a valid c3d file: iostream error", "Could not read
        # the processor type" — say nothing a clinician can act on)
        what = ("the file is empty" if p.stat().st_size == 0
                else "the file is damaged or not a C3D file")
        raise InputError(f"cannot read {p.name} as C3D: {what} ({C3D_ADVICE})") from None
    params = c["parameters"]
    # Some writers' headers disagree with their parameters (the analog count, the scale
    # factor's sign), and the parameters are what ezc3d reads the data by: a file is cut
    # short only when it is by both, so a whole file from another lab is never refused.
    if held is not None and cut and not _whole_by_parameters(params, p.stat().st_size,
                                                              held[1]):
        raise cut_short()
    labels = [str(s).strip() for s in (_param(params, "POINT", "LABELS") or [])]
    pts = np.asarray(c["data"]["points"], dtype=float)
    n_points = pts.shape[1] if pts.ndim == 3 else 0
    if n_points == 0:
        raise InputError(f"{p.name} holds no 3-D points")
    # Files with more than 255 points continue the labels in LABELS2, LABELS3 ...
    k = 2
    while len(labels) < n_points and _param(params, "POINT", f"LABELS{k}"):
        labels += [str(s).strip() for s in _param(params, "POINT", f"LABELS{k}")]
        k += 1
    labels = (labels + [f"point{i + 1}" for i in range(len(labels), n_points)])[:n_points]
    rate = float(c["header"]["points"]["frame_rate"])
    if not (np.isfinite(rate) and rate > 0):  # (ezc3d takes POINT:RATE over the header's)
        raise InputError(f"{p.name} gives no frame rate (POINT:RATE and the header's are 0)")
    units_v = _param(params, "POINT", "UNITS")
    # No POINT:UNITS, or an unknown one: guessed from the size of the body.
    units = file_units(str(units_v[0]) if units_v else "", pts[:3].transpose(2, 1, 0), labels)
    scale = unit_scale(units)

    xyz = pts[:3].transpose(2, 1, 0) * scale  # (T, M, 3)
    try:
        resid = np.asarray(c["data"]["meta_points"]["residuals"], dtype=float)[0].T
        xyz[resid < 0] = np.nan
    except (KeyError, IndexError):
        pass
    xyz[np.all(xyz == 0.0, axis=-1)] = np.nan

    keep = np.ones(n_points, dtype=bool)
    if markers_only:
        model = set()
        for g in _NON_MARKER_GROUPS:
            v = _param(params, "POINT", g)
            if v:
                model |= {str(s).strip() for s in v}
        keep = np.array([lab not in model for lab in labels])
    first = _first_frame(int(c["header"]["points"]["first_frame"]), params)
    T = xyz.shape[0]
    times = (first + np.arange(T)) / rate

    events: list[MarkerEvent] = []
    ev = params.get("EVENT", {})
    if "TIMES" in ev:
        tv = np.asarray(ev["TIMES"]["value"], dtype=float).reshape(2, -1)
        ev_t = tv[0] * 60.0 + tv[1]
        ev_l = list(ev.get("LABELS", {}).get("value", [])) + [""] * len(ev_t)
        ev_c = list(ev.get("CONTEXTS", {}).get("value", [])) + [""] * len(ev_t)
        used = ev.get("USED", {}).get("value", [len(ev_t)])
        n_ev = min(int(np.asarray(used).ravel()[0]), len(ev_t))
        events = [normalise_event(str(ev_l[i]), str(ev_c[i]), float(ev_t[i]))
                  for i in range(n_ev)]
    meta: dict[str, Any] = {"source": str(p), "first_frame": first}
    widths = {side: _subject_length_m(params, f"{side}AnkleWidth") for side in ("L", "R")}
    if any(w is not None for w in widths.values()):
        meta["ankle_width_m"] = {s: w for s, w in widths.items() if w is not None}
    diameter = _subject_length_m(params, "MarkerDiameter")
    if diameter is not None and diameter <= 0.05:
        meta["marker_diameter_m"] = diameter
    return MarkerTrajectories(
        times=times, positions=xyz[:, keep],
        labels=[lb for lb, k_ in zip(labels, keep, strict=True) if k_],
        rate=rate, units=units, events=events, meta=meta,
    )


def _subject_lengths(meta: dict[str, Any]) -> dict[str, float]:
    """The ``PROCESSING`` subject measurements :func:`read_c3d` put in ``meta``, in metres.

    ``meta["ankle_width_m"]`` (``{"L": m, "R": m}``) gives ``LAnkleWidth``/``RAnkleWidth``,
    ``meta["marker_diameter_m"]`` ``MarkerDiameter``; absent keys give nothing.

    Raises:
        InputError: a value that is not a positive length in the range :func:`read_c3d`
            reads back (2-200 mm).
    """
    out: dict[str, float] = {}
    widths = meta.get("ankle_width_m") or {}
    if not isinstance(widths, dict):
        raise InputError("meta['ankle_width_m'] must be {'L': metres, 'R': metres}")
    named = [(f"{s}AnkleWidth", widths[s]) for s in ("L", "R") if widths.get(s) is not None]
    if meta.get("marker_diameter_m") is not None:
        named.append(("MarkerDiameter", meta["marker_diameter_m"]))
    for name, v in named:
        try:
            x = float(v)
        except (TypeError, ValueError):
            x = float("nan")
        if not 0.002 <= x <= 0.2:  # NaN fails too
            raise InputError(f"{name} {v!r} is not a length in metres between 0.002 and 0.2 "
                             "(meta['ankle_width_m'] / meta['marker_diameter_m'])")
        out[name] = x
    return out


def write_c3d(path: str | Path, markers: MarkerTrajectories, units: str | None = None) -> None:
    """Write marker trajectories (and their events) to a C3D file.

    The subject's ankle widths and marker diameter that :func:`read_c3d` took from a
    file's ``PROCESSING`` group (``markers.meta["ankle_width_m"]``,
    ``meta["marker_diameter_m"]``) are written back there as Plug-in Gait names them
    (``LAnkleWidth``, ``RAnkleWidth``, ``MarkerDiameter``), in the unit written (mm or
    m; a file in cm gets mm, Vicon's unit for them): a file read and written again keeps
    the ankle joint centres the crossing method places with them.

    Args:
        path: destination ``.c3d``.
        markers: trajectories in metres; their ``times[0] * rate`` must be a whole frame
            number (it becomes the file's first frame).
        units: length unit to write (default: ``markers.units``; Vicon tools expect mm).

    Raises:
        InputError: the time axis does not start on a whole frame, a label is longer
            than 255 characters, or an ankle width / marker diameter in ``meta`` is not a
            length in metres of 0.002-0.2.
    """
    import ezc3d

    u = units or markers.units or "mm"
    scale = unit_scale(u)
    first = round(float(markers.times[0]) * markers.rate) if len(markers) else 0
    if len(markers) and abs(first - markers.times[0] * markers.rate) > 1e-3:
        raise InputError("C3D time axis must start on a whole frame (times[0] * rate); "
                         "shift the times first")
    if any(len(lab) > 255 for lab in markers.labels):
        raise InputError("C3D labels must be at most 255 characters")
    subject = _subject_lengths(markers.meta or {})
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [float(markers.rate)]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(markers.labels)
    c["parameters"]["POINT"]["UNITS"]["value"] = [u]
    data = np.ones((4, len(markers.labels), len(markers)))
    data[:3] = (markers.positions / scale).transpose(2, 1, 0)
    c["data"]["points"] = data
    c["header"]["points"]["first_frame"] = min(int(first), 65534)  # 16-bit, one-based
    last = int(first) + len(markers)  # one-based, as Vicon writes them
    for name, v in (("ACTUAL_START_FIELD", int(first) + 1), ("ACTUAL_END_FIELD", last)):
        c.add_parameter("TRIAL", name, [v % 65536, v // 65536])
    # in the points' unit where read_c3d tells it from the value (mm: 64, m: 0.064); a cm
    # value (6.4) would read as mm, so cm files get mm as Vicon Nexus writes them
    length_scale = scale if normalise_units(u) in ("mm", "m") else 1e-3
    for name, x in subject.items():
        c.add_parameter("PROCESSING", name, [float(x / length_scale)])
    for e in markers.events:
        minutes = int(e.time_s // 60.0)
        c.add_event([minutes, float(e.time_s - 60.0 * minutes)],
                    _SIDE_CONTEXT.get(e.side, "General"),
                    e.label or _EVENT_LABELS.get(e.kind, e.kind), "", "",
                    1 if e.kind == "foot_strike" else 2 if e.kind == "foot_off" else 0)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    c.write(str(path))


def skeleton_to_markers(series: SkeletonSeries, events: Sequence[MarkerEvent] = (),
                        tracked_only: bool = False, rate: float | None = None,
                        units: str = "mm") -> MarkerTrajectories:
    """View a skeleton series as labelled points (one per joint, SDK names).

    Args:
        series: the skeleton (uniformly sampled for C3D/TRC export).
        events: gait events to carry along.
        tracked_only: blank joints that are not TRACKED (NOT_TRACKED ones are always blank).
        rate: sampling rate, Hz; default one over the median time step.
        units: unit to record as the unit of the file to write.

    Returns:
        Marker trajectories (metres, the series' frame and time axis), one per joint.

    Raises:
        InputError: fewer than two frames and no ``rate``.
    """
    if len(series) < 2 and rate is None:
        raise InputError("need at least two frames (or an explicit rate) to export")
    r = float(rate) if rate is not None else float(1.0 / np.median(np.diff(series.times)))
    pos = series.tracked_positions() if tracked_only else series.positions.copy()
    pos[series.states == TrackingState.NOT_TRACKED] = np.nan
    return MarkerTrajectories(series.times.copy(), pos, list(series.joint_set.joints), r, units,
                              list(events), dict(series.meta))


def write_skeleton_c3d(path: str | Path, series: SkeletonSeries,
                       events: Sequence[MarkerEvent] = (), units: str = "mm") -> None:
    """Export a uniformly sampled skeleton as a C3D file (joints = labelled points).

    The time axis is shifted to start on a whole frame if needed.

    Args:
        path: Destination ``.c3d`` (overwritten).
        series: The skeleton (metres, time first axis); its rate is one over the median
        time step.
        events: Gait events to store in the file's EVENT group.
        units: Length unit to write (Vicon tools expect ``"mm"``).

    Raises:
        InputError: fewer than two frames.
    """
    m = skeleton_to_markers(series, events, units=units)
    shift = round(m.times[0] * m.rate) / m.rate - m.times[0]
    if abs(shift) > 1e-9:
        m.times = m.times + shift
        m.events = [MarkerEvent(e.time_s + shift, e.side, e.kind, e.label) for e in m.events]
    write_c3d(path, m, units)
