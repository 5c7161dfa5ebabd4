"""A kinematic walker: footprints first, then feet, pelvis, legs (IK), trunk and arms.

The model is built so that its ground truth is exact by construction:

1. **Footprints.** A sequence of heel strikes alternating left/right (starting with the
   left foot from standing, as the seed paper's subjects did), with per-step variability,
   a 180° turn on the spot at each end of the corridor, and exact step time, length and
   width. Stance ≈ 60 % of the stride and each double support ≈ 10 % (Perry & Burnfield,
   *Gait Analysis*, 2nd ed., 2010): a foot leaves the floor 20 % of a step time after
   the other foot strikes.
2. **Feet.** In stance the foot rolls over the heel (initial contact with the foot
   pitched ≈ 20° toes-up, foot flat at ≈ 8 % of the stride), stays flat, then rolls over
   the metatarsal heads (heel rise from ≈ 35 % of the stride, ≈ 50° plantar pitch at toe
   off) — the heel, ankle and forefoot rockers of Perry. In swing the foot follows by
   default (``WalkerParams.swing`` ``"minjerk"``) a minimum-jerk path from rest to rest
   with a 4–10 cm sine lift. With ``swing="literature"`` (an option: it lowers the
   validation study's realism band from 6/8 to 4/8 rows, ``docs/simulation.md``) the foot
   leaves the floor at rest (the push-off pivot ends at rest) and **lands moving**: the
   heel's horizontal speed at contact is ``landing_speed_frac`` × walking speed (0.5:
   Lockhart et al. 2003, Ergonomics 46:1136, and Winter 1992, Phys Ther 72:45, report a
   non-zero horizontal heel contact velocity that grows with walking speed; their figures
   were not recoverable from the sources at hand, so 0.5 is this model's choice, ≈ 0.6
   m/s at 1.25 m/s), its vertical speed a small 0.1 m/s downward (``_LAND_VZ``; likewise
   not from a recovered figure). The forward speed is a quintic, so its profile is skewed
   towards the landing, and peaks at the minimum toe clearance (they coincide in healthy
   gait: peak swing-foot velocity ≈ 0.014 s after it, on intact limbs too: PMC4361493);
   the toe tip clears by ``min_toe_clearance_m`` = 1.29 cm (Winter 1992, 11 subjects, SD
   ≈ 0.4 cm) with the foot 3° toes-down (tibia vertical, ankle near neutral at mid swing:
   Perry), after an early-swing ankle peak at 25 % of swing (knee flexion peak ≈ 73 % of
   the stride). The foot's pitch reaches the heel-strike pitch at 90 % of swing. The toes
   are rigid with the forefoot, so the toe tip dips below the floor for the first ≈ 10 %
   of swing, where a real foot's toes are still bent on it.
3. **Pelvis.** Its horizontal path is a C² spline through the midpoint of the two feet at
   every heel strike, plus lateral sway towards the stance foot (±2 cm), pelvic rotation
   (±4°), obliquity (±4°) and anterior tilt (Perry; Winter, *Biomechanics and Motor
   Control of Human Movement*, 4th ed., 2009). Its height is a smooth minimum of the
   standing height and the highest height both legs can reach — so it is lowest in
   double support and highest in mid stance, as in real gait.
4. **Legs** by two-link inverse kinematics (constant thigh and shank lengths, knee in the
   plane of progression); **trunk** with forward lean and counter-rotation; **arms**
   swinging in antiphase to the legs.

Segment lengths are fractions of body height from Winter (2009, Fig. 4.1 / Table 4.1).
Kinect v2 joint definitions: ``AnkleLeft`` is the ankle joint centre, ``FootLeft`` lies on
the forefoot (≈ 2/3 of the way from ankle to toe tip, a few cm above the floor), the hips
are the hip joint centres and ``SpineBase`` the pelvis centre slightly above them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicSpline

from engine.errors import InputError
from engine.skeleton import KINECT_V2

FloatArray = NDArray[np.float64]
Side = Literal["L", "R"]

_J = {name: i for i, name in enumerate(KINECT_V2.joints)}


# ---------------------------------------------------------------------- parameters


@dataclass
class WalkerParams:
    """Per-subject walking parameters.

    ``cadence_steps_min`` is derived (``60 · speed / step_length``) so the three can
    never disagree.

    Attributes:
        height_m: Body height (m).
        speed_m_s: Steady walking speed (m/s).
        step_length_m: Mean step length (m), the mean of left and right steps.
        step_width_m: Mean lateral distance between the ankles at foot placement (m).
        asymmetry: Left/right step-length ratio − 1 (0 = symmetric).
        arm_swing_deg: Peak-to-peak shoulder flexion/extension (deg).
        step_length_cv: Step-to-step coefficient of variation of step length.
        step_time_cv: Step-to-step coefficient of variation of step time.
        step_width_sd_m: Step-to-step SD of step width (m).
        swing: ``"minjerk"`` (default): a minimum-jerk path from rest at toe off to rest
            at heel strike; ``"literature"``: the foot lands moving, its speed peaking at
            minimum toe clearance (see the module docstring; an option, not the default,
            because it lowers the validation study's realism band count, see
            ``docs/simulation.md``).
        landing_speed_frac: Horizontal heel speed at heel contact as a fraction of the
            walking speed (``"literature"`` swing only).
        min_toe_clearance_m: Toe tip height at mid swing (``"literature"`` swing only).
    """

    height_m: float = 1.75
    speed_m_s: float = 1.25
    step_length_m: float = 0.72
    step_width_m: float = 0.115
    asymmetry: float = 0.0
    arm_swing_deg: float = 30.0
    step_length_cv: float = 0.03
    step_time_cv: float = 0.025
    step_width_sd_m: float = 0.02
    swing: Literal["literature", "minjerk"] = "minjerk"
    landing_speed_frac: float = 0.5
    min_toe_clearance_m: float = 0.0129

    def __post_init__(self) -> None:
        checks = [
            ("height_m", 1.0, 2.3), ("speed_m_s", 0.2, 2.5), ("step_length_m", 0.15, 1.2),
            ("step_width_m", 0.0, 0.4), ("asymmetry", -0.5, 0.5), ("arm_swing_deg", 0.0, 90.0),
            ("step_length_cv", 0.0, 0.3), ("step_time_cv", 0.0, 0.3),
            ("step_width_sd_m", 0.0, 0.1), ("landing_speed_frac", 0.0, 1.0),
            ("min_toe_clearance_m", 0.0, 0.1),
        ]
        for name, lo, hi in checks:
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and lo <= v <= hi):
                raise InputError(f"WalkerParams.{name} must be within [{lo}, {hi}], got {v!r}")
        if self.swing not in ("literature", "minjerk"):
            raise InputError(f"WalkerParams.swing must be 'literature' or 'minjerk', "
                             f"got {self.swing!r}")
        if self.step_length_m > 0.6 * self.height_m:
            raise InputError(f"WalkerParams.step_length_m {self.step_length_m} m is too long "
                             f"for a {self.height_m} m tall subject (max 0.6 × height)")

    @property
    def cadence_steps_min(self) -> float:
        """Cadence (steps/min), derived from speed and step length."""
        return 60.0 * self.speed_m_s / self.step_length_m

    @property
    def step_time_s(self) -> float:
        """Mean step time (s): step length over speed."""
        return self.step_length_m / self.speed_m_s

    @property
    def step_lengths_lr(self) -> tuple[float, float]:
        """Mean (left, right) step lengths honouring ``asymmetry`` (left/right − 1)."""
        right = 2.0 * self.step_length_m / (2.0 + self.asymmetry)
        return right * (1.0 + self.asymmetry), right

    @classmethod
    def random(cls, rng: np.random.Generator) -> WalkerParams:
        """A plausible healthy adult.

        Sources: height ~ N(1.72, 0.06) m (the spread of seed 000's ten young adults:
        their Vicon subject-average step lengths spread only 3.6–5.1 cm and strides
        8.0–8.4 cm, less than adult mixed-sex stature, SD 0.09 m, gives); comfortable speed
        ~ N(1.25, 0.15) m/s (seed 000 Table 1: 1.23 ± 0.15 m/s; Bohannon & Andrews 2011,
        Physiotherapy 97:182: 1.3–1.4 m/s for 20–59 y); step length ≈ 0.415 × height,
        scaling with speed^0.4 (Grieve & Gear 1966; gives 0.72 m at 1.75 m / 1.22 m/s as in
        seed 000 Tables 2–3) with 2 % inter-subject spread (with the two above, a
        subject-average SD ≈ 4.5 cm as seed 000's Vicon); |asymmetry| a few percent
        (healthy step-length symmetry ratios 0.97–1.03, Patterson et al. 2010, Gait
        Posture 31:241); arm swing 20–40° peak-to-peak (Meyns et al. 2013, J Biomech
        46:1). Within-subject variability: step length CV ≈ 3 %, step time CV ≈ 2.5 %
        (Hollman et al. 2010, Gait Posture 32:23); step width SD 2.5 cm (seed 000's
        Vicon: step-level SD 3.0–3.15 cm with subject averages spread 1.75–1.85 cm leaves
        √(3.1² − 1.8²) ≈ 2.5 cm within subjects; Owings & Grabiner 2004, J Biomech
        37:935: 2–2.5 cm), with the subject means spread N(0.115, 0.018) m (seed 000
        Vicon 11.7 ± 1.8 cm).

        Args:
            rng: Random generator.

        Returns:
            The parameters (SI units).
        """
        height = float(np.clip(rng.normal(1.72, 0.06), 1.50, 2.00))
        speed = float(np.clip(rng.normal(1.25, 0.15), 0.85, 1.70))
        step = 0.415 * height * (speed / 1.25) ** 0.4 * float(np.clip(rng.normal(1.0, 0.02),
                                                                         0.9, 1.1))
        return cls(
            height_m=height, speed_m_s=speed, step_length_m=float(step),
            step_width_m=float(np.clip(rng.normal(0.115, 0.018), 0.05, 0.2)),
            step_width_sd_m=0.025,
            asymmetry=float(np.clip(rng.normal(0.0, 0.02), -0.06, 0.06)),
            arm_swing_deg=float(np.clip(rng.normal(30.0, 6.0), 15.0, 45.0)),
        )


@dataclass(frozen=True)
class Anthropometry:
    """Segment dimensions (m) from body height, after Winter (2009) Fig. 4.1."""

    height: float

    @property
    def ankle_h(self) -> float:
        """Ankle joint centre above the floor (0.039 H)."""
        return 0.039 * self.height

    @property
    def shank(self) -> float:
        """Knee → ankle."""
        return (0.285 - 0.039) * self.height

    @property
    def thigh(self) -> float:
        """Hip → knee."""
        return (0.530 - 0.285) * self.height

    @property
    def hip_half_width(self) -> float:
        # hip joint centres ≈ 0.1 H apart (Bell et al. 1990 pelvis regressions)
        """Half the distance between the hip joint centres."""
        return 0.05 * self.height

    @property
    def foot_length(self) -> float:
        """Heel → toe tip."""
        return 0.152 * self.height

    @property
    def heel_back(self) -> float:
        """Heel contact point behind the ankle centre."""
        return 0.22 * self.foot_length

    @property
    def ball_fwd(self) -> float:
        """Metatarsal heads in front of the ankle centre."""
        return 0.55 * self.foot_length

    @property
    def spine_base_up(self) -> float:
        """Kinect SpineBase above the hip joint centres' midpoint."""
        return 0.02 * self.height

    @property
    def spine_mid(self) -> float:
        """SpineBase → SpineMid."""
        return 0.15 * self.height

    @property
    def spine_upper(self) -> float:
        """SpineMid → SpineShoulder (shoulder level 0.818 H)."""
        return 0.818 * self.height - 0.550 * self.height - self.spine_mid

    @property
    def neck(self) -> float:
        """SpineShoulder → Neck."""
        return 0.052 * self.height

    @property
    def head(self) -> float:
        """Neck → Head."""
        return 0.066 * self.height

    @property
    def shoulder_half_width(self) -> float:
        """Half the distance between the shoulder joint centres."""
        return 0.105 * self.height

    @property
    def upper_arm(self) -> float:
        """Shoulder → elbow."""
        return 0.186 * self.height

    @property
    def forearm(self) -> float:
        """Elbow → wrist."""
        return 0.146 * self.height

    @property
    def hand(self) -> float:
        """Wrist → Kinect HandLeft (mid-hand)."""
        return 0.045 * self.height

    @property
    def hand_tip(self) -> float:
        """Kinect HandLeft (mid-hand) → HandTipLeft."""
        return 0.05 * self.height


# ---------------------------------------------------------------------- records


@dataclass(frozen=True)
class FootPlacement:
    """A ground-truth foot placement.

    Attributes:
        side: "L" or "R".
        time_s: Heel-strike (initial contact) time, true clock (s).
        position: Ankle joint centre (Kinect ``AnkleLeft/Right``) while the foot is flat.
        heel: Heel contact point on the floor.
        foot_flat_s: Time the forefoot touches down.
        toe_off_s: Time the foot leaves the floor.
        heading_rad: Foot direction (rad from world +X).
        kind: "first" (first step of a pass), "walk", "last" (closing step) or "turn".
    """

    side: Side
    time_s: float
    position: FloatArray
    heel: FloatArray
    foot_flat_s: float
    toe_off_s: float
    heading_rad: float
    kind: str


@dataclass(frozen=True)
class GaitEvent:
    """A ground-truth gait event: ``kind`` is "foot_strike" or "foot_off"."""

    side: Side
    kind: str
    time_s: float


@dataclass
class _Steps:
    """Footprints in time order (index 0, 1 are the standing start feet)."""

    side: list[int] = field(default_factory=list)  # +1 left, -1 right
    t_hs: list[float] = field(default_factory=list)
    t_to: list[float] = field(default_factory=list)
    heel: list[FloatArray] = field(default_factory=list)
    heading: list[float] = field(default_factory=list)
    kind: list[str] = field(default_factory=list)
    gain: list[float] = field(default_factory=list)  # gait-motion amplitude (0 standing)


# Stance timing (fractions of the step time T; a stride is 2 T).
_FF_T = 0.16  # foot flat ≈ 8 % of the stride after heel strike
_HR_T = 0.50  # heel rise starts 0.5 T (25 % of stride) before toe off (≈ 35 % of stride)
_DS_T = 0.20  # double support = 10 % of the stride
_HS_PITCH = math.radians(20.0)
_TO_PITCH = math.radians(50.0)
_SW_PEAK_U = 0.25  # ankle highest at the knee flexion peak, ≈ 73 % of the stride (Perry)
_SW_PEAK_DZ = 0.02  # ankle rise above its toe-off height by then (m)
_LAND_VZ = 0.1  # downward heel speed at contact (m/s)
_MTC_PITCH_DEG = -3.0  # foot pitch at minimum toe clearance (deg, + toes up)


def _rz(a: FloatArray) -> FloatArray:
    c, s = np.cos(a), np.sin(a)
    R = np.zeros((*np.shape(a), 3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
    return R


def _ry(a: FloatArray) -> FloatArray:
    c, s = np.cos(a), np.sin(a)
    R = np.zeros((*np.shape(a), 3, 3))
    R[..., 0, 0], R[..., 0, 2], R[..., 2, 0], R[..., 2, 2], R[..., 1, 1] = c, s, -s, c, 1.0
    return R


def _rx(a: FloatArray) -> FloatArray:
    c, s = np.cos(a), np.sin(a)
    R = np.zeros((*np.shape(a), 3, 3))
    R[..., 1, 1], R[..., 1, 2], R[..., 2, 1], R[..., 2, 2], R[..., 0, 0] = c, -s, s, c, 1.0
    return R


def _mv(R: FloatArray, v: ArrayLike) -> FloatArray:
    return np.einsum("...ij,...j->...i", R, np.broadcast_to(v, (*R.shape[:-2], 3)))


def _unit(v: FloatArray) -> FloatArray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _minjerk(s: FloatArray) -> FloatArray:
    return s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)


def _frames(origin: FloatArray, R: FloatArray) -> FloatArray:
    T = np.zeros((*origin.shape[:-1], 4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = origin
    T[..., 3, 3] = 1.0
    return T


def _axis_frame(z_axis: FloatArray, x_hint: FloatArray) -> FloatArray:
    """Rotation with the given z axis and x as close as possible to ``x_hint``."""
    z = _unit(z_axis)
    x = x_hint - np.sum(x_hint * z, axis=-1, keepdims=True) * z
    x = _unit(x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


#: Bone segments: name → (proximal joint, distal joint) for frames, meshes and IMUs.
BONES: dict[str, tuple[str, str]] = {
    "pelvis": ("HipLeft", "HipRight"),
    "trunk": ("SpineBase", "SpineShoulder"),
    "head": ("Neck", "Head"),
    "thigh_l": ("HipLeft", "KneeLeft"), "thigh_r": ("HipRight", "KneeRight"),
    "shank_l": ("KneeLeft", "AnkleLeft"), "shank_r": ("KneeRight", "AnkleRight"),
    "foot_l": ("AnkleLeft", "FootLeft"), "foot_r": ("AnkleRight", "FootRight"),
    "upperarm_l": ("ShoulderLeft", "ElbowLeft"), "upperarm_r": ("ShoulderRight", "ElbowRight"),
    "forearm_l": ("ElbowLeft", "WristLeft"), "forearm_r": ("ElbowRight", "WristRight"),
    "hand_l": ("WristLeft", "HandTipLeft"), "hand_r": ("WristRight", "HandTipRight"),
}


@dataclass(frozen=True)
class Capsule:
    """A body part for rendering/occlusion: segment ``a``→``b`` (Kinect joints or
    offsets) with a radius (m)."""

    part: str
    a: str
    b: str
    radius: float


class Walker:
    """A subject walking the corridor back and forth.

    Args:
        params: Subject parameters.
        path_start: Start of the walking line (3,) (z ignored; floor at z = 0).
        path_end: End of the walking line (3,).
        start_time: True time (s) at which the subject starts walking from standing.
        back_and_forth: Turn at the ends and walk back; otherwise stop at ``path_end``.
        seed: Seed of the step-to-step variability.
        turn_steps: Steps used for each 180° turn.
        horizon_s: Length of walk generated up front (extended on demand).
    """

    def __init__(
        self,
        params: WalkerParams,
        path_start: ArrayLike,
        path_end: ArrayLike,
        start_time: float = 0.0,
        back_and_forth: bool = True,
        seed: int | None = 0,
        turn_steps: int = 4,
        horizon_s: float = 600.0,
    ) -> None:
        self.params = params
        self.body = Anthropometry(params.height_m)
        a = np.asarray(path_start, dtype=float)[:2]
        b = np.asarray(path_end, dtype=float)[:2]
        if a.shape != (2,) or b.shape != (2,) or not np.all(np.isfinite(np.r_[a, b])):
            raise InputError("path_start and path_end must be finite 3-D points")
        if np.linalg.norm(b - a) < 2.0 * params.step_length_m:
            raise InputError("the walking path must be at least two steps long")
        if turn_steps < 2:
            raise InputError("turn_steps must be >= 2")
        self.path_start, self.path_end = a, b
        self.start_time = float(start_time)
        self.back_and_forth = back_and_forth
        self.turn_steps = int(turn_steps)
        self._rng = np.random.default_rng(seed)
        self._s = _Steps()
        self._finished = False
        self._pass_from, self._pass_to = a, b
        self._last: dict[int, int] = {}
        self._init_standing()
        self._splines_upto = -math.inf
        self._cache: tuple[bytes, dict[str, FloatArray]] | None = None
        # generate a long walk at once so that results never depend on query order
        self._ensure(self.start_time + horizon_s)

    # ------------------------------------------------------------------ footprints

    def _add(self, side: int, t_hs: float, heel: FloatArray, heading: float, kind: str,
             gain: float) -> None:
        s = self._s
        # the previous footprint of the same side lifts off 20 % of a step after the
        # opposite foot's last strike (double support 10 % of the stride)
        prev_same = self._last[side]
        prev_opp = len(s.side) - 1
        if s.kind[prev_opp] == "stand":
            s.t_to[prev_same] = t_hs - (1.0 - _DS_T) * self.params.step_time_s
        else:
            s.t_to[prev_same] = s.t_hs[prev_opp] + _DS_T * (t_hs - s.t_hs[prev_opp])
        s.side.append(side)
        s.t_hs.append(t_hs)
        s.t_to.append(math.inf)
        s.heel.append(np.asarray(heel, dtype=float))
        s.heading.append(float(heading))
        s.kind.append(kind)
        s.gain.append(gain)
        self._last[side] = len(s.side) - 1

    def _init_standing(self) -> None:
        u = _unit(self.path_end - self.path_start)
        n = np.array([-u[1], u[0]])
        psi = math.atan2(u[1], u[0])
        hw = self.params.step_width_m / 2.0
        for side in (1, -1):  # left then right, so the left foot moves first
            self._s.side.append(side)
            self._s.t_hs.append(self.start_time - 1e3)
            self._s.t_to.append(math.inf)
            self._s.heel.append(self.path_start + side * hw * n - self.body.heel_back * u)
            self._s.heading.append(psi)
            self._s.kind.append("stand")
            self._s.gain.append(0.0)
            self._last[side] = len(self._s.side) - 1

    def _ensure(self, t: float) -> None:
        """Generate footprints until time ``t`` is covered (plus margin)."""
        while not self._finished and self._s.t_hs[-1] < t + 3.0:
            self._gen_pass()
            if not self._finished:
                self._gen_turn()
        if self._splines_upto < t:
            self._build_splines()

    def _gen_pass(self) -> None:
        p, s, rng = self.params, self._s, self._rng
        A, B = self._pass_from, self._pass_to
        length = float(np.linalg.norm(B - A))
        u = (B - A) / length
        n = np.array([-u[1], u[0]])
        psi = math.atan2(u[1], u[0])
        along = {sd: float((s.heel[self._last[sd]] - A) @ u) for sd in (-1, 1)}
        ll, lr = p.step_lengths_lr
        first = True
        while True:
            side = -s.side[-1]
            t = s.t_hs[-1]
            if s.kind[-1] == "stand":
                t = self.start_time
            T = p.step_time_s * (1.0 + p.step_time_cv * rng.standard_normal())
            L = (ll if side == 1 else lr) * (1.0 + p.step_length_cv * rng.standard_normal())
            kind = "walk"
            if first:
                L *= 0.6  # the first step from standing is shorter (seed 000, Fig. 6)
                kind = "first"
            target = along[-side] + L
            if target > length:
                # closing step: bring the foot alongside the other one and stop
                target = along[-side]
                kind = "last"
            lateral = side * (p.step_width_m / 2.0 + 0.5 * p.step_width_sd_m
                              * math.sqrt(2.0) * rng.standard_normal())
            heel = A + target * u + lateral * n
            self._add(side, t + T, heel, psi, kind, 0.3 if kind == "last" else 1.0)
            along[side] = target
            first = False
            if kind == "last":
                break
        if not self.back_and_forth:
            self._finished = True

    def _gen_turn(self) -> None:
        p, s = self.params, self._s
        A, B = self._pass_from, self._pass_to
        u = (B - A) / np.linalg.norm(B - A)
        psi0 = math.atan2(u[1], u[0])
        # turn centre: midway between the feet, at the ankles
        c = 0.5 * (s.heel[-1] + s.heel[-2]) + self.body.heel_back * u
        for j in range(1, self.turn_steps + 1):
            psi = psi0 + math.pi * j / self.turn_steps  # turning to the left
            side = -s.side[-1]
            d = np.array([math.cos(psi), math.sin(psi)])
            nn = np.array([-d[1], d[0]])
            heel = c + side * p.step_width_m / 2.0 * nn - self.body.heel_back * d
            self._add(side, s.t_hs[-1] + 1.15 * p.step_time_s, heel, psi, "turn", 0.3)
        self._pass_from, self._pass_to = B, A

    # ------------------------------------------------------------------ splines

    def _ankle_flat(self, i: int) -> FloatArray:
        psi = self._s.heading[i]
        return self._s.heel[i] + self.body.heel_back * np.array([math.cos(psi), math.sin(psi)])

    def _build_splines(self) -> None:
        s = self._s
        n = len(s.side)
        # The body stands still until start_time: the splines start there at rest
        # (clamped: zero velocity) and are held before it (see _pose). Knots far before
        # the start let the C² spline swing the arms (≈ 1 m/s) and sway the pelvis
        # (≈ 0.1 m/s) through the "standing" second.
        t_keys = [self.start_time]
        mid0 = 0.5 * (self._ankle_flat(0) + self._ankle_flat(1))
        xy = [mid0]
        hd = [s.heading[0]]
        for k in range(2, n):
            t_keys.append(s.t_hs[k])
            xy.append(0.5 * (self._ankle_flat(k) + self._ankle_flat(k - 1)))
            h0, h1 = s.heading[k - 1], s.heading[k]
            hd.append(h0 + 0.5 * math.remainder(h1 - h0, 2 * math.pi))
        hd_arr = np.unwrap(np.array(hd))
        tk = np.array(t_keys)
        if self._finished:  # standing after the last step
            tk = np.r_[tk, tk[-1] + 0.5, tk[-1] + 1e3]
            xy += [xy[-1], xy[-1]]
            hd_arr = np.r_[hd_arr, hd_arr[-1], hd_arr[-1]]
        self._sp_xy = CubicSpline(tk, np.array(xy), bc_type="clamped")
        self._sp_hd = CubicSpline(tk, hd_arr, bc_type="clamped")
        # signed gait oscillations: +1 = left stance (mid single support) / left heel strike
        sgn = np.array(s.side[2:], dtype=float) * np.array(s.gain[2:])
        t_hs = np.array(s.t_hs[2:])
        T = np.diff(np.r_[self.start_time, t_hs])
        t_mid = t_hs + 0.6 * np.r_[T[1:], T[-1]]
        z0 = [self.start_time]
        end = [t_hs[-1] + 2.0, t_hs[-1] + 1e3]
        self._sp_mid = CubicSpline(np.r_[z0, t_mid, end], np.r_[0, sgn, 0, 0],
                                   bc_type="clamped")
        self._sp_hs = CubicSpline(np.r_[z0, t_hs, end], np.r_[0, sgn, 0, 0],
                                  bc_type="clamped")
        self._hs_arr = {sd: np.array([s.t_hs[i] for i in range(n) if s.side[i] == sd])
                        for sd in (1, -1)}
        self._idx = {sd: np.array([i for i in range(n) if s.side[i] == sd]) for sd in (1, -1)}
        self._arr = {"t_hs": np.array(s.t_hs), "t_to": np.array(s.t_to),
                     "heel": np.array(s.heel), "heading": np.array(s.heading)}
        self._splines_upto = s.t_hs[-1] - 2.5 if not self._finished else math.inf

    # ------------------------------------------------------------------ feet

    def _foot(self, side: int, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        """World ankle positions (T,3) and foot rotations (T,3,3) of one side."""
        b = self.body
        idx = self._idx[side]
        hs = self._hs_arr[side]
        k = np.clip(np.searchsorted(hs, t, side="right") - 1, 0, len(idx) - 1)
        cur = idx[k]
        nxt = idx[np.minimum(k + 1, len(idx) - 1)]
        ar = self._arr
        t_hs = ar["t_hs"][cur]
        t_to = ar["t_to"][cur]
        t_next = ar["t_hs"][nxt]
        heel = ar["heel"][cur]
        psi = ar["heading"][cur]
        psi_n = ar["heading"][nxt]
        heel_n = ar["heel"][nxt]
        Tstep = self.params.step_time_s
        ff = t_hs + _FF_T * Tstep
        hr = np.maximum(ff, t_to - _HR_T * Tstep)
        stance = (t < t_to) | (nxt == cur)
        # pitch (+ toes up) and pivot in stance
        pitch = np.zeros_like(t)
        load = stance & (t < ff)
        u = np.clip((t - t_hs) / (ff - t_hs), 0.0, 1.0)
        pitch[load] = _HS_PITCH * (1.0 - _minjerk(u[load]))
        push = stance & (t >= hr) & np.isfinite(t_to)
        with np.errstate(invalid="ignore"):
            w = np.clip((t - hr) / np.maximum(t_to - hr, 1e-9), 0.0, 1.0)
        pitch[push] = -_TO_PITCH * _minjerk(w[push])
        R = _rz(psi) @ _ry(-pitch)
        hz = b.ankle_h
        heel3 = np.c_[heel, np.zeros(len(t))]
        ball_loc = np.array([b.ball_fwd, 0.0, -hz])
        heel_loc = np.array([-b.heel_back, 0.0, -hz])
        ball3 = heel3 + _mv(_rz(psi), [b.heel_back + b.ball_fwd, 0.0, 0.0])
        ankle = np.where(push[:, None], ball3 - _mv(R, ball_loc), heel3 - _mv(R, heel_loc))
        # swing: from the toe-off pose to the next heel-strike pose
        sw = ~stance
        if np.any(sw):
            i_sw = np.nonzero(sw)[0]
            R0 = _rz(psi[i_sw]) @ _ry(np.full(len(i_sw), _TO_PITCH))
            p0 = ball3[i_sw] - _mv(R0, ball_loc)
            R1 = _rz(psi_n[i_sw]) @ _ry(np.full(len(i_sw), -_HS_PITCH))
            p1 = np.c_[heel_n[i_sw], np.zeros(len(i_sw))] - _mv(R1, heel_loc)
            sv = np.clip((t[i_sw] - t_to[i_sw]) / (t_next[i_sw] - t_to[i_sw]), 0.0, 1.0)
            pitch_sw = -_TO_PITCH + (_TO_PITCH + _HS_PITCH) * _minjerk(np.clip(sv * 1.3, 0, 1))
            if self.params.swing == "minjerk":
                m = _minjerk(sv)
                pos = p0 + (p1 - p0) * m[:, None]
                # clearance: the ankle rises early in swing (knee flexion peak ≈ 70 % of stride)
                dist = np.linalg.norm(p1[:, :2] - p0[:, :2], axis=1)
                lift = (0.04 + 0.06 * np.clip(dist / self.params.step_length_m / 2.0, 0, 1)) \
                    * np.sin(np.pi * sv) * (1.4 - 0.8 * sv)
                pos[:, 2] += lift
            else:
                m, pos, pitch_sw = self._swing_path(p0, p1, sv, t_next[i_sw] - t_to[i_sw])
            dpsi = np.remainder(psi_n[i_sw] - psi[i_sw] + np.pi, 2 * np.pi) - np.pi
            ankle[i_sw] = pos
            R[i_sw] = _rz(psi[i_sw] + dpsi * m) @ _ry(-pitch_sw)
        return ankle, R

    def _swing_path(self, p0: FloatArray, p1: FloatArray, u: FloatArray, t_sw: FloatArray
                    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The ``"literature"`` swing: ankle path (N,3), horizontal progress (N,) and foot
        pitch (N,, + toes up) at normalised swing times ``u`` from toe-off pose ``p0`` to
        heel-strike pose ``p1`` over swing durations ``t_sw`` (s).

        Horizontal: a quintic from rest at toe off (the push-off pivot ends at rest) to the
        landing speed at heel contact (``landing_speed_frac`` × walking speed, no
        acceleration), so the speed profile is skewed late. Vertical: a piecewise cubic
        through the early-swing peak (knee flexion peak, ``_SW_PEAK_U``), the minimum toe
        clearance at the instant of peak forward speed, and the landing with a small
        downward heel speed ``_LAND_VZ``. The foot pitch is a few degrees toes-down at
        minimum clearance (tibia vertical, ankle near neutral at mid swing: Perry) and
        reaches the heel-strike pitch before contact.
        """
        b, prm = self.body, self.params
        d = p1[:, :2] - p0[:, :2]
        dist = np.maximum(np.linalg.norm(d, axis=1), 1e-6)
        # landing speed normalised by the mean swing speed; short steps (turns, closing
        # steps) land proportionally slower; <= 1.5 keeps the progress monotonic
        full = np.clip(dist / (2.0 * prm.step_length_m), 0.0, 1.0)
        v1 = np.clip(prm.landing_speed_frac * prm.speed_m_s * full * t_sw / dist, 0.0, 1.5)
        h = _minjerk(u) + v1 * u**3 * (-4.0 + 7.0 * u - 3.0 * u * u)
        # instant of peak speed (h'' = 0): (120 - 60 v1) u² + (84 v1 - 180) u + 60 - 24 v1
        qa, qb, qc = 120.0 - 60.0 * v1, 84.0 * v1 - 180.0, 60.0 - 24.0 * v1
        um = np.clip((-qb - np.sqrt(np.maximum(qb * qb - 4 * qa * qc, 0.0))) / (2 * qa),
                     _SW_PEAK_U + 0.1, 0.9)
        # pitch: back from the push-off plantar pitch by the early-swing peak, a few degrees
        # toes-down at minimum clearance, the heel-strike pitch before contact
        pm = math.radians(_MTC_PITCH_DEG)
        x1 = np.clip(u / um, 0.0, 1.0)
        x2 = np.clip((u - um) / np.maximum(0.9 - um, 1e-6), 0.0, 1.0)
        # (1 − (1 − x)⁴(1 + 4x): starts and ends at rest, so the foot's angular velocity
        # is continuous at toe off and FootLeft/Right have no kink there)
        ease = 1.0 - (1.0 - x1) ** 4 * (1.0 + 4.0 * x1)
        pitch = np.where(u < um, -_TO_PITCH + (_TO_PITCH + pm) * ease,
                         pm + (_HS_PITCH - pm) * _minjerk(x2))
        toe_fwd = b.foot_length - b.heel_back
        z_mtc = prm.min_toe_clearance_m + b.ankle_h * math.cos(pm) - toe_fwd * math.sin(pm)
        z0, z1 = p0[:, 2], p1[:, 2]
        zs = [z0, z0 + _SW_PEAK_DZ * full, np.full_like(z0, z_mtc) * full + z1 * (1 - full),
              z1]
        us = [np.zeros_like(u), np.full_like(u, _SW_PEAK_U), um, np.ones_like(u)]
        vs = [np.zeros_like(u), np.zeros_like(u), np.zeros_like(u), -_LAND_VZ * t_sw]
        z = np.zeros_like(u)
        for j in range(3):
            sel = (u >= us[j]) & (u <= us[j + 1]) if j == 2 else (u >= us[j]) & (u < us[j + 1])
            w = us[j + 1][sel] - us[j][sel]
            x = (u[sel] - us[j][sel]) / w
            h00, h10 = 2 * x**3 - 3 * x**2 + 1, x**3 - 2 * x**2 + x
            h01, h11 = -2 * x**3 + 3 * x**2, x**3 - x**2
            z[sel] = (h00 * zs[j][sel] + h10 * w * vs[j][sel] + h01 * zs[j + 1][sel]
                      + h11 * w * vs[j + 1][sel])
        pos = np.c_[p0[:, :2] + d * h[:, None], z]
        return h, pos, pitch

    # ------------------------------------------------------------------ full pose

    def _pose(self, t: ArrayLike) -> dict[str, FloatArray]:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if t.ndim != 1 or not np.all(np.isfinite(t)):
            raise InputError("times must be a 1-D array of finite seconds")
        key = t.tobytes()
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        if len(t):
            self._ensure(float(t.max()))
        b, p = self.body, self.params
        ankle_l, Rf_l = self._foot(1, t)
        ankle_r, Rf_r = self._foot(-1, t)
        ts = np.maximum(t, self.start_time)  # standing still before the start
        xy = self._sp_xy(ts)
        psi = self._sp_hd(ts)
        mid = self._sp_mid(ts)  # +1 in left mid-stance
        hs = self._sp_hs(ts)  # +1 at left heel strike
        # pelvis: rotation (left hip forward at left heel strike), obliquity (swing side
        # drops), anterior tilt; amplitudes from Perry & Burnfield 2010
        yaw = psi - math.radians(4.0) * hs
        roll = math.radians(4.0) * mid
        tilt = np.full(len(t), math.radians(10.0))
        Rp = _rz(yaw) @ _rx(roll) @ _ry(tilt)
        Rh = _rz(psi)
        sway = 0.012 * p.height_m * mid
        left = _mv(Rh, [0.0, 1.0, 0.0])
        fwd = _mv(Rh, [1.0, 0.0, 0.0])
        centre_xy = xy + sway[:, None] * left[:, :2]
        # pelvis height: smooth minimum of the standing height and the highest height at
        # which each leg still reaches its ankle (leaves 0.5 % of the leg length slack)
        leg = b.thigh + b.shank
        zmax = b.ankle_h + leg * 0.985
        cands = [np.full(len(t), zmax)]
        hip_off = {}
        for side, ank in ((1, ankle_l), (-1, ankle_r)):
            off = _mv(Rp, [0.0, side * b.hip_half_width, 0.0])
            hip_off[side] = off
            dxy = centre_xy + off[:, :2] - ank[:, :2]
            reach = np.sqrt(np.maximum((0.995 * leg) ** 2 - np.sum(dxy * dxy, axis=1), 0.0))
            cands.append(ank[:, 2] - off[:, 2] + reach)
        c = np.stack(cands)
        k = 0.01
        cmin = c.min(axis=0)
        z = cmin - k * np.log(np.sum(np.exp(-(c - cmin) / k), axis=0))
        centre = np.c_[centre_xy, z]
        J = np.full((len(t), 25, 3), np.nan)
        J[:, _J["HipLeft"]] = centre + hip_off[1]
        J[:, _J["HipRight"]] = centre + hip_off[-1]
        # legs: two-link IK, knee bending forward
        knees = {}
        for side, ank, name in ((1, ankle_l, "Left"), (-1, ankle_r, "Right")):
            hip = J[:, _J["Hip" + name]]
            d = ank - hip
            dist = np.linalg.norm(d, axis=1)
            dist = np.clip(dist, abs(b.thigh - b.shank) + 1e-6, leg - 1e-6)
            uu = d / np.linalg.norm(d, axis=1, keepdims=True)
            x = (b.thigh**2 - b.shank**2 + dist**2) / (2 * dist)
            y = np.sqrt(np.maximum(b.thigh**2 - x**2, 0.0))
            nrm = fwd - np.sum(fwd * uu, axis=1, keepdims=True) * uu
            nrm = _unit(nrm)
            knee = hip + uu * x[:, None] + nrm * y[:, None]
            knees[side] = knee
            J[:, _J["Knee" + name]] = knee
            J[:, _J["Ankle" + name]] = ank
            Rf = Rf_l if side == 1 else Rf_r
            J[:, _J["Foot" + name]] = ank + _mv(Rf, [0.66 * b.ball_fwd + 0.04, 0.0,
                                                    -b.ankle_h + 0.035])
        # trunk: forward lean ≈ 4°, thorax counter-rotation ≈ 60 % of pelvic rotation
        Rt = _rz(psi + 0.6 * math.radians(4.0) * hs) @ _ry(np.full(len(t), math.radians(4.0)))
        sb = centre + _mv(Rp, [-0.01, 0.0, b.spine_base_up])
        J[:, _J["SpineBase"]] = sb
        J[:, _J["SpineMid"]] = sb + _mv(Rt, [0.0, 0.0, b.spine_mid])
        ss = J[:, _J["SpineMid"]] + _mv(Rt, [0.0, 0.0, b.spine_upper])
        J[:, _J["SpineShoulder"]] = ss
        J[:, _J["Neck"]] = ss + _mv(Rt, [0.01, 0.0, b.neck])
        J[:, _J["Head"]] = J[:, _J["Neck"]] + _mv(Rt, [0.015, 0.0, b.head])
        # arms: the left arm is forward at right heel strike (antiphase to the left leg)
        amp = math.radians(p.arm_swing_deg) / 2.0
        R_arm = {}
        for side, name in ((1, "Left"), (-1, "Right")):
            sh = ss + _mv(Rt, [-0.01, side * b.shoulder_half_width, -0.025 * p.height_m])
            flex = -math.radians(8.0) - side * amp * hs
            Ru = Rt @ _rx(np.full(len(t), side * math.radians(8.0))) @ _ry(-flex)
            el = sh + _mv(Ru, [0.0, 0.0, -b.upper_arm])
            elbow_flex = math.radians(20.0) + 0.6 * np.maximum(flex, 0.0)
            Rl = Ru @ _ry(-elbow_flex)
            wr = el + _mv(Rl, [0.0, 0.0, -b.forearm])
            J[:, _J["Shoulder" + name]] = sh
            J[:, _J["Elbow" + name]] = el
            J[:, _J["Wrist" + name]] = wr
            J[:, _J["Hand" + name]] = wr + _mv(Rl, [0.0, 0.0, -b.hand])
            J[:, _J["HandTip" + name]] = wr + _mv(Rl, [0.0, 0.0, -b.hand - b.hand_tip])
            J[:, _J["Thumb" + name]] = wr + _mv(Rl, [0.03, -side * 0.01, -0.05])
            R_arm[side] = (Ru, Rl)
        out: dict[str, FloatArray] = {"joints": J, "R_pelvis": Rp, "R_trunk": Rt,
                                      "R_foot_l": Rf_l, "R_foot_r": Rf_r, "fwd": fwd,
                                      "R_ua_l": R_arm[1][0], "R_fa_l": R_arm[1][1],
                                      "R_ua_r": R_arm[-1][0], "R_fa_r": R_arm[-1][1],
                                      "centre": centre}
        self._cache = (key, out)
        return out

    # ------------------------------------------------------------------ public API

    def joints(self, t: ArrayLike) -> FloatArray:
        """``(T, 25, 3)`` world positions of the Kinect v2 joints (KINECT_V2 order).

        Args:
            t: ``(T,)`` true times, s.

        Returns:
            Joint positions, m, world frame (Z up), time first axis.
        """
        return self._pose(t)["joints"].copy()

    def bone_frames(self, t: ArrayLike) -> dict[str, FloatArray]:
        """World pose ``(T, 4, 4)`` of each bone in :data:`BONES`.

        Frames: origin at the proximal joint; for limbs and the trunk +z points from the
        distal to the proximal joint (up when standing), +x forward, +y to the subject's
        left; the pelvis frame is x forward, y left, z up; the foot frame has +x towards
        the toes, +z dorsal (up when flat).

        Args:
            t: ``(T,)`` true times, s.

        Returns:
            Bone name -> ``(T, 4, 4)`` ``T_world_bone`` (m).
        """
        P = self._pose(t)
        J = P["joints"]
        j = _J
        fr: dict[str, FloatArray] = {}
        fr["pelvis"] = _frames(P["centre"], P["R_pelvis"])
        fr["trunk"] = _frames(J[:, j["SpineBase"]], P["R_trunk"])
        fr["head"] = _frames(J[:, j["Neck"]], P["R_trunk"])
        fwd = P["fwd"]
        for sfx, name in (("l", "Left"), ("r", "Right")):
            hip, knee, ank = J[:, j["Hip" + name]], J[:, j["Knee" + name]], J[:, j["Ankle" + name]]
            fr[f"thigh_{sfx}"] = _frames(hip, _axis_frame(hip - knee, fwd))
            fr[f"shank_{sfx}"] = _frames(knee, _axis_frame(knee - ank, fwd))
            fr[f"foot_{sfx}"] = _frames(ank, P[f"R_foot_{sfx}"])
            sh, el, wr = (J[:, j["Shoulder" + name]], J[:, j["Elbow" + name]],
                          J[:, j["Wrist" + name]])
            fr[f"upperarm_{sfx}"] = _frames(sh, P[f"R_ua_{sfx}"])
            fr[f"forearm_{sfx}"] = _frames(el, P[f"R_fa_{sfx}"])
            fr[f"hand_{sfx}"] = _frames(wr, P[f"R_fa_{sfx}"])
        return fr

    @cached_property
    def capsules(self) -> list[Capsule]:
        """Body parts as capsules between joints (radii after Winter/NASA anthropometry,
        scaled by height).

        Returns:
            The capsules (names, end joints, radii in m).
        """
        s = self.params.height_m / 1.75
        caps = [
            Capsule("pelvis", "HipLeft", "HipRight", 0.095 * s),
            Capsule("trunk", "SpineBase", "SpineShoulder", 0.125 * s),
            Capsule("neck", "SpineShoulder", "Neck", 0.055 * s),
            Capsule("head", "Neck", "Head", 0.09 * s),
        ]
        for sfx, n in (("l", "Left"), ("r", "Right")):
            caps += [
                Capsule(f"thigh_{sfx}", "Hip" + n, "Knee" + n, 0.075 * s),
                Capsule(f"shank_{sfx}", "Knee" + n, "Ankle" + n, 0.05 * s),
                Capsule(f"foot_{sfx}", "Heel" + n, "Toe" + n, 0.035 * s),
                Capsule(f"upperarm_{sfx}", "Shoulder" + n, "Elbow" + n, 0.045 * s),
                Capsule(f"forearm_{sfx}", "Elbow" + n, "Wrist" + n, 0.037 * s),
                Capsule(f"hand_{sfx}", "Wrist" + n, "HandTip" + n, 0.03 * s),
            ]
        return caps

    def capsule_segments(self, t: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Capsule end points and radii at times ``t`` (order of :attr:`capsules`).

        Args:
            t: ``(T,)`` true times, s.

        Returns:
            ``(a, b, radii)``: ``(T, C, 3)`` end points (m, world) and ``(C,)`` radii (m).
        """
        P = self._pose(t)
        J = P["joints"]
        b = self.body
        extra: dict[str, FloatArray] = {}
        for sfx, n in (("l", "Left"), ("r", "Right")):
            Rf = P[f"R_foot_{sfx}"]
            ank = J[:, _J["Ankle" + n]]
            r = 0.035 * self.params.height_m / 1.75
            extra["Heel" + n] = ank + _mv(Rf, [-b.heel_back + r, 0.0, -b.ankle_h + r])
            extra["Toe" + n] = ank + _mv(Rf, [b.foot_length - b.heel_back - r, 0.0,
                                              -b.ankle_h + r])

        def pt(name: str) -> FloatArray:
            return extra[name] if name in extra else J[:, _J[name]]

        caps = self.capsules
        A = np.stack([pt(c.a) for c in caps], axis=1)
        B = np.stack([pt(c.b) for c in caps], axis=1)
        # widen the trunk: shift the capsule's top below the shoulders' surface
        return A, B, np.array([c.radius for c in caps])

    def body_mesh(self, t: float) -> tuple[FloatArray, NDArray[np.int32], NDArray[np.int32]]:
        """Triangle mesh of the body at time ``t``.

        Args:
            t: True time, s.

        Returns:
            ``(vertices (V,3) world m, triangles (F,3) int32, part_labels (F,) int32)``,
            ``part_labels`` indexing :attr:`capsules`.
        """
        A, B, r = self.capsule_segments([float(t)])
        return capsules_mesh(A[0], B[0], r)

    def foot_placements(self, t0: float = -math.inf, t1: float | None = None
                        ) -> list[FootPlacement]:
        """Ground-truth foot placements with heel strike in ``[t0, t1]``.

        Args:
            t0: Start, s (true clock).
            t1: End, s; None: the end of the generated walk (at least 30 s after
                ``start_time``).

        Returns:
            The placements in time order.
        """
        if t1 is not None and math.isfinite(t1):
            self._ensure(t1)
        s = self._s
        out = []
        for i in range(2, len(s.side)):
            if s.t_hs[i] < t0 or (t1 is not None and s.t_hs[i] > t1):
                continue
            if not math.isfinite(s.t_to[i]):
                continue  # not yet complete (its toe off lies beyond the generated walk)
            a = self._ankle_flat(i)
            out.append(FootPlacement(
                side="L" if s.side[i] == 1 else "R", time_s=s.t_hs[i],
                position=np.array([a[0], a[1], self.body.ankle_h]),
                heel=np.array([s.heel[i][0], s.heel[i][1], 0.0]),
                foot_flat_s=s.t_hs[i] + _FF_T * self.params.step_time_s,
                toe_off_s=s.t_to[i], heading_rad=s.heading[i], kind=s.kind[i]))
        return out

    def events(self, t0: float, t1: float) -> list[GaitEvent]:
        """True foot strikes and foot offs in ``[t0, t1]`` (s, true clock), in time order.

        The ground truth of gait-event detection: a ``"foot_strike"`` is the instant the
        foot's heel contact point reaches the floor (the standing start's feet have
        none), a ``"foot_off"`` the instant its forefoot (the metatarsal heads it rolls
        over) leaves it; ``tests/engine/sim/test_walker_events.py`` checks both against
        the foot's kinematics. Each foot off comes 20 % of a step after the other foot's
        strike (double support 2 × 10 % of the stride, stance 60 %).

        Args:
            t0: Start, s (true clock).
            t1: End, s.

        Returns:
            The events in time order.
        """
        self._ensure(t1)
        s = self._s
        ev = []
        for i in range(len(s.side)):
            side: Side = "L" if s.side[i] == 1 else "R"
            if s.kind[i] != "stand" and t0 <= s.t_hs[i] <= t1:
                ev.append(GaitEvent(side, "foot_strike", s.t_hs[i]))
            if t0 <= s.t_to[i] <= t1:
                ev.append(GaitEvent(side, "foot_off", s.t_to[i]))
        return sorted(ev, key=lambda e: e.time_s)

    def pass_times(self, t1: float) -> list[tuple[float, float]]:
        """(first heel strike, last heel strike) of each straight pass up to ``t1``.

        Args:
            t1: End, s (true clock).

        Returns:
            ``(start_s, end_s)`` per pass, in time order.
        """
        self._ensure(t1)
        s = self._s
        out, start = [], None
        for i in range(2, len(s.side)):
            if s.kind[i] == "first":
                start = s.t_hs[i]
            elif s.kind[i] == "last" and start is not None:
                if s.t_hs[i] <= t1:
                    out.append((start, s.t_hs[i]))
                start = None
        return out


# ---------------------------------------------------------------------- meshes


def _capsule_template(n_around: int = 10, n_cap: int = 4) -> tuple[FloatArray, NDArray[np.int32],
                                                                   FloatArray]:
    """Unit capsule template: vertices on a unit sphere split at the equator.

    Returns ``(dirs (V,3), triangles (F,3), top (V,) 1 for the upper hemisphere)``;
    a capsule is ``a + r·dir + top·(b − a)`` in a frame whose z is along ``b − a``.
    """
    rings = []
    tops = []
    # lower hemisphere from pole to equator, then upper from equator to pole
    lat = np.r_[np.linspace(-np.pi / 2, 0, n_cap + 1), np.linspace(0, np.pi / 2, n_cap + 1)]
    top = np.r_[np.zeros(n_cap + 1), np.ones(n_cap + 1)]
    az = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    for la, tp in zip(lat, top, strict=True):
        ring = np.stack([np.cos(la) * np.cos(az), np.cos(la) * np.sin(az),
                         np.full_like(az, np.sin(la))], axis=1)
        rings.append(ring)
        tops.append(np.full(n_around, tp))
    V = np.concatenate(rings)
    tris = []
    nr = len(rings)
    for i in range(nr - 1):
        for j in range(n_around):
            a = i * n_around + j
            b = i * n_around + (j + 1) % n_around
            c = (i + 1) * n_around + j
            d = (i + 1) * n_around + (j + 1) % n_around
            tris += [[a, c, b], [b, c, d]]
    return V, np.array(tris, dtype=np.int32), np.concatenate(tops)


_TEMPLATE = _capsule_template()


def capsules_mesh(A: FloatArray, B: FloatArray, radii: FloatArray
                  ) -> tuple[FloatArray, NDArray[np.int32], NDArray[np.int32]]:
    """Triangle mesh of capsules ``A[i]``→``B[i]`` with ``radii[i]``.

    Args:
        A: ``(C, 3)`` first end points, m.
        B: ``(C, 3)`` second end points, m.
        radii: ``(C,)`` radii, m.

    Returns:
        ``(vertices (V,3), triangles (F,3) int32, part_labels (F,) int32)``, each triangle
        labelled with its capsule's index.
    """
    dirs, tris, top = _TEMPLATE
    C = len(radii)
    axis = B - A
    length = np.linalg.norm(axis, axis=1)
    z = axis / np.maximum(length, 1e-9)[:, None]
    helper = np.where(np.abs(z[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    x = _unit(np.cross(helper, z))
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=-1)  # (C,3,3)
    V = (A[:, None, :] + radii[:, None, None] * np.einsum("cij,vj->cvi", R, dirs)
         + top[None, :, None] * axis[:, None, :])
    nv = len(dirs)
    F = (tris[None, :, :] + (np.arange(C) * nv)[:, None, None]).reshape(-1, 3)
    labels = np.repeat(np.arange(C, dtype=np.int32), len(tris))
    return V.reshape(-1, 3), F.astype(np.int32), labels
