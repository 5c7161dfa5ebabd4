"""KSCC — Kinect Skeleton Coordinate Calibration (seed 004) into a universal skeleton frame.

A user stands still for about four seconds (120 frames at 30 fps). From those frames:

* the **initial centre** ``C`` = mean over frames of the mean of all joints (paper eq. for
  ``A`` and ``C``);
* the **facing** from the shoulders: the paper's ``θ = atan(D/W)`` with ``D = Zr − Zl``
  (depth difference) and ``W = Xr − Xl`` (width), generalised here with ``atan2`` on the
  horizontal shoulder vector in a Z-up frame, so any facing within ±90° (and beyond) works.
  By default D and W are summed over the shoulder, elbow, wrist and hand pairs (the
  paper's own assumption that a user standing straight has all joints in one body plane):
  each joint's fitting error is independent, so the angle is less than half as noisy as
  from the shoulders alone (``bench/kscc.py``'s simulated Kinect v1, 120 frames at 3.1 m:
  SD 0.6–0.9° vs 1.4–2.2°; at a 20° initial angle the pull of the turned-away shoulder
  towards the sensor biases the shoulder line by 2.4°, the pooled lines by 0.6°), which
  extends seed 004's "≤ 4 cm" from ±25° to ±45° there; ``facing="shoulders"`` is the
  paper's exact estimate.

Every later frame is translated by ``−C`` and rotated about the vertical with a
quaternion (``engine.geometry``, w-first) into the **universal frame** ``U``: origin at the
initial centre, +Z up, +X the user's initial facing direction, +Y the user's left. Two
users calibrated this way at two sites can be compared joint by joint
(``engine.compare``). The paper's universal frame (Kinect SDK axes, user facing the
sensor, i.e. −Z) differs from ``U`` only by a fixed relabelling of axes: paper
X = −Y_U (towards the user's right), Y = Z_U (up), Z = −X_U (behind the user).

Input frames. Rotating "about the vertical" needs to know where up is:

* ``frame="kinect"`` — Kinect SDK camera space (v1/v2): +X the sensor's left, +Y up,
  +Z forward (the sensor assumed level, as in the paper);
* ``frame="opencv"`` — OpenCV/Azure Kinect depth-camera frame: +X right, +Y down,
  +Z forward (sensor level);
* ``frame="world"`` — already Z up (e.g. a calibrated world frame);
* ``frame=(ux, uy, uz)`` — the up direction measured in the input frame (e.g. from the
  sensor's accelerometer), for a tilted sensor;
* or ``T_world_sensor`` — a full 4×4 pose into a Z-up world (overrides ``frame``).

Stillness (documented thresholds). KSCC needs a stable centre and facing, so stillness
is judged on the body as a whole, pooled over joints with a median (a Kinect's per-joint
fitting error of a few cm, which wanders within fractions of a second, would make single
joint speeds useless, and an occasional wild joint must not count as movement). A frame
is still when (1) the body — the median joint displacement — moves slower than
``speed_threshold_mps`` (0.15 m/s, measured over ``speed_window_s`` = 0.3 s: a step, a
lean or walking exceeds it, postural sway of a few mm/s does not), (2) the median joint
displacement from the joints' means over the frames collected so far is below
``max_drift_m`` (5 cm; slow drifts), and (3) the body, averaged over the speed window, is
turned less than ``max_turn_deg`` (20°) about the vertical from its collected mean pose
(turning on the spot; a 2-D Procrustes fit over all joints, far steadier than the
shoulder line). The joints of the facing method (:func:`facing_left`; for the paper's,
both shoulders) must be present (not NaN, not NOT_TRACKED), and at least half the joints.
A moving or lost user restarts the collection, and the message says why. Tuned so that
the simulated Kinect v2 skeleton (``engine.sim.skeleton_model``, slowly varying joint
errors of several cm) standing still 2.5–4 m away at initial angles up to 40° is
collected without restarts.
"""

from __future__ import annotations

import json
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import InputError, InsufficientDataError
from engine.geometry import make_transform, quat_from_axis_angle, quat_to_matrix
from engine.skeleton import JointSet, SkeletonSeries, TrackingState

FloatArray = NDArray[np.float64]

#: Frames the paper collects (≈ 4 s at 30 fps).
N_STILL_FRAMES = 120

_FRAME_MATRICES: dict[str, FloatArray] = {
    # rows: level-frame axes (X forward of the sensor, Y sensor's left, Z up) in input coords
    "kinect": np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
    "opencv": np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]),
    "world": np.eye(3),
}

#: Roles used for the centre when ``centre="roles"`` (present in every joint set).
CENTRE_ROLES: tuple[str, ...] = (
    "pelvis", "spine_mid", "spine_top", "head",
    "shoulder_left", "elbow_left", "wrist_left", "hand_left",
    "shoulder_right", "elbow_right", "wrist_right", "hand_right",
    "hip_left", "knee_left", "ankle_left", "foot_left",
    "hip_right", "knee_right", "ankle_right", "foot_right",
)

State = Literal["waiting", "collecting", "moved", "done"]


@dataclass(frozen=True)
class KsccProgress:
    """What a live UI shows during calibration.

    Attributes:
        state: ``waiting`` (no body, shoulders hidden, or not yet still), ``collecting``,
            ``moved`` (the user moved; collection restarted), ``done``.
        n_collected: Still frames collected so far.
        n_required: Still frames needed.
        message: One short sentence for the operator.
    """

    state: State
    n_collected: int
    n_required: int
    message: str

    @property
    def fraction(self) -> float:
        """Share of the required still frames collected so far, 0–1."""
        return self.n_collected / self.n_required

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form for a live UI.

        Returns:
            The fields and ``fraction``.
        """
        return {"state": self.state, "n_collected": self.n_collected,
                "n_required": self.n_required, "fraction": self.fraction,
                "message": self.message}


def level_transform(frame: str | ArrayLike = "kinect", T_world_sensor: ArrayLike | None = None
                    ) -> tuple[FloatArray, FloatArray | None]:
    """``T_level_input`` (4×4, Z up) and the sensor's horizontal view axis in that frame.

    Args:
        frame: The skeleton's axes: ``"kinect"`` (Kinect SDK camera space, Y up),
            ``"opencv"`` (a gaitrig node's sensor frame, Y down), ``"world"`` (Z up) or an
            up vector ``(3,)`` in the input frame.
        T_world_sensor: The sensor's 4×4 pose when known: it is then the transform
            (``frame`` is ignored) and its optical axis the view axis.

    Returns:
        The transform and the unit horizontal optical axis (or ``None`` when the input
        frame says nothing about the sensor, i.e. ``frame="world"`` without a pose).

    Raises:
        InputError: unknown frame name, zero or degenerate up vector, bad pose.
    """
    if T_world_sensor is not None:
        T = np.asarray(T_world_sensor, dtype=float)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise InputError("T_world_sensor must be a finite 4×4 matrix")
        axis = T[:3, 2].copy()  # optical axis (+Z of a Kinect/OpenCV camera) in the world
        axis[2] = 0.0
        n = np.linalg.norm(axis)
        return T, (axis / n if n > 1e-6 else None)
    if isinstance(frame, str):
        if frame not in _FRAME_MATRICES:
            raise InputError(f"unknown skeleton frame {frame!r}; use 'kinect' (Y up), "
                             "'opencv' (Y down), 'world' (Z up) or an up vector")
        M = _FRAME_MATRICES[frame]
        return make_transform(M, np.zeros(3)), (None if frame == "world"
                                                else np.array([1.0, 0.0, 0.0]))
    up = np.asarray(frame, dtype=float)
    if up.shape != (3,) or not np.isfinite(up).all() or np.linalg.norm(up) < 1e-9:
        raise InputError("the up vector must be three finite numbers, not all zero")
    up = up / np.linalg.norm(up)
    # level X = the input's +Z (a camera's optical axis) made horizontal
    fwd = np.array([0.0, 0.0, 1.0]) - up[2] * up
    if np.linalg.norm(fwd) < 1e-6:
        raise InputError("the up vector is parallel to the camera's optical axis (+Z); "
                         "pass T_world_sensor instead")
    fwd /= np.linalg.norm(fwd)
    left = np.cross(up, fwd)
    return make_transform(np.stack([fwd, left, up]), np.zeros(3)), np.array([1.0, 0.0, 0.0])


def _valid_positions(series: SkeletonSeries, use_inferred: bool) -> FloatArray:
    p = series.positions.copy()
    bad = series.states == TrackingState.NOT_TRACKED
    if not use_inferred:
        bad |= series.states == TrackingState.INFERRED
    p[bad] = np.nan
    return p


def _nanmean0(P: FloatArray) -> FloatArray:
    """Mean over axis 0 ignoring NaN, NaN where nothing is left (no warnings)."""
    ok = np.isfinite(P)
    n = ok.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.where(ok, P, 0.0).sum(axis=0) / np.maximum(n, 1), np.nan)


FacingMode = Literal["shoulders", "arms", "trunk"]
FACING_MODES: tuple[str, ...] = ("shoulders", "arms", "trunk")

#: Mirrored joint pairs of the ``"arms"`` facing (shoulder line first).
ARM_PAIRS: tuple[str, ...] = ("shoulder", "elbow", "wrist", "hand")
#: An arm pair whose line deviates more than this from the shoulder line is ignored
#: (a forearm held forward, a hand in a pocket): it is not in the body plane.
ARM_PAIR_MAX_DEV_DEG = 25.0


def facing_left(pose: ArrayLike, joint_set: JointSet, mode: FacingMode = "shoulders",
                min_width_m: float = 0.05) -> FloatArray | None:
    """Unit horizontal vector towards the user's left, from one level-frame pose (J, 3).

    ``"shoulders"``: the paper's shoulder line (right → left shoulder). ``"arms"``: the
    paper's own assumption that a user standing straight has every joint in one body
    plane, applied to the shoulder, elbow, wrist and hand pairs: their right → left
    vectors are summed, i.e. the paper's ``θ = atan(D/W)`` with ``D`` and ``W`` summed over
    the pairs. Every joint's fitting error is independent, so four pairs halve the noise
    of the angle; pairs deviating more than ``ARM_PAIR_MAX_DEV_DEG`` from the shoulder
    line are left out (an arm not hanging at the side), and the legs are never used
    (feet are often staggered). ``"trunk"``: the mean direction of the shoulder and hip
    lines that are visible; when neither line is complete (a shoulder and a hip hidden
    behind the body at large angles), the half lines from the spine top / pelvis to the
    visible shoulder / hip. ``None`` when the required joints are missing (both
    shoulders for ``"shoulders"``/``"arms"``) or closer than ``min_width_m`` seen from
    above.

    Args:
        pose: ``(J, 3)`` joints of one frame in the level frame (Z up), m; NaN = missing.
        joint_set: Its joint set (roles name the joints).
        mode: ``"shoulders"``, ``"arms"`` or ``"trunk"`` as above.
        min_width_m: Shortest usable horizontal span, m.

    Returns:
        ``(3,)`` unit vector (z = 0), or None.
    """
    P = np.asarray(pose, dtype=float)

    def j(role: str) -> FloatArray:
        return P[joint_set.role_index(role)]

    def unit(v: FloatArray, min_len: float) -> FloatArray | None:
        h = np.array([v[0], v[1], 0.0])
        n = float(np.hypot(h[0], h[1]))
        return h / n if np.isfinite(n) and n >= min_len else None

    full = [unit(j("shoulder_left") - j("shoulder_right"), min_width_m)]
    if mode == "shoulders" or (full[0] is None and mode == "arms"):
        return full[0]
    if mode == "arms":
        ref = full[0]
        assert ref is not None
        cos_max = np.cos(np.radians(ARM_PAIR_MAX_DEV_DEG))
        total = np.zeros(3)
        for part in ARM_PAIRS:
            v = j(f"{part}_left") - j(f"{part}_right")
            v = np.array([v[0], v[1], 0.0])
            n = float(np.hypot(v[0], v[1]))
            # summing the raw vectors weights each pair by its width, as D/W pooled does
            if np.isfinite(n) and n >= min_width_m and v @ ref >= cos_max * n:
                total += v
        return unit(total, 1e-9)
    full.append(unit(j("hip_left") - j("hip_right"), min_width_m))
    lines = [v for v in full if v is not None]
    if not lines:
        half = [unit(j("shoulder_left") - j("spine_top"), min_width_m / 2),
                unit(j("spine_top") - j("shoulder_right"), min_width_m / 2),
                unit(j("hip_left") - j("pelvis"), min_width_m / 2),
                unit(j("pelvis") - j("hip_right"), min_width_m / 2)]
        lines = [v for v in half if v is not None]
    if not lines:
        return None
    return unit(np.sum(lines, axis=0), 1e-9)


#: Median joint distance from the skeleton's median above which it cannot be in metres
#: (≈ 0.4 m for an adult in metres; Azure Kinect Body Tracking writes millimetres).
MAX_BODY_SPREAD_M = 1.5


def check_metres(pose: ArrayLike) -> None:
    """Raise when a skeleton frame (J, 3) is clearly not in metres.

    Uses the median joint distance from the median joint position, so one wild joint
    (a fitting failure) does not trigger it.

    Args:
        pose: ``(J, 3)`` joints of one frame (NaN = missing).

    Raises:
        InputError: the spread exceeds ``MAX_BODY_SPREAD_M``.
    """
    P = np.asarray(pose, dtype=float)
    P = P[np.isfinite(P).all(axis=-1)]
    if len(P) >= 3:
        spread = float(np.median(np.linalg.norm(P - np.median(P, axis=0), axis=1)))
        if spread > MAX_BODY_SPREAD_M:
            raise InputError(
                f"the skeleton's joints lie {spread:.3g} units apart on average; positions "
                "must be in metres (Azure Kinect Body Tracking writes millimetres: divide by "
                "1000)"
            )


def _body_yaw_deg(ref: FloatArray, pose: FloatArray) -> float:
    """Rotation about the vertical (deg) best aligning ``ref`` to ``pose`` (2-D Procrustes).

    Pools every joint present in both (centred on their medians), so it is far less noisy
    than the shoulder line alone; 0 when fewer than three joints are shared.
    """
    ok = np.isfinite(ref).all(axis=1) & np.isfinite(pose).all(axis=1)
    if ok.sum() < 3:
        return 0.0
    a = ref[ok, :2] - np.median(ref[ok, :2], axis=0)
    b = pose[ok, :2] - np.median(pose[ok, :2], axis=0)
    return float(np.degrees(np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]),
                                       np.sum(a * b))))


class StillnessCollector:
    """Streaming collection of consecutive still frames (see the module docstring).

    Args:
        joint_set: Joint set of the frames.
        n_frames: Still frames to collect.
        speed_threshold_mps: Body speed (median joint displacement per second) above
            which the user is moving.
        speed_window_s: Time base of the speed estimate.
        max_drift_m: Largest median joint shift from the collected means.
        max_turn_deg: Largest turn about the vertical of the pose averaged over the speed
            window from the collected mean pose.
        facing: Facing method (:func:`facing_left`); its joints must be visible.
    """

    def __init__(self, joint_set: JointSet, n_frames: int = N_STILL_FRAMES,
                 speed_threshold_mps: float = 0.15, speed_window_s: float = 0.3,
                 max_drift_m: float = 0.05, max_turn_deg: float = 20.0,
                 facing: FacingMode = "arms") -> None:
        if min(n_frames, speed_threshold_mps, speed_window_s, max_drift_m, max_turn_deg) <= 0:
            raise InputError("stillness parameters must be positive")
        self.max_turn_deg = float(max_turn_deg)
        self.facing: FacingMode = facing
        self.joint_set = joint_set
        self.n_frames = int(n_frames)
        self.speed_threshold_mps = float(speed_threshold_mps)
        self.speed_window_s = float(speed_window_s)
        self.max_drift_m = float(max_drift_m)
        self.reset()

    def reset(self) -> None:
        """Forget everything (new user, new session)."""
        self._hist: deque[tuple[float, FloatArray]] = deque()
        self._frames: list[FloatArray] = []
        self._index: list[int] = []
        self._sum = np.zeros((len(self.joint_set.joints), 3))
        self._cnt = np.zeros(len(self.joint_set.joints))
        self._last_t = -np.inf
        self._k = -1
        self.restarts = 0
        self.longest = 0
        #: why the last restart happened: "moved", "drifted", "turned" or "lost"
        self.last_reason = ""

    @property
    def frames(self) -> FloatArray:
        """``(n, J, 3)`` collected still frames (NaN where a joint was missing)."""
        return np.array(self._frames).reshape(-1, len(self.joint_set.joints), 3)

    @property
    def indices(self) -> list[int]:
        """Update-call indices (0-based) of the collected frames."""
        return list(self._index)

    @property
    def done(self) -> bool:
        """Whether ``n_frames`` consecutive still frames have been collected."""
        return len(self._frames) >= self.n_frames

    def _restart(self) -> None:
        self.longest = max(self.longest, len(self._frames))
        if self._frames:
            self.restarts += 1
        self._frames.clear()
        self._index.clear()
        self._sum[:] = 0.0
        self._cnt[:] = 0.0

    def _progress(self, state: State, msg: str) -> KsccProgress:
        return KsccProgress(state, len(self._frames), self.n_frames, msg)

    def update(self, time: float, positions: ArrayLike) -> KsccProgress:
        """Feed one frame (``(J, 3)``, NaN = missing joint) at ``time`` seconds.

        Args:
            time: Frame time, s (strictly increasing).
            positions: ``(J, 3)`` joints in the level frame (Z up), m.

        Returns:
            The progress after this frame.

        Raises:
            InputError: a frame of another shape, times not increasing, or not in metres.
        """
        p = np.asarray(positions, dtype=float)
        if p.shape != self._sum.shape:
            raise InputError(f"a {self.joint_set.name} frame must have shape {self._sum.shape}, "
                             f"got {p.shape}")
        t = float(time)
        if not t > self._last_t:
            raise InputError("frame times must be strictly increasing")
        self._last_t = t
        self._k += 1
        if self.done:
            return self._progress("done", "calibration data complete")
        while self._hist and t - self._hist[0][0] > 1.5 * self.speed_window_s:
            self._hist.popleft()
        ref = next((h for h in reversed(self._hist) if t - h[0] >= self.speed_window_s),
                   self._hist[0] if self._hist else None)
        self._hist.append((t, p))
        check_metres(p)
        valid = np.isfinite(p).all(axis=1)
        face = facing_left(p, self.joint_set, self.facing)
        if face is None or valid.sum() < len(valid) / 2:
            had = bool(self._frames)
            self._restart()
            if had:
                self.last_reason = "lost"
            what = ("the body" if valid.sum() < len(valid) / 2 else
                    "both shoulders" if self.facing != "trunk" else "the shoulders or hips")
            return self._progress("moved" if had else "waiting",
                                  f"{what} not visible — face the sensor"
                                  + (", restarting" if had else ""))
        if ref is None or t - ref[0] < 0.5 * self.speed_window_s:
            return self._progress("waiting", "stand still facing the sensor")
        both = valid & np.isfinite(ref[1]).all(axis=1)
        if both.sum() < len(valid) / 2:  # the body was just acquired: no speed yet
            return self._progress("waiting", "stand still facing the sensor")
        # speed of the body from the median joint displacement: pooling joints keeps the
        # per-joint fitting noise out, the median ignores a few wild joints
        speed = float(np.linalg.norm(np.median(p[both] - ref[1][both], axis=0))) / (t - ref[0])
        why = "moved" if speed > self.speed_threshold_mps else ""
        if not why and self._frames:
            m = valid & (self._cnt > 0)
            mean = self._sum[m] / self._cnt[m, None]
            drift = float(np.linalg.norm(np.median(p[m] - mean, axis=0)))
            turn = 0.0
            # compare with the collected mean only once it averages as many frames as the
            # window does; a single noisy frame is no reference
            if len(self._frames) >= len(self._hist):
                turn = abs(_body_yaw_deg(self._sum / np.maximum(self._cnt, 1)[:, None],
                                         _nanmean0(np.array([h[1] for h in self._hist]))))
            why = ("drifted" if drift > self.max_drift_m
                   else "turned" if turn > self.max_turn_deg else "")
        if why:
            had = bool(self._frames)
            self._restart()
            self.last_reason = why
            if had:
                return self._progress("moved", f"{why} — restarting; please stand still")
            return self._progress("waiting", "stand still facing the sensor")
        self._frames.append(p)
        self._index.append(self._k)
        self._sum[valid] += p[valid]
        self._cnt[valid] += 1
        if self.done:
            self.longest = max(self.longest, len(self._frames))
            return self._progress("done", "calibration data complete")
        return self._progress("collecting", f"collecting {len(self._frames)}/{self.n_frames}")


def find_still_window(series: SkeletonSeries, n_frames: int = N_STILL_FRAMES,
                      frame: str | ArrayLike = "kinect", T_world_sensor: ArrayLike | None = None,
                      use_inferred: bool = True, facing: FacingMode = "arms",
                      **stillness: float) -> NDArray[np.int64]:
    """Indices of the first ``n_frames`` consecutive still frames of a recording.

    Args:
        series: The recording (time first axis, metres).
        n_frames: Consecutive still frames required.
        frame: The skeleton's axes (see :func:`level_transform`).
        T_world_sensor: The sensor's pose when known.
        use_inferred: Use INFERRED joints too.
        facing: How the facing is measured (see :func:`facing_left`).
        **stillness: Thresholds of :class:`StillnessCollector`.

    Returns:
        ``(n_frames,)`` frame indices into ``series``.

    Raises:
        InsufficientDataError: too short, or the user never stood still long enough.
        InputError: a shoulder is missing in every frame.
    """
    T_level, _ = level_transform(frame, T_world_sensor)
    P = _valid_positions(series, use_inferred) @ T_level[:3, :3].T + T_level[:3, 3]
    js = series.joint_set
    if len(series) < n_frames:
        raise InsufficientDataError(
            f"KSCC needs {n_frames} still frames (about {n_frames / 30:.0f} s at 30 fps); "
            f"the recording has only {len(series)} frames"
        )
    if facing != "trunk":
        for role in ("shoulder_left", "shoulder_right"):
            if not np.isfinite(P[:, js.role_index(role)]).all(axis=1).any():
                raise InputError(
                    f"{js.roles[role]} is missing (NaN or not tracked) in every frame; the "
                    "user must stand facing the sensor with both shoulders visible"
                )
    col = StillnessCollector(js, n_frames, facing=facing, **stillness)
    for t, p in zip(series.times, P, strict=True):
        if col.update(t, p).state == "done":
            return np.array(col.indices, dtype=np.int64)
    raise InsufficientDataError(
        f"the user never stood still for {n_frames} consecutive frames (longest still "
        f"stretch: {max(col.longest, len(col.frames))} frames, restarted {col.restarts} times "
        "after moving or losing the shoulders); ask them to stand still, facing the sensor, "
        f"for about {n_frames / 30:.0f} s"
    )


class KsccCalibrator:
    """Estimator: fit the initial centre and facing, transform into the universal frame.

    Args:
        n_frames: Still frames to collect (paper: 120).
        frame: Input frame convention or up vector (module docstring).
        T_world_sensor: Pose into a Z-up world; overrides ``frame``.
        centre: ``"all"`` — mean of all joints (the paper); ``"roles"`` — mean of the 20
            role joints every joint set has, so Kinect v1/v2/Azure centres agree.
        facing: ``"arms"`` (default) — the paper's ``atan(D/W)`` with D and W summed over
            the shoulder, elbow, wrist and hand pairs (the paper's body-plane assumption;
            half the angle noise of the shoulders alone, see ``bench/kscc.py``);
            ``"shoulders"`` — the paper's shoulder line only; ``"trunk"`` — shoulder and
            hip lines, with half lines when a shoulder/hip is hidden (:func:`facing_left`).
        use_inferred: Use INFERRED joints (the SDK's guesses); NOT_TRACKED/NaN never.
        speed_threshold_mps, speed_window_s, max_drift_m, max_turn_deg: Stillness
            thresholds (:class:`StillnessCollector`).

    Attributes (after fit / a completed stream):
        centre_: Initial centre ``C`` in input coordinates (m).
        heading_: Facing direction in the level frame (rad, CCW from its +X).
        angle_: Rotation about the vertical applied into the universal frame (rad) = −heading_.
        initial_angle_: The paper's θ (rad): 0 facing the sensor, > 0 when the left
            shoulder is nearer; ``None`` when the sensor's axis is unknown.
        quaternion_: w-first rotation level → universal (about +Z by ``angle_``).
        T_universal_input_: 4×4 map from input coordinates to the universal frame.
        still_indices_: Frame indices used (batch fit) or update indices (stream).
        joint_set_: Joint set it was fitted on.
    """

    def __init__(self, n_frames: int = N_STILL_FRAMES, frame: str | ArrayLike = "kinect",
                 T_world_sensor: ArrayLike | None = None,
                 centre: Literal["all", "roles"] = "all",
                 facing: FacingMode = "arms", use_inferred: bool = True,
                 speed_threshold_mps: float = 0.15, speed_window_s: float = 0.3,
                 max_drift_m: float = 0.05, max_turn_deg: float = 20.0) -> None:
        if centre not in ("all", "roles"):
            raise InputError("centre must be 'all' or 'roles'")
        if facing not in FACING_MODES:
            raise InputError("facing must be 'shoulders', 'arms' or 'trunk'")
        self.facing: FacingMode = facing
        self.n_frames = n_frames
        self.frame = frame
        self.T_world_sensor = T_world_sensor
        self.centre = centre
        self.use_inferred = use_inferred
        self.stillness = {"speed_threshold_mps": speed_threshold_mps,
                          "speed_window_s": speed_window_s, "max_drift_m": max_drift_m,
                          "max_turn_deg": max_turn_deg}
        self._T_level, self._axis = level_transform(frame, T_world_sensor)
        self._collector: StillnessCollector | None = None

    # ------------------------------------------------------------------ fitting

    def fit(self, series: SkeletonSeries) -> KsccCalibrator:
        """Calibrate from the first still window of a recording.

        Args:
            series: The sensor's skeleton recording (time first axis, metres, in ``frame``).

        Returns:
            ``self``, with ``centre_``, ``heading_``, ``T_universal_input_`` ... and
            ``still_indices_`` (the frames used) set.

        Raises:
            InsufficientDataError: too short, or the user never stood still long enough.
            InputError: a shoulder is missing in every frame, or the skeleton is not in metres.
        """
        idx = find_still_window(series, self.n_frames, self.frame, self.T_world_sensor,
                                self.use_inferred, self.facing, **self.stillness)
        P = _valid_positions(series, self.use_inferred)[idx]
        self._fit_level(P @ self._T_level[:3, :3].T + self._T_level[:3, 3], series.joint_set)
        self.still_indices_ = idx
        return self

    def update(self, time: float, positions: ArrayLike, states: ArrayLike | None = None,
               joint_set: JointSet | None = None) -> KsccProgress:
        """Streaming calibration: feed frames until the progress says ``done``.

        Args:
            time: Frame time (s), strictly increasing.
            positions: ``(J, 3)`` joints in the input frame.
            states: ``(J,)`` tracking states (optional; NOT_TRACKED joints are ignored).
            joint_set: Needed on the first call only; inferred from J otherwise.

        Returns:
            The progress (state, frames collected of those required, message) for a live UI.

        Raises:
            InputError: ``positions`` not ``(J, 3)`` or ``states`` of another length.
        """
        p = np.array(positions, dtype=float)
        if self._collector is None:
            js = joint_set or _joint_set_by_count(p.shape[0] if p.ndim == 2 else -1)
            self._collector = StillnessCollector(js, self.n_frames, facing=self.facing,
                                                 **self.stillness)
        col = self._collector
        if states is not None:
            s = np.asarray(states)
            bad = s == TrackingState.NOT_TRACKED
            if not self.use_inferred:
                bad |= s == TrackingState.INFERRED
            if s.shape != p.shape[:1]:
                raise InputError(f"states must have shape ({p.shape[0]},), got {s.shape}")
            p[bad] = np.nan
        if p.ndim != 2 or p.shape[1] != 3:
            raise InputError(f"positions must be (J, 3), got {p.shape}")
        was_done = col.done
        prog = col.update(time, p @ self._T_level[:3, :3].T + self._T_level[:3, 3])
        if prog.state == "done" and not was_done:
            self._fit_level(col.frames, col.joint_set)
            self.still_indices_ = np.array(col.indices, dtype=np.int64)
        return prog

    def reset(self) -> None:
        """Start a new streaming calibration (keeps the previous fit until replaced)."""
        self._collector = None

    def _fit_level(self, W: FloatArray, js: JointSet) -> None:
        """Centre and facing from still frames ``W`` (n, J, 3) in the level frame."""
        if self.centre == "all":
            cols = np.arange(len(js.joints))
        else:
            cols = np.array([js.role_index(r) for r in CENTRE_ROLES])
        per_frame = _nanmean0(np.swapaxes(W[:, cols], 0, 1))  # paper's A(t), (n, 3)
        c = _nanmean0(per_frame)  # paper's C
        if not np.isfinite(c).all():
            raise InputError("no usable joint positions in the still frames")
        left = facing_left(_nanmean0(W), js, self.facing)
        if left is None:
            raise InputError(
                "cannot tell which way the user faces: the shoulders"
                + (" and hips are" if self.facing == "trunk" else " are")
                + " missing or less than 5 cm apart seen from above (user side-on to the "
                "sensor?); ask the user to turn towards the sensor"
            )
        heading = float(np.arctan2(-left[0], left[1]))  # forward = left × up = (ly, −lx)
        q = quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), -heading)
        R = quat_to_matrix(q)
        T_u_level = make_transform(R, -R @ c)
        self.joint_set_ = js
        self.heading_ = heading
        self.angle_ = -heading
        self.quaternion_ = q
        self.T_universal_input_ = T_u_level @ self._T_level
        T_input_level = np.linalg.inv(self._T_level)
        self.centre_ = T_input_level[:3, :3] @ c + T_input_level[:3, 3]
        if self._axis is None:
            self.initial_angle_: float | None = None
        else:
            a = self._axis
            sensor_left = np.array([-a[1], a[0], 0.0])
            d = -left  # RS − LS
            self.initial_angle_ = float(np.arctan2(d @ a, d @ sensor_left))

    # ------------------------------------------------------------ persistence

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready calibration (to keep it while the sensor stays put, or to send it).

        Returns:
            Settings and fitted values (``T_universal_input`` 4×4 as nested lists); what
            :func:`save_kscc` writes and :meth:`from_dict` reads.

        Raises:
            InputError: not fitted.
        """
        self._check_fitted()
        return {
            "kind": "kscc", "version": 1, "joint_set": self.joint_set_.name,
            "frame": (self.frame if isinstance(self.frame, str)
                      else np.asarray(self.frame, dtype=float).tolist()),
            "T_world_sensor": (None if self.T_world_sensor is None
                               else np.asarray(self.T_world_sensor, float).tolist()),
            "centre_mode": self.centre, "facing": self.facing, "n_frames": self.n_frames,
            "centre": self.centre_.tolist(), "heading": self.heading_,
            "initial_angle": self.initial_angle_,
            "T_universal_input": self.T_universal_input_.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> KsccCalibrator:
        """Inverse of :meth:`to_dict`.

        Args:
            d: A dict as :meth:`to_dict` writes.

        Returns:
            The fitted calibrator.

        Raises:
            InputError: not a KSCC calibration, or malformed.
        """
        from engine.skeleton import JOINT_SETS

        try:
            if d.get("kind") != "kscc":
                raise InputError("not a KSCC calibration (kind != 'kscc')")
            cal = cls(int(d["n_frames"]), d["frame"], d["T_world_sensor"], d["centre_mode"],
                      d["facing"])
            T = np.asarray(d["T_universal_input"], dtype=float)
            if T.shape != (4, 4) or not np.isfinite(T).all():
                raise InputError("T_universal_input must be a finite 4×4 matrix")
            cal.joint_set_ = JOINT_SETS[d["joint_set"]]
            cal.heading_ = float(d["heading"])
            cal.angle_ = -cal.heading_
            cal.quaternion_ = quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), cal.angle_)
            cal.centre_ = np.asarray(d["centre"], dtype=float).reshape(3)
            ia = d["initial_angle"]
            cal.initial_angle_ = None if ia is None else float(ia)
            cal.T_universal_input_ = T
            cal.still_indices_ = np.zeros(0, dtype=np.int64)
        except (KeyError, TypeError, ValueError) as e:
            if isinstance(e, InputError):
                raise
            raise InputError(f"malformed KSCC calibration: {e!r}") from None
        return cal

    @property
    def initial_angle_deg_(self) -> float | None:
        """The paper's initial angle θ in degrees (``None`` if the sensor axis is unknown)."""
        return None if self.initial_angle_ is None else float(np.degrees(self.initial_angle_))

    # --------------------------------------------------------------- transform

    def _check_fitted(self) -> None:
        if not hasattr(self, "T_universal_input_"):
            raise InputError("KSCC is not calibrated yet: call fit() or stream frames with "
                             "update() until it reports 'done'")

    def transform_points(self, positions: ArrayLike) -> FloatArray:
        """Map points ``(..., 3)`` from the input frame into the universal frame.

        Args:
            positions: ``(..., 3)`` points, m, in the input frame (any leading axes, e.g.
                ``(T, J, 3)``).

        Returns:
            The points in the universal frame (``T_universal_input_`` applied), same shape.

        Raises:
            InputError: not fitted, or the last axis is not 3.
        """
        self._check_fitted()
        p = np.asarray(positions, dtype=float)
        if p.shape[-1:] != (3,):
            raise InputError(f"points must have a last axis of 3, got {p.shape}")
        T = self.T_universal_input_
        return p @ T[:3, :3].T + T[:3, 3]

    def transform(self, series: SkeletonSeries) -> SkeletonSeries:
        """The whole series in the universal frame (states and times unchanged).

        Args:
            series: A recording of the calibrated sensor (same joint set).

        Returns:
            A new series, ``meta["frame"] = "kscc_universal"``.

        Raises:
            InputError: not fitted, or another joint set than the calibration's.
        """
        self._check_fitted()
        if series.joint_set.name != self.joint_set_.name:
            raise InputError(f"KSCC was calibrated on {self.joint_set_.name} skeletons but got "
                             f"{series.joint_set.name}; calibrate each sensor's stream itself")
        meta = dict(series.meta)
        meta["frame"] = "kscc_universal"
        return SkeletonSeries(series.times.copy(), self.transform_points(series.positions),
                              series.states.copy(), series.joint_set, meta)


def _joint_set_by_count(n: int) -> JointSet:
    from engine.skeleton import JOINT_SETS

    for js in JOINT_SETS.values():
        if len(js.joints) == n:
            return js
    raise InputError(f"cannot tell the joint set of a {n}-joint frame; expected 20 (Kinect "
                     "v1), 25 (Kinect v2) or 32 (Azure Kinect), or pass joint_set=")


def save_kscc(path: str | Path, cal: KsccCalibrator) -> None:
    """Write a fitted calibration as JSON (read back by :func:`load_kscc`).

    Args:
        path: Destination file (overwritten).
        cal: A fitted calibrator (``KsccCalibrator.to_dict`` is what is written).
    """
    Path(path).write_text(json.dumps(cal.to_dict(), indent=1))


def load_kscc(path: str | Path) -> KsccCalibrator:
    """Read a calibration written by :func:`save_kscc`.

    Args:
        path: The JSON file.

    Returns:
        A fitted :class:`KsccCalibrator` (``transform`` works at once).

    Raises:
        InputError: unreadable or not a KSCC calibration file.
    """
    try:
        d = json.loads(Path(path).read_text())
    except (OSError, ValueError) as e:
        raise InputError(f"cannot read KSCC calibration {path}: {e}") from None
    if not isinstance(d, dict):
        raise InputError(f"{path} is not a KSCC calibration file")
    return KsccCalibrator.from_dict(d)


def kscc_calibrate(series: SkeletonSeries, **kwargs: object) -> KsccCalibrator:
    """Batch KSCC: ``KsccCalibrator(**kwargs).fit(series)``.

    Args:
        series: The sensor's recording with the user standing still.
        **kwargs: :class:`KsccCalibrator` settings.

    Returns:
        The fitted calibrator.

    Raises:
        InsufficientDataError: the user never stood still long enough.
        InputError: bad settings or a skeleton not in metres.
    """
    return KsccCalibrator(**kwargs).fit(series)  # type: ignore[arg-type]


__all__ = [
    "CENTRE_ROLES",
    "MAX_BODY_SPREAD_M",
    "N_STILL_FRAMES",
    "FacingMode",
    "KsccCalibrator",
    "KsccProgress",
    "StillnessCollector",
    "check_metres",
    "facing_left",
    "find_still_window",
    "kscc_calibrate",
    "level_transform",
    "load_kscc",
    "save_kscc",
]
