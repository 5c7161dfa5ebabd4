"""Calibration lifecycle on the server: versioned files under ``<data_dir>/calibrations``.

The latest version is the active calibration; restoring an older one saves it again as a
new version (history is never rewritten).

Live capture (:class:`CaptureManager`): the wizard asks every connected node for N colour
+ depth frames over the node protocol (``calib_capture``), runs detection → 3D corners →
graph → chaining → joint optimisation → ICP on them, and keeps the result until the user
accepts (saved as the new active version, applied to the nodes) or rejects it. The same
capture with a few frames re-detects the markers for the bumped-tripod check, on demand
or periodically (:meth:`CaptureManager.run_periodic`, started by the calibration router's
lifespan): only while a calibration is active, all its sensors are connected and no
recording is running or transferring (a check must never take node CPU from a recording).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from app.nodes.protocol import (
    CalibrationCapture,
    calib_distortion,
    decode_calib_frame,
    dump,
)
from engine.calibration.corners3d import SensorFrames
from engine.calibration.pipeline import CalibrationResult
from engine.calibration.store import (
    check_moved,
    list_versions,
    load_version,
    result_to_dict,
    save_version,
)
from engine.errors import CalibrationError, GaitrigError, InputError
from engine.pointcloud import CameraIntrinsics
from engine.wording import named

log = logging.getLogger("gaitrig.calibration")


def calibration_dir(data_dir: Path) -> Path:
    """Folder of the saved calibrations."""
    return Path(data_dir) / "calibrations"


def summary(res: CalibrationResult) -> dict[str, Any]:
    """One row of the calibration list."""
    worst = [v for v in res.sensor_residual_m.values() if math.isfinite(v)]
    return {
        "version": res.version, "created": res.created, "sensors": res.sensor_ids,
        "markers": sorted(res.T_world_marker),
        "max_sensor_residual_mm": round(max(worst) * 1000, 2) if worst else None,
        "rejected": len(res.rejected),
    }


def list_calibrations(data_dir: Path) -> list[dict[str, Any]]:
    """Summaries of all versions, newest first."""
    folder = calibration_dir(data_dir)
    return [summary(load_version(folder, v)) for v in reversed(list_versions(folder))]


def get_calibration(data_dir: Path, version: int | None = None) -> dict[str, Any]:
    """Full JSON of one version (default: the active, i.e. latest)."""
    return result_to_dict(load_version(calibration_dir(data_dir), version))


def _ids_spec(ids: Sequence[int]) -> str:
    """``[1, 2, 3, 5]`` → ``"1-3,5"`` (the form the wizard's id field takes)."""
    out: list[str] = []
    for _, run in itertools.groupby(enumerate(sorted(ids)), key=lambda kv: kv[1] - kv[0]):
        vals = [v for _, v in run]
        out.append(str(vals[0]) if len(vals) == 1 else f"{vals[0]}-{vals[-1]}")
    return ",".join(out)


def _most_common(sizes: Sequence[float]) -> float:
    """The size most markers have."""
    return max(set(sizes), key=list(sizes).count)


def suggested_markers(data_dir: Path, backends: Sequence[str]) -> dict[str, Any]:
    """What the capture form should start with: the active calibration's markers; for a
    rig of simulated sensors only (``backends`` of the connected nodes), the simulated
    room's; else the printed sheet's defaults (1-8, 20 cm)."""
    folder = calibration_dir(data_dir)
    if list_versions(folder):
        res = load_version(folder)
        if res.marker_sizes:
            return {"marker_ids": _ids_spec(list(res.marker_sizes)),
                    "marker_size_m": _most_common(list(res.marker_sizes.values())),
                    "source": f"calibration {res.version}"}
    if backends and all(b == "sim" for b in backends):
        from engine.sim.rig import default_avenue_rig

        markers = default_avenue_rig(None).markers
        return {"marker_ids": _ids_spec([m.id for m in markers]),
                "marker_size_m": _most_common([m.size_m for m in markers]),
                "source": "the simulated demo room"}
    return {"marker_ids": "1-8", "marker_size_m": 0.20, "source": "the printed sheet's default"}


def save(data_dir: Path, res: CalibrationResult) -> int:
    """Save a new calibration; returns its version."""
    return save_version(res, calibration_dir(data_dir))


def restore(data_dir: Path, version: int) -> int:
    """Make an older version active again by saving it as the newest version."""
    folder = calibration_dir(data_dir)
    res = load_version(folder, version)
    res.meta = {**res.meta, "restored_from": version}
    return save_version(res, folder)


def check_pose_change(data_dir: Path, poses: dict[str, Any]) -> list[dict[str, Any]]:
    """Bumped-tripod check of fresh sensor poses against the active calibration.

    Raises:
        InputError: poses that are not 4×4 matrices.
    """
    new = {}
    for s, T in poses.items():
        a = np.asarray(T, dtype=float)
        if a.shape != (4, 4) or not np.isfinite(a).all():
            raise InputError(f"pose of {s!r} must be a 4×4 matrix of numbers")
        new[str(s)] = a
    return check_moved(load_version(calibration_dir(data_dir)), new)


def simulate_and_save(data_dir: Path, seed: int, frames: int) -> dict[str, Any]:
    """Run the calibration on the simulated avenue, save it, return it with true errors."""
    from engine.calibration.pipeline import calibrate_frames
    from engine.calibration.simcapture import pose_errors, simulate_capture
    from engine.sim.rig import default_avenue_rig

    rig = default_avenue_rig(seed)
    res = calibrate_frames(simulate_capture(rig, frames, seed),
                           {m.id: m.size_m for m in rig.markers})
    res.meta["source"] = f"simulation (seed {seed}, {frames} frames)"
    version = save(data_dir, res)
    doc = result_to_dict(res)
    doc["version"] = version
    doc["true_errors"] = pose_errors(res, rig)
    return doc


def active_poses(data_dir: Path) -> dict[str, dict[str, Any]]:
    """Sensor poses of the active calibration, in the form the analysis uses
    (``{node: {"T_world_sensor", "source", "calibration_version", "residual_mm"}}``);
    empty when nothing is calibrated."""
    folder = calibration_dir(data_dir)
    if not list_versions(folder):
        return {}
    res = load_version(folder)
    out: dict[str, dict[str, Any]] = {}
    for s, T in res.T_world_sensor.items():
        r = res.sensor_residual_m.get(s, float("nan"))
        out[s] = {"T_world_sensor": np.asarray(T).tolist(), "source": "calibration",
                  "calibration_version": str(res.version),
                  "residual_mm": round(r * 1000, 3) if math.isfinite(r) else None}
    return out


def _set_pose(session: Any, T: list[list[float]]) -> None:
    session.sensor = session.sensor.model_copy(update={"T_world_sensor": T})


def apply_to_registry(registry: Any, data_dir: Path) -> list[str]:
    """Give every known node the active calibration's pose (replacing the pose the node
    reported; a node it leaves out gets its reported pose back), keep doing so for nodes
    that (re)connect later, and let the node listeners (3D view, live cloud's lenses,
    planner) redraw every node at once: a restored or accepted version changes the poses
    and the camera models of nodes that are not in it too.

    Returns:
        Ids of the nodes that got a calibrated pose now.
    """
    poses = active_poses(data_dir)
    applied = []
    for node_id, s in registry.nodes.items():
        if node_id in poses:
            _set_pose(s, poses[node_id]["T_world_sensor"])
            applied.append(node_id)
        elif s.sensor.T_world_sensor != s.reported_pose:
            _set_pose(s, s.reported_pose)  # an older version's pose would pass for the node's
    listeners = registry.listeners
    if not any(getattr(cb, "_gaitrig_calibration", False) for cb in listeners):
        def on_connect(session: Any) -> None:
            p = active_poses(data_dir).get(session.id)
            if p is not None:
                _set_pose(session, p["T_world_sensor"])
        on_connect._gaitrig_calibration = True  # type: ignore[attr-defined]
        # first, so the 3D view and planner listeners after it see the calibrated pose
        listeners.insert(0, on_connect)
    for s in list(registry.nodes.values()):
        for cb in list(listeners):
            if getattr(cb, "_gaitrig_calibration", False):
                continue
            try:
                cb(s)
            except Exception:  # a display must never break applying a calibration
                log.exception("a node listener failed after applying the calibration")
    return sorted(applied)


def active_result(data_dir: Path) -> CalibrationResult | None:
    """The active calibration, or None when nothing is calibrated (or it is unreadable)."""
    folder = calibration_dir(data_dir)
    try:
        return load_version(folder) if list_versions(folder) else None
    except InputError:
        log.warning("the active calibration in %s cannot be read", folder)
        return None


# --------------------------------------------------------------------------- live capture

#: Jobs kept for the wizard (older ones are forgotten).
MAX_JOBS = 8
#: Seconds a node may take for its first frame (a simulated node first ray-casts the room
#: at the capture size) and between two frames before its capture counts as failed.
FIRST_FRAME_TIMEOUT_S = 120.0
STALL_TIMEOUT_S = 30.0
#: Frames per node of the periodic bumped-tripod check (few: it competes with nothing,
#: but it should be over quickly).
PERIODIC_FRAMES = 5


@dataclass
class CaptureJob:
    """A capture from the connected nodes and what was computed from it.

    ``kind`` is ``"calibrate"`` (the wizard: detection → 3D corners → graph → pose graph →
    ICP; the result waits for the user's accept/reject) or ``"check"`` (bumped-tripod
    check against the active calibration). ``state``: capturing → computing → done |
    failed (``message`` says why) | accepted | rejected.
    """

    id: int
    kind: str
    nodes: list[str]
    frames: int
    marker_sizes: dict[int, float]
    created: float = field(default_factory=time.time)
    state: str = "capturing"
    message: str = ""
    unreachable: list[str] = field(default_factory=list)
    received: dict[str, int] = field(default_factory=dict)
    errors: dict[str, str] = field(default_factory=dict)
    raw: dict[str, list[tuple[dict[str, Any], bytes]]] = field(default_factory=dict)
    result: CalibrationResult | None = None
    doc: dict[str, Any] | None = None
    checks: list[dict[str, Any]] = field(default_factory=list)
    version: int | None = None
    trigger: str = "manual"
    calibration_version: int | None = None
    calibration_created: float | None = None
    done: asyncio.Event = field(default_factory=asyncio.Event)
    task: asyncio.Task[None] | None = field(default=None, repr=False)

    def node_finished(self, node: str) -> bool:
        return node in self.errors or self.received.get(node, 0) >= self.frames

    def to_dict(self) -> dict[str, Any]:
        """Progress and outcome for the console."""
        d: dict[str, Any] = {
            "id": self.id, "kind": self.kind, "state": self.state, "message": self.message,
            "frames": self.frames, "created": self.created, "nodes": {
                n: {"received": self.received.get(n, 0), "error": self.errors.get(n)}
                for n in self.nodes},
            "marker_sizes_m": {str(k): v for k, v in self.marker_sizes.items()},
        }
        if self.unreachable:
            d["unreachable"] = self.unreachable
        if self.doc is not None:
            d["result"] = self.doc
        if self.kind == "check":
            d["checks"] = self.checks
            d["moved"] = [c["sensor"] for c in self.checks if c["status"] == "moved"]
            d["trigger"] = self.trigger
            d["calibration"] = {"version": self.calibration_version,
                                "created": self.calibration_created}
        if self.version is not None:
            d["version"] = self.version
        return d


class CaptureManager:
    """Runs captures over the node protocol (``calib_capture`` → binary ``calib`` frames).

    One capture at a time. Frames are collected per job, decoded and processed in a
    worker thread; the calibration result is kept unsaved until accepted.

    Args:
        hub: The node hub (sessions and the binary-message hook).
        data_dir: Server data folder (calibrations).
    """

    def __init__(self, hub: Any, data_dir: Path) -> None:
        self.hub = hub
        self.data_dir = Path(data_dir)
        self.jobs: dict[int, CaptureJob] = {}
        self.last_check: CaptureJob | None = None
        self._ids = itertools.count(1)
        self._tasks: set[asyncio.Task[None]] = set()
        #: State of the periodic check (see :meth:`run_periodic`), for the console.
        self.periodic: dict[str, Any] = {"enabled": False, "interval_s": 0.0,
                                         "state": "off", "reason": "", "at": None}
        self._moved: dict[str, dict[str, Any]] = {}
        hub.binary_listeners["calib"] = self.on_binary

    def busy(self) -> CaptureJob | None:
        """The job still capturing or computing, if any."""
        return next((j for j in self.jobs.values() if j.state in ("capturing", "computing")),
                    None)

    async def start(self, kind: str, frames: int, marker_sizes: Mapping[int, float] | None,
                    nodes: Sequence[str] | None = None, trigger: str = "manual") -> CaptureJob:
        """Ask every (or the given) connected node for ``frames`` frames and process them.

        Args:
            kind: ``"calibrate"`` or ``"check"``.
            frames: Frames per node.
            marker_sizes: Marker id → edge length (m); for a check, None = the active
                calibration's markers.
            nodes: Node ids (default: every connected node).
            trigger: ``"manual"`` (a person asked) or ``"periodic"``.

        Raises:
            InputError: no connected node, an unknown/offline node, no active calibration
                for a check.
            CaptureBusyError: another capture is still running.
        """
        running = self.busy()
        if running is not None:
            raise CaptureBusyError(f"capture {running.id} is still {running.state}; wait for "
                                   "it to finish")
        sessions = self.hub.registry.nodes
        online = sorted(n for n, s in sessions.items() if s.connected and s.send is not None)
        want = sorted(set(nodes)) if nodes else online
        if not want:
            raise InputError("no sensor node is connected: start the nodes (Rig page) and "
                             "capture again")
        off = [n for n in want if n not in online]
        if off:
            raise InputError(f"{named('node', off, 'is', 'are')} not connected")
        if kind == "check":
            folder = calibration_dir(self.data_dir)
            if not list_versions(folder):
                raise InputError("no calibration yet: calibrate the rig first (calibration "
                                 "wizard), then the live check compares against it")
            active = load_version(folder)
            sizes = dict(active.marker_sizes)
        else:
            if not marker_sizes:
                raise InputError("give the marker ids and edge length to calibrate with")
            sizes = {int(k): float(v) for k, v in marker_sizes.items()}
        job = CaptureJob(next(self._ids), kind, want, frames, sizes,
                         received={n: 0 for n in want}, raw={n: [] for n in want},
                         trigger=trigger)
        if kind == "check":
            job.calibration_version, job.calibration_created = active.version, active.created
        self.jobs[job.id] = job
        for old in sorted(self.jobs)[:-MAX_JOBS]:
            del self.jobs[old]
        for n in want:
            send = sessions[n].send
            try:
                await send(dump(CalibrationCapture(req_id=job.id, frames=frames)))
            except Exception as exc:  # the socket closed between the check and the send
                job.errors[n] = f"could not reach {n}: {exc}"
        task = asyncio.create_task(self._run(job))
        job.task = task
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return job

    # ------------------------------------------------------------------ periodic check

    def periodic_blocker(self) -> tuple[str | None, list[str]]:
        """Why the periodic check must not run now (None: go), and the nodes to check.

        It runs only with an active calibration, all of its sensors connected, no capture
        in progress and no recording running, stopping or transferring.
        """
        folder = calibration_dir(self.data_dir)
        if not list_versions(folder):
            return "no calibration yet", []
        try:
            active = load_version(folder)
        except InputError as exc:
            return f"the active calibration cannot be read: {exc}", []
        want = sorted(active.T_world_sensor)
        sessions = self.hub.registry.nodes
        off = [n for n in want if (s := sessions.get(n)) is None or not s.connected
               or s.send is None]
        if off:
            return f"{named('sensor', off)} of the calibration not connected", want
        running = self.busy()
        if running is not None:
            return f"capture {running.id} in progress", want
        recs = getattr(self.hub, "recordings", None)
        transfers = getattr(self.hub, "transfers", None)
        for rec in (recs.recordings.values() if recs is not None else ()):
            state = rec.state
            if state in ("recording", "stopping", "transferring") or (
                    transfers is not None and transfers.running_parts(rec.id)):
                return f"recording {rec.id} is {state} (checks wait for it to finish)", want
        return None, want

    def _set_periodic(self, state: str, reason: str, **extra: Any) -> None:
        if (state, reason) != (self.periodic.get("state"), self.periodic.get("reason")):
            log.info("periodic calibration check: %s%s", state, f" ({reason})" if reason else "")
        self.periodic = {**self.periodic, "state": state, "reason": reason, "at": time.time(),
                         "job": None, **extra}

    async def periodic_check(self, frames: int = PERIODIC_FRAMES) -> CaptureJob | None:
        """One periodic bumped-tripod check, when nothing forbids it (see
        :meth:`periodic_blocker`); the outcome is in :attr:`periodic` and, when it ran,
        :attr:`last_check`. Never raises for a missing node or markers."""
        reason, nodes = self.periodic_blocker()
        if reason is not None:
            self._set_periodic("skipped", reason)
            return None
        try:
            job = await self.start("check", frames, None, nodes, trigger="periodic")
        except GaitrigError as exc:  # a node left between the test and the start
            self._set_periodic("skipped", str(exc))
            return None
        self._set_periodic("running", "", job=job.id)
        if job.task is not None:
            await asyncio.wait({job.task})  # not cancelled with us: the capture finishes
        if job.state != "done":
            self._set_periodic("failed", job.message or f"check ended {job.state}", job=job.id)
            return job
        unknown = [f"{c['sensor']}: {c['reason']}" for c in job.checks
                   if c["status"] == "unknown"]
        moved = [c["sensor"] for c in job.checks if c["status"] == "moved"]
        self._set_periodic("moved" if moved else "incomplete" if unknown else "ok",
                           "; ".join(unknown), job=job.id)
        return job

    async def run_periodic(self, interval_s: float, frames: int = PERIODIC_FRAMES) -> None:
        """Check every ``interval_s`` seconds until cancelled (the app lifespan)."""
        self.periodic = {**self.periodic, "enabled": True, "interval_s": interval_s}
        self._set_periodic("waiting", "")
        while True:
            await asyncio.sleep(interval_s)
            try:
                await self.periodic_check(frames)
            except asyncio.CancelledError:
                raise
            except Exception as exc:  # never take the server down; log once per new cause
                if self.periodic.get("reason") != f"internal error: {exc}":
                    log.exception("periodic calibration check failed")
                self._set_periodic("failed", f"internal error: {exc}")

    def live_check_view(self) -> dict[str, Any]:
        """What the console shows about the bumped-tripod check (one source for the
        Calibrate, Rig and Record pages).

        ``warnings`` lists every sensor found moved against the *active* calibration and
        not found back in place since — a later check that cannot see the markers (someone
        standing on them) does not clear it. A check against an older calibration is
        reported as superseded, not as the latest result.
        """
        folder = calibration_dir(self.data_dir)
        versions = list_versions(folder)
        active_v = versions[-1] if versions else None
        job = self.last_check
        d: dict[str, Any]
        if job is None:
            d = {"checked": False, "moved": [], "checks": []}
        elif job.calibration_version != active_v:
            d = {"checked": False, "moved": [], "checks": [],
                 "superseded": {"id": job.id, "calibration_version": job.calibration_version}}
        else:
            d = {"checked": True, **job.to_dict()}
        d["warnings"] = [w for _, w in sorted(self._moved.items())
                         if w["calibration_version"] == active_v]
        d["periodic"] = dict(self.periodic)
        return d

    def _record_moved(self, job: CaptureJob) -> None:
        # per sensor: found moved → warn; found in place → clear; unknown → keep as it was
        moved = {s: w for s, w in self._moved.items()
                 if w["calibration_version"] == job.calibration_version}
        for c in job.checks:
            if c["status"] == "ok":
                moved.pop(c["sensor"], None)
            elif c["status"] == "moved":
                moved[c["sensor"]] = {
                    "sensor": c["sensor"], "moved_mm": c["moved_mm"],
                    "rotated_deg": c["rotated_deg"], "found_at": job.created,
                    "check_id": job.id, "calibration_version": job.calibration_version,
                    "calibration_created": job.calibration_created}
        self._moved = moved

    def on_binary(self, session: Any, header: dict[str, Any], payload: bytes) -> None:
        """Hub hook for binary ``calib`` messages (runs on the event loop)."""
        try:
            job = self.jobs.get(int(header.get("req_id", -1)))
        except (TypeError, ValueError):
            job = None
        node = session.id
        if job is None or job.state != "capturing" or node not in job.received:
            log.warning("calibration frame from %s for unknown capture %s ignored", node,
                        header.get("req_id"))
            return
        if "error" in header:
            job.errors[node] = str(header["error"])
        elif not job.node_finished(node):
            job.raw[node].append((header, payload))
            job.received[node] += 1
        if all(job.node_finished(n) for n in job.nodes):
            job.done.set()

    async def _run(self, job: CaptureJob) -> None:
        # a node fails when it stalls (no frame for a while), not after a fixed total time:
        # a loaded machine renders slowly but steadily
        last = {n: (time.monotonic(), 0) for n in job.nodes}
        while not job.done.is_set():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(job.done.wait(), 1.0)
            now = time.monotonic()
            for n in job.nodes:
                t, k = last[n]
                got = job.received[n]
                if got != k:
                    last[n] = (now, got)
                    continue
                sess = self.hub.registry.nodes.get(n)
                if not job.node_finished(n) and (sess is None or not sess.connected):
                    job.errors[n] = (f"{n} disconnected during the capture after {got} of "
                                     f"{job.frames} frames")
                    continue
                limit = FIRST_FRAME_TIMEOUT_S if got == 0 else STALL_TIMEOUT_S
                if not job.node_finished(n) and now - t > limit:
                    job.errors[n] = (f"{n} sent {got} of {job.frames} frames and then nothing "
                                     f"for {limit:.0f} s (disconnected or overloaded?)")
            if all(job.node_finished(n) for n in job.nodes):
                break
        job.state = "computing"
        try:
            await asyncio.to_thread(self._compute, job)
        except GaitrigError as exc:
            job.state, job.message = "failed", str(exc)
            if isinstance(exc, CalibrationError):
                job.unreachable = list(exc.unreachable)
        except Exception as exc:
            log.exception("calibration capture %d failed", job.id)
            job.state, job.message = "failed", f"internal error: {exc}"
        finally:
            job.raw = {}

    def _sensor_frames(self, job: CaptureJob, node: str) -> SensorFrames:
        items = sorted(job.raw[node], key=lambda hp: int(hp[0].get("index", 0)))
        colors, depths = [], []
        for h, p in items:
            c, d = decode_calib_frame(h, p)
            colors.append(c)
            depths.append(d)
        h0 = items[0][0]
        # a node that sends no distortion (older nodes, ideal lenses) gets none (zeros)
        dh, dw = depths[0].shape[:2]
        ch, cw = colors[0].shape[:2]
        di = CameraIntrinsics.from_matrix(h0["depth_K"], dw, dh,
                                          calib_distortion(h0, "depth_dist") or None)
        ci = CameraIntrinsics.from_matrix(h0["color_K"], cw, ch,
                                          calib_distortion(h0, "color_dist") or None)
        return SensorFrames(node, colors, depths, di, ci,
                            np.asarray(h0["T_depth_color"], float), float(h0["depth_scale"]))

    def _compute(self, job: CaptureJob) -> None:
        from engine.calibration.moved import SensorCheck, check_sensor_frames
        from engine.calibration.pipeline import calibrate_frames

        if job.kind == "check":
            active = load_version(calibration_dir(self.data_dir))
            job.calibration_version, job.calibration_created = active.version, active.created
            checks = []
            for n in job.nodes:
                if n in job.errors:
                    checks.append(SensorCheck(n, "unknown", reason=job.errors[n]).to_dict())
                    continue
                try:
                    checks.append(check_sensor_frames(self._sensor_frames(job, n),
                                                      active).to_dict())
                except GaitrigError as exc:
                    checks.append(SensorCheck(n, "unknown", reason=str(exc)).to_dict())
            job.checks = checks
            moved = [c for c in checks if c["status"] == "moved"]
            job.message = ("; ".join(c["reason"] for c in moved) if moved else
                           f"no sensor moved more than 1 cm / 0.5° since calibration "
                           f"version {active.version}")
            self._record_moved(job)
            job.state = "done"
            self.last_check = job
            return
        if job.errors:
            raise InputError("capture failed on " + "; ".join(
                f"{n}: {e}" for n, e in sorted(job.errors.items())) + " — fix it and capture "
                "again")
        frames = [self._sensor_frames(job, n) for n in job.nodes]
        res = calibrate_frames(frames, job.marker_sizes)
        res.meta["source"] = (f"capture {job.id}: {job.frames} frames from "
                              f"{len(job.nodes)} connected sensors")
        job.result = res
        job.doc = result_to_dict(res)
        job.state = "done"

    def accept(self, job_id: int, registry: Any) -> dict[str, Any]:
        """Save a computed calibration as the new active version and apply it."""
        job = self._get(job_id)
        if job.kind != "calibrate" or job.state != "done" or job.result is None:
            raise InputError(f"capture {job_id} has no calibration waiting to be accepted "
                             f"(state {job.state})")
        job.version = save(self.data_dir, job.result)
        job.state = "accepted"
        applied = apply_to_registry(registry, self.data_dir)
        return {"version": job.version, "applied_to": applied}

    def reject(self, job_id: int) -> dict[str, Any]:
        """Discard a computed calibration (nothing saved; the active one stays)."""
        job = self._get(job_id)
        if job.kind != "calibrate" or job.state != "done":
            raise InputError(f"capture {job_id} has no calibration waiting (state {job.state})")
        job.state, job.result = "rejected", None
        return {"rejected": job_id}

    def _get(self, job_id: int) -> CaptureJob:
        job = self.jobs.get(job_id)
        if job is None:
            raise CaptureNotFoundError(f"no capture {job_id} (the server keeps the last "
                                       f"{MAX_JOBS})")
        return job

    def get(self, job_id: int) -> CaptureJob:
        """A job by id.

        Raises:
            CaptureNotFoundError: unknown or forgotten.
        """
        return self._get(job_id)


class CaptureBusyError(InputError):
    """Another capture is running (HTTP 409)."""


class CaptureNotFoundError(InputError):
    """No such capture job (HTTP 404)."""
