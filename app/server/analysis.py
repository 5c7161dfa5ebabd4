"""Gait analysis of recordings held by the server, and the data of gait reports.

A recording on the server is a folder ``<data_dir>/recordings/<rec_id>/`` with one
sub-folder per node part in the node store's format (:mod:`app.nodes.store`:
``meta.json`` with ``node_id``, ``t_start_server`` and the clock model ``clock_start``;
``frames.bin`` with the binary skeleton messages). The transfer from the nodes fills it.

Analysis of a recording (:func:`analyse_recording`):

1. each part's skeleton stream is read (per frame, the body with most tracked joints);
2. its clock model maps node-local times onto the recording's time axis (0 = the
   recording's start in server time), through
   :func:`engine.integration.integrate_skeletons`'s own time correction;
3. each sensor's pose ``T_world_sensor`` comes from ``sensors.json`` in the recording
   folder: a snapshot of the calibration (or of the node's reported pose) taken the first
   time the recording is analysed, so a later recalibration never changes old results
   silently;
4. Kinect-type trackers assume the person faces the sensor: a person seen from behind
   is reported mirrored (left and right labels swapped). Each sensor's frames are
   checked against the walking direction and un-mirrored (:func:`unmirror_back_facing`);
5. the selected sensors (all, or a subset for the one- vs two-sided comparison) are fused
   and :class:`engine.gait.GaitAnalysis` runs on the fused skeleton.

Results — the gait JSON (``docs/gait-json.md``), the fusion quality report, foot
placements and ankle heights for the plots — are cached as JSON in
``<recording>/analysis/`` keyed by the options and by a fingerprint of the parts and
poses (a part that arrives later makes a new analysis); a failure (e.g. too few steps) is cached
as its message, so a clinician gets the same clear answer at once next time.
"""

from __future__ import annotations

import copy
import functools
import hashlib
import json
import logging
import math
import os
import re
import secrets
from collections import Counter
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from engine.errors import GaitrigError, InputError, InsufficientDataError
from engine.gait import GaitAnalysis
from engine.integration import SensorStream, integrate_skeletons
from engine.io.markers import MarkerTrajectories
from engine.mocap import FeetTrajectories, feet_from_skeleton
from engine.report.render import AgreementRow, QualityInfo, ReportData, TrialData
from engine.skeleton import JOINT_SETS, SkeletonSeries, TrackingState
from engine.wording import count

if TYPE_CHECKING:  # engine.agreement imports scipy: loaded on first use
    from engine.agreement import StudyTrial

_log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]

#: Bump when the analysis changes, so old cached results are recomputed (2: crossings
#: hidden in a short gap of one ankle are found, see GaitAnalysis.max_crossing_gap_s;
#: 3: leg swaps confirmed on the floor, engine.integration._unswap_legs; 4: each sensor
#: placed at its pose for the weighted fusion, was at the world origin; 5: the top view's
#: passes walked back measured along the first pass's axis, see _placements).
ANALYSIS_VERSION = 5
#: Folder name of the server's recordings under the data folder.
RECORDINGS_DIR = "recordings"
_ID_RE = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
#: Walking speed (m/s) of the body centre above which the walking direction tells which
#: way the person faces (below it a person may stand or turn on the spot).
FACING_MIN_SPEED = 0.3
#: Points kept for the ankle-height plot (the report shows one trial's trajectories).
MAX_PLOT_POINTS = 1200
#: A recording shorter than this (s) holds no step a report can use (the Record page
#: says so once it is copied): its analysis says how long it was before which joint
#: was missing ("no tracked AnkleLeft positions" told a clinician nothing).
SHORT_RECORDING_S = 2.0


def _too_short(streams: Sequence[SensorStream], why: str) -> str:
    """``why`` prefixed with the recording's length when it is under
    :data:`SHORT_RECORDING_S` (the longest sensor's skeleton span), else ``why``."""
    spans = []
    for s in streams:
        ts = np.asarray(getattr(getattr(s, "series", None), "times", ()), dtype=float)
        if ts.size:
            spans.append(float(ts[-1] - ts[0]))
    span = round(max(spans, default=SHORT_RECORDING_S), 1)  # (rounded as shown: never "only 2.0 s")
    if span >= SHORT_RECORDING_S:
        return why
    return (f"the recording lasted only {span:.1f} s, too short for a walk with steps: "
            f"record a longer walk ({why})")


def _write_json(path: Path, obj: Any) -> None:
    """Atomic write; the temporary name is unique so concurrent requests never collide."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    tmp.write_text(json.dumps(obj))
    os.replace(tmp, path)
    from app.server.storage import note_changed  # (storage imports this module)

    note_changed(path)  # the recording's bytes on the server changed


def _fingerprint(rec_dir: Path) -> str:
    """Changes when a part arrives or changes, or the sensor poses are replaced."""
    h = hashlib.sha1()
    for node, d in part_dirs(rec_dir).items():
        h.update(f"{node}:{(d / 'frames.bin').stat().st_size};".encode())
    poses = rec_dir / "sensors.json"
    if poses.is_file():
        h.update(poses.read_bytes())
    return h.hexdigest()[:10]


def check_id(value: str, what: str = "recording id") -> str:
    """``value`` if it is a safe folder name (no path traversal), else :class:`InputError`."""
    if not _ID_RE.match(value) or value in (".", ".."):
        raise InputError(f"{what} {value!r} must be 1-64 characters of A-Z a-z 0-9 _ . -")
    return value


def recording_dir(data_dir: Path, rec_id: str) -> Path:
    """Folder of a recording on the server (may not exist yet)."""
    return Path(data_dir) / RECORDINGS_DIR / check_id(rec_id)


def part_dirs(rec_dir: Path) -> dict[str, Path]:
    """Node id → part folder of every part on the server with skeleton data."""
    if not rec_dir.is_dir():
        return {}
    out: dict[str, Path] = {}
    for d in sorted(p for p in rec_dir.iterdir() if p.is_dir()):
        if _ID_RE.match(d.name) and (d / "frames.bin").is_file() and (d / "meta.json").is_file():
            out[d.name] = d
    return out


def read_meta(part_dir: Path) -> dict[str, Any]:
    """A part's ``meta.json``."""
    try:
        meta = json.loads((part_dir / "meta.json").read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"part {part_dir.name}: unreadable meta.json ({exc})") from exc
    if not isinstance(meta, dict):
        raise InputError(f"part {part_dir.name}: meta.json is not an object")
    return meta


def read_part(part_dir: Path) -> SkeletonSeries:
    """A part's skeleton stream (sensor frame, node-local clock).

    Per frame the body with the most tracked joints is taken (one subject walks at a
    time); frames without a body are all NOT_TRACKED.

    Raises:
        InsufficientDataError: the part holds fewer than two skeleton frames.
    """
    from app.nodes.protocol import ProtocolError, decode_skeletons
    from app.nodes.store import NodeStore

    store = NodeStore(part_dir.parent)
    times: list[float] = []
    pos: list[FloatArray] = []
    sts: list[NDArray[np.uint8]] = []
    n_joints: int | None = None
    for header, payload in store.read(part_dir.name):
        if header.get("kind") != "skeleton":
            continue
        try:
            p, s = decode_skeletons(header, payload)
        except ProtocolError:
            continue  # a damaged frame is skipped, not fatal
        t = float(header["t"])
        if times and t <= times[-1]:
            continue
        J = p.shape[1] if p.shape[0] else (n_joints or int(header.get("joints", 25)))
        if n_joints is None:
            n_joints = J
        if n_joints != J:
            continue
        if p.shape[0]:
            b = int(np.argmax((s == TrackingState.TRACKED).sum(axis=1)))
            pos.append(p[b].astype(float))
            sts.append(s[b])
        else:
            pos.append(np.full((J, 3), np.nan))
            sts.append(np.zeros(J, np.uint8))
        times.append(t)
    if len(times) < 2:
        raise InsufficientDataError(f"sensor {part_dir.name}: the recording part holds "
                                    f"{count(len(times), 'skeleton frame')}")
    J = n_joints or 25
    # The stream carries no joint names: the joint count tells the set (as in
    # app.server.storage.read_part_skeleton); a k4a node's 32 joints are Azure Kinect's.
    js = next((j for j in JOINT_SETS.values() if len(j.joints) == J), None)
    if js is None:
        raise InputError(f"sensor {part_dir.name}: skeletons with {J} joints match no known "
                         f"joint set ({', '.join(sorted(JOINT_SETS))})")
    P = np.asarray(pos, dtype=float)
    S = np.asarray(sts, dtype=np.uint8)
    P[S == TrackingState.NOT_TRACKED] = np.nan
    return SkeletonSeries(np.asarray(times), P, S, js, {"sensor_id": part_dir.name})


def _swap_pairs(names: tuple[str, ...]) -> list[tuple[int, int]]:
    pairs = []
    # Kinect v1/v2 names end in "Left"; Azure Kinect's (a k4a node) in "_LEFT".
    for left, right in (("Left", "Right"), ("_LEFT", "_RIGHT")):
        for i, n in enumerate(names):
            if n.endswith(left):
                other = n[: -len(left)] + right
                if other in names:
                    pairs.append((i, names.index(other)))
    return pairs


def unmirror_back_facing(series_world: SkeletonSeries, sensor_pos: FloatArray
                         ) -> tuple[SkeletonSeries, float]:
    """Swap left/right labels of frames in which the sensor sees the person's back.

    Body trackers of the Kinect family fit a person as if facing the sensor, so from
    behind the left leg is labelled right. The true facing is the walking direction (the
    body centre's horizontal velocity); the labelled facing is the normal of the labelled
    hip axis. While walking faster than :data:`FACING_MIN_SPEED`, frames whose labelled
    facing points against the walking direction *and* whose sensor is behind the person
    are swapped. Standing frames keep the decision of the nearest walking frame.

    Args:
        series_world: one sensor's skeleton in the world frame (Z up).
        sensor_pos: the sensor's position in the world (3,).

    Returns:
        The corrected series and the fraction of its tracked frames that were swapped.
    """
    js = series_world.joint_set
    pairs = _swap_pairs(js.joints)
    if not pairs:
        return series_world, 0.0
    P = series_world.positions
    t = series_world.times
    c = P[:, js.role_index("pelvis")]
    hl = P[:, js.index(js.roles["hip_left"])]
    hr = P[:, js.index(js.roles["hip_right"])]
    ok = np.isfinite(c).all(axis=1) & np.isfinite(hl).all(axis=1) & np.isfinite(hr).all(axis=1)
    if ok.sum() < 5:
        return series_world, 0.0
    # Walking velocity from the centre over ±0.25 s (robust to joint jitter).
    idx = np.flatnonzero(ok)
    v = np.full((len(t), 2), np.nan)
    for k in idx:
        near = idx[(t[idx] >= t[k] - 0.25) & (t[idx] <= t[k] + 0.25)]
        if len(near) >= 3 and t[near[-1]] > t[near[0]]:
            v[k] = (c[near[-1], :2] - c[near[0], :2]) / (t[near[-1]] - t[near[0]])
    speed = np.linalg.norm(v, axis=1)
    walking = ok & (speed > FACING_MIN_SPEED)
    if not walking.any():
        return series_world, 0.0
    # The left hip lies at up × forward of the right one, so the labelled facing is the
    # hip axis turned by −90° about the vertical.
    lat = (hl - hr)[:, :2]
    facing = np.column_stack([lat[:, 1], -lat[:, 0]])
    agrees = np.einsum("ij,ij->i", facing, v) > 0
    to_sensor = sensor_pos[:2] - c[:, :2]
    behind = np.einsum("ij,ij->i", to_sensor, v) < 0
    swap_w = walking & ~agrees & behind
    # Frames that are not walking take the nearest walking frame's decision.
    wi = np.flatnonzero(walking)
    pos_i = np.searchsorted(t[wi], t)
    nxt = wi[np.clip(pos_i, 0, len(wi) - 1)]
    prv = wi[np.clip(pos_i - 1, 0, len(wi) - 1)]
    pick = np.where(np.abs(t[prv] - t) < np.abs(t[nxt] - t), prv, nxt)
    swap = np.where(walking, swap_w, swap_w[pick]) & ok
    if not swap.any():
        return series_world, 0.0
    P2 = P.copy()
    S2 = series_world.states.copy()
    for a, b in pairs:
        P2[swap, a], P2[swap, b] = P[swap, b], P[swap, a]
        S2[swap, a], S2[swap, b] = series_world.states[swap, b], series_world.states[swap, a]
    out = SkeletonSeries(t, P2, S2, js, dict(series_world.meta))
    return out, float(swap.sum() / max(1, ok.sum()))


def _transform(series: SkeletonSeries, T: FloatArray) -> SkeletonSeries:
    P = series.positions @ T[:3, :3].T + T[:3, 3]
    return SkeletonSeries(series.times, P, series.states, series.joint_set, dict(series.meta))


# ---------------------------------------------------------------------------- sensors


def sensor_poses(rec_dir: Path, live_poses: Mapping[str, Any] | None = None
                 ) -> dict[str, dict[str, Any]]:
    """Poses of the recording's sensors: ``{node: {"T_world_sensor", "source", ...}}``.

    The first call writes ``sensors.json`` in the recording folder from ``live_poses``
    (the current calibration, or the poses the nodes report); later calls read it.
    Nodes without a pose are left out (their parts cannot be placed in the world).
    """
    path = rec_dir / "sensors.json"
    saved: dict[str, dict[str, Any]] = {}
    if path.is_file():
        try:
            raw = json.loads(path.read_text())
            saved = raw if isinstance(raw, dict) else {}
        except (OSError, json.JSONDecodeError):
            saved = {}
    changed = False
    for node in part_dirs(rec_dir):
        if node in saved or not live_poses or node not in live_poses:
            continue
        entry = live_poses[node]
        if isinstance(entry, dict):
            T = entry.get("T_world_sensor")
            extra = {k: v for k, v in entry.items() if k != "T_world_sensor"}
        else:
            T, extra = entry, {"source": "node"}
        if T is None:
            continue
        arr = np.asarray(T, dtype=float)
        if arr.shape != (4, 4) or not np.isfinite(arr).all():
            continue
        saved[node] = {"T_world_sensor": arr.tolist(), **extra}
        changed = True
    if changed:
        _write_json(path, saved)
    return saved


@dataclass(frozen=True)
class AnalysisOptions:
    """What to analyse: gait event method, fusion estimator and the sensor subset."""

    method: str = "crossing"
    estimator: str = "weighted"
    sensors: tuple[str, ...] | None = None  # None = every sensor with data

    def key(self) -> str:
        """File-name-safe cache key."""
        sub = "all" if self.sensors is None else "+".join(sorted(self.sensors))
        digest = hashlib.sha1(sub.encode()).hexdigest()[:10]
        return f"v{ANALYSIS_VERSION}-{self.method}-{self.estimator}-{digest}"


def _clock_of(meta: Mapping[str, Any]) -> dict[str, float]:
    clock = meta.get("clock_start") or meta.get("clock") or {}
    try:
        return {"offset_s": float(clock["offset_s"]), "drift": float(clock.get("drift", 0.0)),
                "t_ref": float(clock.get("t_ref", 0.0)),
                "uncertainty_s": float(clock.get("uncertainty_s", 0.0))}
    except (KeyError, TypeError, ValueError):
        return {"offset_s": 0.0, "drift": 0.0, "t_ref": 0.0, "uncertainty_s": math.nan}


def unmirror_in_sensor_frame(series: SkeletonSeries, T_world_sensor: FloatArray
                             ) -> tuple[SkeletonSeries, float]:
    """One sensor's skeleton with its back-facing frames un-mirrored, still in the
    sensor's frame: what the fusion takes with the sensor's pose (reports and fused
    exports alike).

    The fusion weighs each sensor by where it stands (distance, the body side it sees,
    the surface it fits to), so a stream keeps its own frame and pose; world coordinates
    with an identity pose would put every sensor at the world origin.

    Args:
        series: the sensor's skeleton in its own frame.
        T_world_sensor: the sensor's pose (4×4).

    Returns:
        The corrected series (sensor frame) and the fraction of its tracked frames that
        were swapped (:func:`unmirror_back_facing`).
    """
    T = np.asarray(T_world_sensor, dtype=float)
    world, mirrored = unmirror_back_facing(_transform(series, T), T[:3, 3])
    return _transform(world, np.linalg.inv(T)), mirrored


def load_streams(rec_dir: Path, poses: Mapping[str, Mapping[str, Any]]
                 ) -> tuple[list[SensorStream], dict[str, Any]]:
    """Every part of a recording as a world-placed, un-mirrored :class:`SensorStream`.

    Returns:
        The streams (times on the node clocks; the clock correction in each stream maps
        them to seconds since the recording's start) and per-sensor facts for the report.

    Raises:
        InsufficientDataError: no part with skeleton data and a known pose.
    """
    parts = part_dirs(rec_dir)
    if not parts:
        raise InsufficientDataError(f"recording {rec_dir.name} has no sensor data on the "
                                    "server yet; transfer it from the nodes first")
    streams: list[SensorStream] = []
    facts: dict[str, Any] = {}
    for node, d in parts.items():
        meta = read_meta(d)
        pose = poses.get(node)
        if pose is None:
            facts[node] = {"skipped": "no sensor pose (calibrate the rig)"}
            continue
        T = np.asarray(pose["T_world_sensor"], dtype=float)
        try:
            series = read_part(d)
        except InsufficientDataError as exc:
            facts[node] = {"skipped": str(exc)}
            continue
        clk = _clock_of(meta)
        t0 = float(meta.get("t_start_server") or 0.0)
        # Node clock model: t_local = t_server + offset + drift·(t_server − t_ref). With
        # t_rec = t_server − t0 this is the integration's t_local = a + (1 + d)·t_rec.
        a = t0 + clk["offset_s"] + clk["drift"] * (t0 - clk["t_ref"])
        local, mirrored = unmirror_in_sensor_frame(series, T)
        tracked = float(np.mean(series.states == TrackingState.TRACKED) * 100.0)
        streams.append(SensorStream(local, T, a, clk["drift"] * 1e6, node))
        facts[node] = {"frames": len(series), "tracked_pct": tracked,
                       "mirrored_pct": 100.0 * mirrored,
                       "clock_offset_ms": 1e3 * clk["offset_s"],
                       "clock_uncertainty_ms": 1e3 * clk["uncertainty_s"],
                       "pose_source": pose.get("source", "node"),
                       "calibration_version": pose.get("calibration_version"),
                       "calibration_residual_mm": pose.get("residual_mm"),
                       "position": T[:3, 3].tolist()}
    if not streams:
        why = "; ".join(f"{k}: {v['skipped']}" for k, v in facts.items())
        raise InsufficientDataError(f"recording {rec_dir.name}: no usable sensor ({why})")
    return streams, facts


def _placements(ga: GaitAnalysis, feet: FeetTrajectories) -> list[dict[str, Any]]:
    """Foot positions at the step events: x along the walkway (the first pass's
    direction, for every pass), y across each pass's own direction (left positive)."""
    out: list[dict[str, Any]] = []
    axis: np.ndarray | None = None
    for s in ga.steps_:
        wp = ga.passes_[s.pass_index]
        d = np.array(wp.direction, dtype=float)
        lat = np.array([-d[1], d[0]])
        # A pass walked back is measured along the same axis as the first: along its own
        # direction its placements were mirrored and drawn metres beyond the first pass's
        # instead of on the same stretch of floor.
        axis = d if axis is None else axis
        along = d if d @ axis >= 0 else -d
        x = feet.foot(s.side)
        p = np.array([np.interp(s.time_s, feet.times, x[:, k]) for k in range(3)])
        if not np.isfinite(p).all():
            continue
        out.append({"side": s.side, "time_s": s.time_s,
                    "position": [float(p[:2] @ along), float(p[:2] @ lat), float(p[2])]})
    # One common origin so that several passes overlay.
    if out:
        x0 = min(o["position"][0] for o in out)
        for o in out:
            o["position"][0] -= x0
    return out


def _ankles(feet: FeetTrajectories) -> dict[str, Any]:
    step = max(1, math.ceil(len(feet.times) / MAX_PLOT_POINTS))
    sl = slice(None, None, step)

    def clean(a: FloatArray) -> list[float | None]:
        return [None if not math.isfinite(v) else round(float(v), 4) for v in a[sl]]

    return {"times": clean(np.asarray(feet.times)),
            "L": clean(feet.foot("L")[:, 2]), "R": clean(feet.foot("R")[:, 2])}


def analyse_series(series: SkeletonSeries | FeetTrajectories, method: str = "crossing"
                   ) -> dict[str, Any]:
    """Gait analysis of a world-frame skeleton (or feet): gait JSON + plot data."""
    feet = series if isinstance(series, FeetTrajectories) else feet_from_skeleton(series)
    ga = GaitAnalysis(method).fit(feet)  # type: ignore[arg-type]
    return {"gait": ga.to_dict(), "placements": _placements(ga, feet), "ankles": _ankles(feet)}


def analyse_recording(rec_dir: Path, options: AnalysisOptions,
                      live_poses: Mapping[str, Any] | None = None,
                      use_cache: bool = True) -> dict[str, Any]:
    """Analyse a recording on the server (cached).

    Returns:
        ``{"rec_id", "options", "ok", "error", "sensors_available", "sensors_used",
        "sensors", "fusion", "gait", "placements", "ankles"}``; ``ok`` is False with a
        clinician-readable ``error`` when the recording cannot give a gait result (no
        body, too few steps).

    Raises:
        InputError: bad options or unknown sensor ids (the caller's mistake).
        InsufficientDataError: the recording has no data on the server.
    """
    if options.method not in ("crossing", "heelstrike"):
        raise InputError(f"method must be 'crossing' or 'heelstrike', got {options.method!r}")
    if options.estimator not in ("weighted", "mean"):
        raise InputError(f"estimator must be 'weighted' or 'mean', got {options.estimator!r}")
    available = list(part_dirs(rec_dir))
    if options.sensors is not None:
        if not options.sensors:
            raise InputError("choose at least one sensor")
        unknown = sorted(set(options.sensors) - set(available))
        if unknown:
            raise InputError(f"recording {rec_dir.name} has no sensor {', '.join(unknown)}; "
                             f"its sensors are {', '.join(available) or 'none'}")
    poses = sensor_poses(rec_dir, live_poses)
    cache = rec_dir / "analysis" / f"{options.key()}-{_fingerprint(rec_dir)}.json"
    if use_cache and cache.is_file():
        try:
            cached: dict[str, Any] = json.loads(cache.read_text())
            return cached
        except (OSError, json.JSONDecodeError):
            pass
    streams, facts = load_streams(rec_dir, poses)
    ids = [s.sensor_id for s in streams]
    chosen = ids if options.sensors is None else [s for s in ids if s in options.sensors]
    out: dict[str, Any] = {
        "rec_id": rec_dir.name, "version": ANALYSIS_VERSION,
        "options": {"method": options.method, "estimator": options.estimator,
                    "sensors": list(options.sensors) if options.sensors is not None else None},
        "ok": False, "error": None, "sensors_available": available, "sensors_used": chosen,
        "sensors": {k: v for k, v in facts.items() if options.sensors is None
                    or k in options.sensors},
        "fusion": None, "gait": None, "placements": [], "ankles": None,
    }
    try:
        if not chosen:
            raise InsufficientDataError("none of the chosen sensors has usable data: "
                                        + "; ".join(f"{k}: {facts[k].get('skipped')}"
                                                    for k in options.sensors or []))
        fused, report = integrate_skeletons(streams, options.estimator,  # type: ignore[arg-type]
                                            sensors=chosen)
        rep = report.to_dict()
        out["fusion"] = {
            "estimator": rep["estimator"], "rate_hz": rep["rate_hz"],
            "cutoff_hz": rep["cutoff_hz"], "tracked_pct": rep["tracked_pct"],
            "filled_pct": rep["filled_pct"], "gaps_filled": len(rep["gaps_filled"]),
            "gaps_unfilled": len(rep["gaps_unfilled"]),
            "sensors_contributing": rep["sensors_contributing"],
            "sensors_per_sample": rep["sensors_per_sample"],
            "duration_s": float(fused.times[-1] - fused.times[0]),
        }
        out.update(analyse_series(fused, options.method))
        out["ok"] = True
    except InsufficientDataError as exc:
        out["error"] = _too_short(streams, str(exc))
    except InputError as exc:
        # E.g. no tracked ankles at all: the recording has no usable body.
        out["error"] = _too_short(streams, f"no usable body in the recording: {exc}")
    except GaitrigError as exc:  # any other typed engine failure
        out["error"] = f"the gait analysis cannot use this recording: {exc}"
    except (ArithmeticError, ValueError, IndexError, np.linalg.LinAlgError) as exc:
        # An engine defect on unusual data (e.g. a walk too short for a filter window):
        # the clinician gets a clear message instead of a server error; the trace is
        # logged and the result is not cached, so a fixed engine retries.
        _log.exception("gait analysis of recording %s failed", rec_dir.name)
        out["error"] = (f"the gait analysis failed on recording {rec_dir.name} "
                        f"({type(exc).__name__}: {exc}); record a longer, straight walk, "
                        "and report the recording id if it persists")
        return out
    cache.parent.mkdir(exist_ok=True)
    _write_json(cache, out)
    return out


# ---------------------------------------------------------------------------- reports


def _lower_body_tracked(fusion: Mapping[str, Any]) -> float | None:
    tp = fusion.get("tracked_pct") or {}
    vals = [float(v) for k, v in tp.items()
            if any(w in k for w in ("Ankle", "Knee", "Hip", "Foot", "SpineBase"))]
    vals = vals or [float(v) for v in tp.values()]
    return float(np.mean(vals)) if vals else None


def quality_from_analyses(analyses: list[dict[str, Any]],
                          trial_labels: Mapping[str, str] | None = None) -> QualityInfo:
    """The report's data-quality facts from recording analyses (a note names a recording
    by its trial label in ``trial_labels``, rec_id → label: :func:`recording_named`)."""
    q = QualityInfo(recordings=len(analyses))
    tracked: list[float] = []
    versions: dict[str, None] = {}  # ordered set
    # None when nothing was fused (mocap files): no sensor or fused skeleton had gaps to
    # fill, so the report does not claim "0 gaps ... (each sensor and the fused skeleton)"
    gaps: int | None = None
    for a in analyses:
        mirrored: list[str] = []
        named = recording_named(str(a["rec_id"]), (trial_labels or {}).get(str(a["rec_id"]), ""))
        for node, f in (a.get("sensors") or {}).items():
            if "skipped" in f:
                q.notes.append(f"{named}: sensor {node} not used — "
                               f"{f['skipped']}.")
                continue
            if node not in q.sensors_used:
                q.sensors_used.append(node)
            # Offsets, residuals and calibrations differ between recordings: all are kept
            # (the table showed the last recording's alone, unlabelled).
            off = float(f.get("clock_offset_ms") or 0.0)
            lo, hi = q.clock_offset_range_ms.get(node, (off, off))
            q.clock_offset_range_ms[node] = (min(lo, off), max(hi, off))
            q.clock_offsets_ms[node] = off
            unc = f.get("clock_uncertainty_ms")
            if unc is not None and math.isfinite(float(unc)):
                q.clock_uncertainty_ms[node] = max(float(unc),
                                                   q.clock_uncertainty_ms.get(node, 0.0))
            res = f.get("calibration_residual_mm")
            if res is not None:
                q.calibration_residuals_mm[node] = max(
                    float(res), q.calibration_residuals_mm.get(node, float(res)))
            if f.get("calibration_version"):
                versions.setdefault(str(f["calibration_version"]), None)
            if float(f.get("mirrored_pct") or 0.0) > 0.5:
                mirrored.append(f"{node} ({f['mirrored_pct']:.0f} %)")
        if mirrored:
            # One line per recording: six sensors used to give six near-identical notes.
            q.notes.append(f"{named}: left/right labels were corrected from "
                           "the walking direction where a sensor saw the subject from behind "
                           f"(share of its frames: {', '.join(mirrored)}).")
        # how the feet were measured, where it needs saying (a population ankle width)
        for note in ((a.get("gait") or {}).get("summary") or {}).get("notes") or []:
            q.notes.append(f"{named}: {note}")
        opts = a.get("options") or {}
        if opts.get("sensors") is not None:
            avail = a.get("sensors_available") or []
            q.notes.append(f"{named} was analysed with a subset of its sensors "
                           f"({', '.join(a.get('sensors_used') or [])} of {', '.join(avail)}); "
                           "sensors on one side of the walkway see the far leg through the "
                           "body, so its step width and length are less accurate.")
        fus = a.get("fusion") or {}
        lb = _lower_body_tracked(fus)
        if lb is not None:
            tracked.append(lb)
        if fus:
            gaps = (gaps or 0) + int(fus.get("gaps_filled") or 0)
        if not versions and any(
                (f.get("pose_source") == "node") for f in (a.get("sensors") or {}).values()):
            note = ("Sensor poses are those reported by the nodes (no rig calibration "
                    "was stored with the recording).")
            if note not in q.notes:
                q.notes.append(note)
    q.calibration_version = ", ".join(versions) or None
    q.joints_tracked_pct = float(np.mean(tracked)) if tracked else None
    q.gaps_filled = gaps
    return q


def trial_from_analysis(a: Mapping[str, Any], name: str | None = None,
                        with_sensors: bool = True) -> TrialData:
    """A report trial from an analysis result (:func:`analyse_recording`/`analyse_file`).

    ``with_sensors`` appends the sensors used to the trial's name (when trials differ).
    """
    ank = a.get("ankles") or {}
    times = heights = None
    if ank.get("times"):
        times = np.array([np.nan if v is None else v for v in ank["times"]], dtype=float)
        heights = {s: np.array([np.nan if v is None else v for v in ank[s]], dtype=float)
                   for s in ("L", "R")}
    used = a.get("sensors_used")
    label = name or str(a.get("rec_id", "trial"))
    if used and with_sensors:
        label += f" ({', '.join(used)})"
    return TrialData(label, a["gait"], a.get("placements") or None, times, heights)


def agreement_rows(measured: list[dict[str, Any]], reference: list[dict[str, Any]],
                   max_dt_s: float = 0.25) -> tuple[list[AgreementRow], list[tuple[str, bytes]]]:
    """Step-level agreement of measured with reference steps, and Bland–Altman plots.

    Args:
        measured: gait JSON steps of the recording (times since the recording's start).
        reference: gait JSON steps of the reference system on the same time axis.
    """
    from types import SimpleNamespace

    from engine.agreement import agreement, bland_altman_png, match_steps

    m = [SimpleNamespace(**s) for s in measured]
    r = [SimpleNamespace(**s) for s in reference]
    pairs = match_steps(m, r, max_dt_s)
    rows: list[AgreementRow] = []
    figs: list[tuple[str, bytes]] = []
    # Step time in ms: its bias and limits are a few ms, which the table's two decimals
    # of seconds showed as "0.00" and "-0.00".
    for attr, label, unit, scale in (("length_m", "Step length", "cm", 100.0),
                                     ("width_m", "Step width", "cm", 100.0),
                                     ("duration_s", "Step time", "ms", 1000.0)):
        for side in ("L", "R", "L+R"):
            pp = [p for p in pairs if side == "L+R" or p[0].side == side]
            a = np.array([getattr(x, attr) for x, _ in pp], dtype=float) * scale
            b = np.array([getattr(y, attr) for _, y in pp], dtype=float) * scale
            ok = np.isfinite(a) & np.isfinite(b)
            a, b = a[ok], b[ok]
            if len(a) < 3:
                continue
            ag = agreement(a, b)
            rows.append(AgreementRow(label, "single steps " + side, ag.n, ag.r, ag.p, ag.bias,
                                     ag.rpc, ag.cv_pct, ag.icc_a1, unit))
            if side == "L+R":
                figs.append((f"Bland–Altman: {label.lower()} (single steps, both sides)",
                             bland_altman_png(a, b, f"{label} vs reference", unit)))
    return rows, figs


def trial_names(labels: Mapping[str, str]) -> dict[str, str]:
    """The name a report gives each recording: its trial label ("walk 3") where that
    label is the recording's alone in the report, label and id where labels repeat, the
    id where there is no label.

    Args:
        labels: rec_id → the trial label given when recording ("" for none).

    Returns:
        rec_id → name.
    """
    counts = Counter(v.strip() for v in labels.values() if v.strip())
    out = {}
    for rec_id, label in labels.items():
        label = label.strip()
        out[rec_id] = (rec_id if not label else label if counts[label] == 1
                       else f"{label} ({rec_id})")
    return out


#: A recording's state as a report's note says it (the console's words for it).
STATE_WORDS = {"pending": "starting", "recording": "still recording", "stopping": "stopping",
               "on_nodes": "still on the sensors", "on_node": "still on the sensor",
               "transferring": "being copied to the server", "incomplete": "incomplete"}


def recording_named(rec_id: str, label: str = "", state: str = "") -> str:
    """How a report's note names a recording: by the trial label the clinician gave it,
    with the recording id beside (``Trial “walk 3” (recording <id>)``), or by its id
    alone where there is no label (``Recording <id>``).

    Args:
        state: the recording's state (``on_nodes``…), said in words beside the id.
    """
    label = " ".join(label.split())
    state = STATE_WORDS.get(state, state)
    beside = f", {state}" if state else ""
    return (f"Trial “{label}” (recording {rec_id}{beside})" if label
            else f"Recording {rec_id}" + (f" ({state})" if state else ""))


def build_report(subject_code: str, analyses: list[dict[str, Any]], *,
                 title: str = "Gait report", subject_info: dict[str, Any] | None = None,
                 session_label: str = "", session_date: str = "",
                 references: Mapping[str, list[dict[str, Any]]] | None = None,
                 trial_labels: Mapping[str, str] | None = None) -> ReportData:
    """A :class:`ReportData` from analysed recordings (failed analyses become notes).

    Args:
        references: rec_id → reference gait JSON steps (agreement section).
        trial_labels: rec_id → the trial's label (:func:`trial_names` names the trials;
            without it, trials are named by recording id).

    Raises:
        InsufficientDataError: no analysis with a gait result.
    """
    good = [a for a in analyses if a.get("ok")]
    if not good:
        why = "; ".join(f"{a.get('rec_id')}: {a.get('error')}" for a in analyses)
        raise InsufficientDataError("no recording gave a gait result"
                                    + (f" ({why})" if why else ""))
    q = quality_from_analyses(good, trial_labels)
    for a in analyses:
        if not a.get("ok"):
            rec_id = str(a.get("rec_id"))
            q.notes.append(f"{recording_named(rec_id, (trial_labels or {}).get(rec_id, ''))} "
                           f"was not used: {a.get('error')}")
    rows: list[AgreementRow] = []
    figs: list[tuple[str, bytes]] = []
    meas_all: list[dict[str, Any]] = []
    ref_all: list[dict[str, Any]] = []
    with_ref: list[str] = []
    names = trial_names({str(a.get("rec_id")): (trial_labels or {}).get(str(a.get("rec_id")), "")
                         for a in good})
    for k, a in enumerate(good):
        ref = (references or {}).get(str(a.get("rec_id")))
        if ref:
            with_ref.append(str(a.get("rec_id")))
            # Trials are kept apart in time so that steps of two trials never pair.
            shift = 1e5 * k
            meas_all += [{**s, "time_s": s["time_s"] + shift} for s in a["gait"]["steps"]]
            ref_all += [{**s, "time_s": s["time_s"] + shift} for s in ref]
    basis = ""
    if ref_all:
        rows, figs = agreement_rows(meas_all, ref_all)
        # A subject report may hold one referenced trial among many: say which.
        n_pairs = max((r.n for r in rows), default=0)
        # named as the Per trial table names them (the clinician's labels, not ids)
        basis = (f"Steps of {'trial' if len(with_ref) == 1 else 'trials'} "
                 f"{', '.join(names[r] for r in with_ref)} ({len(with_ref)} of {len(good)} "
                 "trials) paired with "
                 f"the steps of the attached reference within 0.25 s: {n_pairs} pairs.")
        if not rows:
            q.notes.append("A reference recording is attached but fewer than three steps "
                           "matched it in time (within 0.25 s): check that both start "
                           "together.")
    # The sensors go into the trial names only when trials differ in them; otherwise the
    # data-quality section lists them once (ten trials repeated "(S1, …, S6)" ten times).
    same = len({tuple(a.get("sensors_used") or ()) for a in good}) == 1
    trials = []
    for a in good:
        rec_id = str(a.get("rec_id"))
        trial = trial_from_analysis(a, name=names[rec_id], with_sensors=not same)
        if names[rec_id] != rec_id and rec_id not in names[rec_id]:
            trial.source = rec_id
        trials.append(trial)
    return ReportData(subject_code, trials, title=title,
                      subject_info=subject_info or {}, session_label=session_label,
                      session_date=session_date, quality=q, agreement=rows,
                      agreement_figures=figs, agreement_basis=basis)


def analyse_file(path: Path, method: str = "crossing", left: str | None = None,
                 right: str | None = None, up: str | None = None,
                 units: str | None = None, ankle_markers: str = "auto",
                 ankle_width_m: float | tuple[float, ...] | None = None, *,
                 data: MarkerTrajectories | SkeletonSeries | None = None) -> dict[str, Any]:
    """Analyse a C3D/TRC/CSV file as a report trial (``ok`` always True; errors raise).

    ``left``, ``right``, ``up``, ``units``, ``ankle_markers`` and ``ankle_width_m`` are
    :func:`engine.mocap.load_feet`'s (None, ``"auto"``: detected from the file). ``data``
    is the file's content when it was read already (``app.server.storage.parse_reference``):
    then ``path`` only names the file and is not read again.

    Raises:
        GaitrigError: unreadable file, no usable ankle/heel data, too few steps.
    """
    from engine.mocap import feet_from_file_data, load_feet

    try:
        if data is None:
            feet = load_feet(path, left=left, right=right, up=up, units=units,
                             ankle_markers=ankle_markers, ankle_width_m=ankle_width_m)
        else:
            feet = feet_from_file_data(data, left=left, right=right, up=up, units=units,
                                       ankle_markers=ankle_markers,
                                       ankle_width_m=ankle_width_m)
    except GaitrigError:
        raise
    except (OSError, ValueError, KeyError, IndexError) as exc:  # a malformed file
        raise InputError(f"cannot read {path.name}: {exc}") from exc
    res = analyse_series(feet, method)
    return {"rec_id": path.name, "ok": True, "error": None, "sensors": {}, "fusion": None,
            **res}


def study_trial(measured: Mapping[str, Any], reference: Mapping[str, Any],
                offset_s: float = 0.0, name: str = "") -> StudyTrial:
    """A :class:`engine.agreement.StudyTrial` from two gait JSON documents of one walk
    (``steps``, ``strides``, ``summary``), the reference's times moved by ``offset_s``
    onto the measured one's (added, as a recording's reference offset)."""
    from types import SimpleNamespace

    from engine.agreement import StudyTrial

    def items(gait: Mapping[str, Any], key: str, shift: float) -> list[Any]:
        return [SimpleNamespace(**{**s, "time_s": s["time_s"] + shift}) for s in gait[key]]

    def speed(gait: Mapping[str, Any]) -> float:
        v = (gait.get("summary") or {}).get("walking_speed_m_s")
        return float("nan") if v is None else float(v)

    return StudyTrial(items(measured, "steps", 0.0), items(reference, "steps", offset_s),
                      items(measured, "strides", 0.0), items(reference, "strides", offset_s),
                      speed(measured), speed(reference), name)


def reference_steps(path: Path, method: str = "crossing", *,
                    data: MarkerTrajectories | SkeletonSeries | None = None
                    ) -> list[dict[str, Any]]:
    """Steps of a reference file (C3D/TRC/CSV), for the agreement section; ``data`` is
    its content when read already (:func:`analyse_file`'s: ``path`` is not read again).

    Raises:
        GaitrigError: :func:`analyse_file`'s, unchanged (a reader's names the file; a
            "reference <file>: " before it named the file twice: callers name it,
            ``app.api.routes._data.refusal``).
    """
    if data is not None:
        steps: list[dict[str, Any]] = analyse_file(path, method, data=data)["gait"]["steps"]
        return steps
    return list(reference_gait(path, method)["steps"])


@functools.lru_cache(maxsize=512)
def _file_gait(path: str, size: int, mtime_ns: int, method: str) -> dict[str, Any]:
    # keyed by the file's size and modification time: a file replaced is analysed anew
    gait: dict[str, Any] = analyse_file(Path(path), method)["gait"]
    return gait


def reference_gait(path: Path, method: str = "crossing") -> dict[str, Any]:
    """The gait JSON (``steps``, ``strides``, ``summary``…) of a stored reference file,
    analysed once per version of the file and method in this process: a project's
    agreement study reads every reference of the project at each request (its HTML, PDF
    and CSV are three requests), and the reports of a subject read theirs again.

    Raises:
        GaitrigError: :func:`analyse_file`'s (a failure is not kept: it is tried again),
            and for a file gone since it was listed.
    """
    try:
        st = path.stat()
    except OSError as exc:
        raise InputError(f"cannot read {path.name}: {exc.strerror or exc}") from exc
    return copy.deepcopy(_file_gait(str(path), st.st_size, st.st_mtime_ns, method))


def subset_label(sensors: Collection[str] | None) -> str:
    """Human label of a sensor subset."""
    return "all sensors" if sensors is None else ", ".join(sorted(sensors))
