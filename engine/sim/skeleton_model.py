"""Kinect-v2-like skeletons observed by one simulated sensor, with realistic errors.

What a Kinect v2 body tracker gets wrong, and how it is simulated here (every parameter
of :class:`SkeletonErrorModel` names its source):

* **Noise grows with distance.** Each joint carries a slowly varying fitting error
  (Ornstein–Uhlenbeck process, per sensor/joint/axis) plus frame-to-frame jitter, both
  scaled linearly with the distance to the sensor (the depth pixel footprint grows
  linearly and the ToF depth noise quadratically with range; Kinect v2 joint errors grow
  with distance: Otte et al. 2016, PLoS ONE 11:e0166532; Wang et al. 2015, IEEE ICHI).
* **Bias towards the visible surface.** The skeleton is fitted to the part of the body
  surface that sensor sees, so joint estimates are pulled towards the sensor — the effect
  seed 000 measured with two opposite sensors ("joint positions estimates of the left
  sensor are closer to the surface which is only tracked by the left sensor", a few cm),
  larger for the body half turned away (Wang et al. 2015: accuracy of the turned-away
  half degrades at 30°/60° view angles).
* **Self-occlusion.** A joint whose line of sight is blocked by another body part
  (ray-capsule test against the walker's body) is reported INFERRED with a much larger
  error, and NOT_TRACKED when the occlusion lasts (seed 000: "the Kinect skeleton fitting
  algorithm initially tries to infer the position of the occluded joints and if that
  fails the respective joints are labeled as untracked").
* **Late acquisition.** A body entering the view is reported only after a detection delay
  of a few hundred ms (seed 000: "needs some time to recognize a person that enters the
  volume", hence the paper's 2 m overlap of tracking volumes).
* **Field of view and range.** Joints outside the depth frustum or 0.5–4.5 m are not
  tracked; no body is reported unless its trunk is in view.
* **Fitting failures.** (a) The Kinect v2 tracker assumes the user faces the sensor: a
  person seen from behind is reported mirrored (left/right labels swapped; Microsoft
  Kinect v2 SDK documentation; Müller et al. 2017, PLoS ONE 12:e0175813 [= seed 000],
  hence walking *towards* the sensors). (b) Brief left/right leg swaps when the legs
  cross (Kinect v2 gait studies report such outliers: Geerse et al. 2015, PLoS ONE
  10:e0139913; Springer & Yogev Seligmann 2016, Sensors 16:194).

The magnitudes are set from the numbers above and from the step-level agreement the seed
paper found against Vicon with its own averaging (Tables 2–3), looking only at the rows
of the paper's method, never at our estimator's (``docs/simulation.md`` lists every
parameter, its source and the order of the tuning): per-sensor slowly varying joint
error 1.2 cm at 2.5 m, isotropic (two-sided step-length RPC ≈ 6 cm, step-width RPC ≈ 4–5
cm; 1.2 fits the six reproducible rows below better than 1.1 or 1.3 cm); the turned-away
half's fit error larger (×2.6: the one-sided error variances of
``bench/gait_error_budget.py`` are far below Table 2's; its frame-to-frame jitter is not
gained, ``far_jitter_gain``) and pulled 1.5 cm towards the
sensor against 2 cm for the near half (Fig. 5B: each sensor's estimate lies towards the
surface it sees; Tables 2–3: the common step-width bias is small and positive, +0.3 cm
two-sided, +0.6 cm one-sided, so the near pull, which widens, slightly exceeds the far
pull, which narrows); partly hidden joints pulled 3 cm along the body's forward axis
(Table 2: one-sided, right steps +1.7 cm longer and left steps −1.1 cm shorter).

Check with the paper's own averaging (``bench/gait_study.py``: 10 random subjects × 10
walks of 7 m from standing, left foot first, equal-weight mean of TRACKED joints, 6 Hz
filter, placement at the crossing instant, the paper's exclusion of the first left step
and first right stride, lengths and widths along the walkway axis of a Kinect frame
registered to the reference with a 1.5° yaw), step-level ICC(A,1) / bias (cm),
simulation (mean over seeds 0–4, the bench's reported figure) vs paper:

* two-sided: step length L 0.82 / 0.15 vs 0.83 / 0.41, R 0.81 / −0.32 vs 0.80 / 0.34;
  step width L 0.67 / −1.74 vs 0.675 / −1.57, R 0.65 / 1.94 vs 0.65 / 2.24.
* one-sided (left sensors): step length L 0.71 / −1.11 vs 0.649 / −1.10, R 0.70 / 0.96
  vs 0.434 / 1.73; step width L 0.55 / −1.56 vs 0.493 / −1.49, R 0.54 / 1.99 vs
  0.297 / 2.68. One-sided is worse than two-sided in every row, as in the paper; six of
  the eight rows are within the band (ICC ± 0.1, bias ± 1 cm).

Known gap: the paper's much worse one-sided agreement of RIGHT steps than left steps
(ICC 0.43 vs 0.65 for length, 0.30 vs 0.49 for width) is not reproduced, and cannot be by
any per-foot error model under the paper's step definition: every step is the difference
of one left and one right placement, so with independent placement errors left and right
steps have the same error variance whichever foot is measured worse. It needs an error
the far foot's placement shares with the NEXT near-foot placement only (Table 2's strides
put the large error on the NEAR foot's placements); the optional ``far_leg_refit_sd_m``
(a lower-body fit shift renewed at each landing of the far foot, per sensor or, with
``far_leg_refit_shared``, common to one side's sensors) is such an effect and reproduces
the one-sided rows, but degrades the two-sided step lengths below the paper's and our
estimator's agreement far below its acceptance (it takes each leg from the sensors facing
it, so it inherits the near-leg shift in full), so it is off (``docs/simulation.md``,
"Error budget" and "One-sided right steps").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

from engine.errors import InputError
from engine.geometry import transform_points
from engine.sim.rig import Rig, SimSensor
from engine.sim.walker import Walker
from engine.skeleton import KINECT_V2, SkeletonSeries, TrackingState

FloatArray = NDArray[np.float64]
_JS = KINECT_V2
_N = len(_JS.joints)
_IDX = {n: i for i, n in enumerate(_JS.joints)}

#: joint → +1 (subject's left), −1 (right), 0 (midline)
_SIDE = np.array([1 if n.endswith("Left") else -1 if n.endswith("Right") else 0
                  for n in _JS.joints])
#: permutation that swaps left and right joint labels
_MIRROR = np.array([_IDX[n.replace("Left", "§").replace("Right", "Left").replace("§", "Right")]
                    for n in _JS.joints])
_LOWER_LEG = [_IDX[n] for n in ("KneeLeft", "AnkleLeft", "FootLeft")]
_LOWER_LEG_R = [_IDX[n] for n in ("KneeRight", "AnkleRight", "FootRight")]
#: relative error scale per joint: feet/ankles and hands are fitted worst (Otte 2016;
#: Wang 2015 report the largest errors at ankles/feet and wrists/hands)
_JOINT_SCALE = np.array([
    {"SpineBase": 0.6, "SpineMid": 0.5, "Neck": 0.5, "Head": 0.5, "SpineShoulder": 0.5,
     "HipLeft": 0.7, "HipRight": 0.7, "KneeLeft": 0.8, "KneeRight": 0.8,
     "AnkleLeft": 1.0, "AnkleRight": 1.0, "FootLeft": 1.2, "FootRight": 1.2,
     }.get(n, 1.0) for n in _JS.joints])


@dataclass
class SkeletonErrorModel:
    """Parameters of the simulated Kinect v2 skeleton errors (SI units).

    Attributes:
        ref_distance_m: Distance at which the SDs below apply; errors scale linearly with
            distance (pixel footprint ∝ range; Otte 2016, Wang 2015).
        slow_sd_m: SD along the line of sight of the slowly varying fitting error of an
            ankle at the reference distance (derived from seed 000 Tables 2–3, see module
            doc).
        lateral_ratio: SD across the line of sight relative to along it. Kinect v2 joint
            offsets are often largest along the optical axis (Xu & McGorry 2015, Int J
            Ind Ergon 46:36; Otte 2016), but seed 000's two-sided step-length and
            step-width RPCs (≈ 6 cm and 4–5 cm, the walkway running along the sensors'
            lines of sight) need errors of similar size along and across: 1.0.
        slow_tau_s: Correlation time of that error (≈ the duration of a stance phase:
            the fit error follows the pose, which changes within a gait phase).
        still_speed_m_s: The slow error evolves at the rate ``1/slow_tau_s`` only while
            the body moves at least this fast (mean speed of the 25 joints), slower in
            proportion below it, and not at all while the body stands still. The
            Kinect v2 fits each depth frame on its own (per-pixel body-part
            classification of a single depth image, Shotton et al. 2011, CVPR; no
            temporal model), so an unchanged pose gives the same fit but for the depth
            noise (``jitter_sd_m``): the fit error follows the pose, not the clock. In
            walking (joints ≥ 1 m/s on average) nothing changes; it freezes the error of
            a subject standing still, whose far ankle otherwise wandered 6–9 cm (median
            range over the 1 s standing start, one-sided, ``bench/sim_stance_wander.py``).
            0 restores the clock-driven error.
        jitter_sd_m: Frame-to-frame white jitter per axis at the reference distance
            (Kinect v2 joint jitter a few mm: Otte 2016; Wang 2015).
        surface_bias_near_m: Bias towards the sensor of joints on the body half facing the
            sensor (seed 000 Fig. 5 and supplementary: a few cm between opposite views).
        surface_bias_far_m: Bias towards the sensor of joints on the body half turned away
            (it narrows the step width seen from one side while the near pull widens
            it; slightly smaller than the near pull: seed 000's common step-width bias
            is small and positive, Tables 2–3).
        surface_bias_mid_m: Bias of midline (spine/head) joints.
        far_noise_gain: Extra factor ×(1+g·far) on the slowly varying fit error of joints
            on the turned-away half (Wang 2015: the turned-away half is less accurate;
            seed 000 Fig. 5). Its size is fitted to Table 2's one-sided error variances
            (``bench/gait_error_budget.py``): 1.6 with the jitter not gained, which keeps
            the far side's placement error variance of the former 1.5 on both terms.
        far_jitter_gain: The same factor for the frame-to-frame jitter alone; None: the
            same as ``far_noise_gain`` (the former model). 0: the turned-away half
            jitters like the near one. No source measures a turned-away joint's jitter:
            Wang 2015 report each view's offset distribution (accuracy, not its
            frame-to-frame part), Otte 2016 a few mm of Kinect v2 landmark noise (feet
            and ankles the noisiest, already in the per-joint scale), and a joint is
            estimated from many depth pixels, so a few more noisy pixels at grazing
            incidence hardly move it. The gained jitter made a standing far ankle
            jitter 2–3 cm per frame (``bench/sim_stance_wander.py``). A partly hidden
            joint still jitters more (``partial_occlusion_gain``).
        partial_occlusion_gain: Extra noise factor for joints whose sight line grazes
            another body part (partly hidden limb; Wang 2015: self-occlusion degrades the
            fit before the joint is lost).
        occlusion_pull_m: Extra bias of a partly hidden joint (its sight line grazes
            another body part): the fit is pulled towards the part of the limb that is
            still visible (seed 000 Fig. 5B: estimates lie towards the surface a sensor
            sees).
        occlusion_pull_forward: Fraction of that pull along the body's forward axis
            (towards the sensor's end of the walkway) rather than along the line of
            sight: when the near leg hides the far leg's inner side, what the sensor
            still sees of the far leg is its front (back) surface. This is what gives
            seed 000's one-sided pattern, right (hidden) steps longer and left steps
            shorter (+1.7 / −1.1 cm, Table 2), without narrowing the step width.
        hidden_reported_tracked: Probability that an occlusion episode goes unnoticed:
            the hidden joint is reported TRACKED, with the inferred error and pulled
            ``hidden_pull_m`` towards the occluding surface (seed 000 Discussion: with
            one-sided tracking the occluded leg's inaccurate estimates "propagate directly"
            into the right-side gait parameters).
        hidden_pull_m: See ``hidden_reported_tracked``.
        inferred_sd_m: SD per axis of the extra error of INFERRED joints (inferred
            positions are guesses from the rest of the body; Kinect v2 inferred ankle
            errors ≈ 5–10 cm, Otte 2016).
        occlusion_depth_m: A joint counts as hidden when its sight line passes this deep
            inside another body part: the tracker still fits a limb of which a few cm of
            its ≈ 10 cm wide surface are visible (seed 000 Fig. 5: the far leg is tracked,
            though biased, unless covered).
        inferred_to_untracked_s: An occlusion lasting longer than this turns INFERRED into
            NOT_TRACKED (seed 000).
        occlusion_hangover_s: A joint stays INFERRED this long after it reappears (the
            SDK's temporal filtering).
        acquisition_median_s: Median delay before a body entering the view is reported
            (seed 000: "a few hundred ms"; log-normal, clipped to 0.15–1.5 s).
        acquisition_sigma: Log-normal shape of that delay.
        acquisition_fit_gain: Extra factor on the slowly varying fit error just after
            the body is acquired, decaying with the time since acquisition: the fit error
            is multiplied by ``1 + acquisition_fit_gain · exp(−Δt / acquisition_fit_tau_s)``
            (Δt: time since the first tracked frame of the current tracking episode).
            A tracker that has just found a person fits it worse for a while (seed 000:
            the Kinect "needs some time to recognize a person that enters the volume";
            the SDK's per-person state, e.g. its body-size estimate, is built over the
            first frames). No study found measures the size or the time course of that
            initial error (seed 000 reports only that a delay exists; Otte 2016, Wang
            2015 and Geerse 2015 analyse steady tracking; Geerse 2015 analyse only the
            intermediate 6 m of a 10 m walkway), so it has no literature value: 0 (off)
            by default. Measured as a candidate for seed 000's one-sided right steps in
            ``docs/simulation.md`` ("Acquisition-phase fit error"): it worsens left and
            right steps, one- and two-sided, alike (a sensor's acquisition is not tied
            to one foot), so it stays off. It decays with time, not with movement
            (unlike ``still_speed_m_s``): it is the tracker's state that settles, not the
            pose that changes.
        acquisition_fit_tau_s: e-folding time of that decay (s).
        clipped_fit_gain: Extra factor on the slowly varying fit error of a body partly
            outside the depth frustum: ``1 + clipped_fit_gain · f`` with ``f`` the
            fraction of the 25 joints out of view (the Kinect v2 SDK tracks clipped
            bodies and flags them, ``Body.ClippedEdges``; a fit to part of a body is
            less constrained). No measured size either: 0 (off); measured with the
            acquisition term in ``docs/simulation.md`` (no row moves: bodies are clipped
            only near a sensor, where the next pair tracks them).
        min_joints_in_view: Fraction of the 25 joints that must be in the frustum for a
            body to be detected (Kinect v2 tracks partially visible bodies but needs the
            trunk).
        leg_swap_rate_hz: Rate of brief left/right lower-leg label swaps per second of
            tracking; a swap starts only while the ankles are within 15 cm of each other
            and one of them is partly hidden by the other leg (legs crossing in view),
            where Kinect v2 gait studies report leg-swap outliers (Geerse 2015, Springer
            2016; neither gives a rate). 0.004 /s: at 0.01 /s the swaps landing on
            crossings doubled the simulated two-sided step-length error variance
            (18 cm², robust 5 cm²) against Table 3's 9.3 cm² (bench/gait_error_budget.py).
        leg_swap_duration_s: (min, max) duration of a swap.
        far_leg_refit_sd_m: SD per horizontal axis (at the reference distance) of a
            lower-body fit offset renewed each time the FAR foot (the one on the body half
            turned away from the sensor) lands. Seen from one side, the far leg passes
            behind the near stance leg during its swing and re-appears in front of it when
            it lands; the tracker then fits the lower body to a new visible surface (seed
            000 Fig. 5: the fit follows the visible surface; Discussion: the far leg is
            periodically occluded and the fit biased), and that fit's shift of both legs
            lasts until the far leg is lost and re-acquired at its next landing (a
            hypothesis: no study has measured it directly). The
            renewal falls between a near-foot placement and the next far-foot placement,
            so a far-foot step (near → far placement) spans two fits while a near-foot
            step (far → near) lies within one: far-side steps get worse, near-side steps
            do not (seed 000 Table 2, left sensors: right steps ICC 0.43 / 0.30 vs left
            0.65 / 0.49 for length / width). Off (0) by default: see docs/simulation.md.
        far_leg_refit_lateral_ratio: SD of that shift across the walking direction
            relative to along it.
        far_leg_refit_shared: The re-fit shift is a common cause of all sensors on the
            same side of the subject (they see the same far leg re-appear from behind
            the same near leg, so their fits move alike): drawn once per landing from
            ``observe_skeletons``' ``shared_seed`` instead of per sensor. Without a
            ``shared_seed`` each sensor draws its own.
        mirror_back_facing: Report a subject seen from behind mirrored (left/right
            labels swapped), as the Kinect v2 SDK does.
        back_facing_noise_gain: Noise factor for back-facing subjects.
    """

    ref_distance_m: float = 2.5
    slow_sd_m: float = 0.012
    lateral_ratio: float = 1.0
    slow_tau_s: float = 0.3
    still_speed_m_s: float = 0.5
    jitter_sd_m: float = 0.006
    surface_bias_near_m: float = 0.02
    surface_bias_far_m: float = 0.015
    surface_bias_mid_m: float = 0.01
    far_noise_gain: float = 1.6
    far_jitter_gain: float | None = 0.0
    partial_occlusion_gain: float = 0.5
    occlusion_pull_m: float = 0.03
    occlusion_pull_forward: float = 1.0
    hidden_reported_tracked: float = 0.0
    hidden_pull_m: float = 0.04
    inferred_sd_m: float = 0.06
    occlusion_depth_m: float = 0.025
    inferred_to_untracked_s: float = 0.4
    occlusion_hangover_s: float = 0.07
    acquisition_median_s: float = 0.4
    acquisition_sigma: float = 0.4
    acquisition_fit_gain: float = 0.0
    acquisition_fit_tau_s: float = 1.0
    clipped_fit_gain: float = 0.0
    min_joints_in_view: float = 0.5
    leg_swap_rate_hz: float = 0.004
    leg_swap_duration_s: tuple[float, float] = (0.1, 0.3)
    far_leg_refit_sd_m: float = 0.0
    far_leg_refit_lateral_ratio: float = 1.0
    far_leg_refit_shared: bool = False
    mirror_back_facing: bool = True
    back_facing_noise_gain: float = 1.5

    @classmethod
    def perfect(cls) -> SkeletonErrorModel:
        """No errors at all (occlusion/visibility logic kept, states honest)."""
        return cls(slow_sd_m=0.0, jitter_sd_m=0.0, surface_bias_near_m=0.0,
                   surface_bias_far_m=0.0, surface_bias_mid_m=0.0, occlusion_pull_m=0.0,
                   hidden_pull_m=0.0, inferred_sd_m=0.0,
                   acquisition_median_s=0.0, acquisition_sigma=0.0, leg_swap_rate_hz=0.0,
                   mirror_back_facing=False)


# ---------------------------------------------------------------------- occlusion


def _seg_seg_dist(p0: FloatArray, p1: FloatArray, q0: FloatArray, q1: FloatArray
                  ) -> FloatArray:
    """Distance between segments p0p1 and q0q1 (broadcast over leading axes)."""
    d1 = p1 - p0
    d2 = q1 - q0
    r = p0 - q0
    a = np.sum(d1 * d1, -1)
    e = np.sum(d2 * d2, -1)
    f = np.sum(d2 * r, -1)
    c = np.sum(d1 * r, -1)
    b = np.sum(d1 * d2, -1)
    denom = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denom > 1e-12, np.clip((b * f - c * e) / denom, 0, 1), 0.0)
        t = np.where(e > 1e-12, (b * s + f) / e, 0.0)
        t_c = np.clip(t, 0, 1)
        s = np.where(t < 0, np.clip(-c / np.maximum(a, 1e-12), 0, 1),
                     np.where(t > 1, np.clip((b - c) / np.maximum(a, 1e-12), 0, 1), s))
    diff = p0 + d1 * s[..., None] - (q0 + d2 * t_c[..., None])
    return np.linalg.norm(diff, axis=-1)


def _point_seg_dist(p: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-12), 0, 1)
    return np.linalg.norm(p - (a + ab * t[..., None]), axis=-1)


def occlusion_clearance(origin: FloatArray, joints: FloatArray, A: FloatArray, B: FloatArray,
                        radii: FloatArray) -> FloatArray:
    """How far each joint's line of sight passes outside the other body parts.

    Args:
        origin: (3,) viewpoint (world).
        joints: (T, J, 3) joint positions.
        A, B: (T, C, 3) capsule axis end points; radii: (C,).

    Returns:
        (T, J) clearance (m): the smallest distance between the sight line and the surface
        of a capsule the joint is not part of; negative when the line passes inside one.
    """
    # a capsule the joint lies in (its own limb) cannot occlude it
    inside = _point_seg_dist(joints[:, :, None, :], A[:, None], B[:, None]) <= radii + 0.02
    # stop the sight line short of the joint so surrounding flesh does not count
    v = joints - origin
    dist = np.linalg.norm(v, axis=-1, keepdims=True)
    end = joints - v / dist * 0.06
    o = np.broadcast_to(origin, end.shape)
    d = _seg_seg_dist(o[:, :, None], end[:, :, None], A[:, None], B[:, None]) - radii
    d = np.where(inside, np.inf, d)
    return np.asarray(d.min(axis=-1))


def occluded_joints(origin: FloatArray, joints: FloatArray, A: FloatArray, B: FloatArray,
                    radii: FloatArray, depth_m: float = 0.025) -> NDArray[np.bool_]:
    """Joints whose sight line passes more than ``depth_m`` inside another body part
    (``(T, J)`` bool; see :func:`occlusion_clearance`)."""
    return occlusion_clearance(origin, joints, A, B, radii) < -depth_m


# ---------------------------------------------------------------------- observation


def _ar1(rng: np.random.Generator, shape: tuple[int, ...], a: float,
         rate: FloatArray | None = None) -> FloatArray:
    """Unit-variance AR(1) series along axis 0, coefficient ``a`` per sample.

    With ``rate`` (``(T,)`` in [0, 1]) sample k advances by only ``rate[k]`` of a sample
    (coefficient ``a**rate[k]``): 0 holds the previous value. The random draws are the
    same with or without ``rate``, so a rate of 1 throughout gives the plain series.
    """
    g = np.sqrt(max(1.0 - a * a, 0.0))
    w = rng.standard_normal(shape) * g
    w[0] = rng.standard_normal(shape[1:])
    if rate is None or np.all(rate >= 1.0):
        return np.asarray(lfilter([1.0], [1.0, -a], w, axis=0))
    ak = np.power(a, np.clip(rate, 0.0, 1.0))
    # the same unit draws, scaled for each sample's own coefficient
    gk = np.sqrt(np.maximum(1.0 - ak * ak, 0.0)) / g if g > 0 else np.zeros_like(ak)
    x = np.empty(shape)
    x[0] = w[0]
    for k in range(1, shape[0]):
        x[k] = ak[k] * x[k - 1] + gk[k] * w[k]
    return x


def _runs_longer(mask: NDArray[np.bool_], times: FloatArray, dur: float) -> NDArray[np.bool_]:
    """Per column, True where ``mask`` has been continuously True for more than ``dur``."""
    T = len(times)
    out = np.zeros_like(mask)
    start = np.full(mask.shape[1:], np.nan)
    for k in range(T):
        m = mask[k]
        start = np.where(m, np.where(np.isnan(start), times[k], start), np.nan)
        out[k] = m & (times[k] - start > dur)
    return out


#: lower-body joints shifted together by a far-leg re-fit
_LEGS = [_IDX[n + sd] for n in ("Hip", "Knee", "Ankle", "Foot") for sd in ("Left", "Right")]
#: a foot has landed when its ankle, after moving faster than the first speed (swing),
#: slows below the second (m/s, horizontal)
_SWING_SPEED, _STANCE_SPEED = 1.5, 0.3


def _far_leg_refit(t: FloatArray, J: FloatArray, far: FloatArray, fwd: FloatArray,
                   scale_d: FloatArray, sd: float, lateral_ratio: float,
                   rng: np.random.Generator, shared_seed: int | None = None) -> FloatArray:
    """``(T, 3)`` horizontal lower-body offset, redrawn at each landing of the far foot
    (see ``SkeletonErrorModel.far_leg_refit_sd_m``): SD ``sd`` along the body's forward
    axis ``fwd`` (T, 3) and ``lateral_ratio·sd`` across it, scaled with the distance at
    the landing like the other fit errors. With ``shared_seed`` the draw of the n-th
    landing of a foot is the same for every sensor that has that foot as its far foot
    (``SkeletonErrorModel.far_leg_refit_shared``)."""
    T = len(t)
    landings: list[tuple[int, int, int]] = []  # (sample, foot 0/1, landing number)
    for f_i, side in enumerate(("Left", "Right")):
        a = _IDX["Ankle" + side]
        sp = np.linalg.norm(np.gradient(J[:, a, :2], t, axis=0), axis=1)
        armed = False
        n = 0
        for k in range(T):
            if sp[k] > _SWING_SPEED:
                armed = True
            elif armed and sp[k] < _STANCE_SPEED:
                armed = False
                n += 1
                # shared: every landing of the foot on the side turned away from this
                # side of the walkway (the same events for all sensors there)
                if far[k, a] > (0.0 if shared_seed is not None else 0.5):
                    landings.append((k, f_i, n))
    landings.sort()
    land = np.array([x[0] for x in landings], dtype=int)
    piece = np.searchsorted(land, np.arange(T), side="right")
    starts = np.concatenate([[0], land]).astype(int)
    if shared_seed is None:
        unit = rng.standard_normal((len(starts), 2))
    else:
        # the n-th landing of a foot: the same draw for all sensors on its far side
        unit = np.array([np.random.default_rng([shared_seed, 0, 0]).standard_normal(2)]
                        + [np.random.default_rng([shared_seed, f_i + 1, n]).standard_normal(2)
                           for _, f_i, n in landings]).reshape(-1, 2)
    z = unit * (sd * scale_d[starts])[:, None]
    f = fwd[starts]
    lat = np.stack([-f[:, 1], f[:, 0], np.zeros(len(f))], axis=1)
    off = z[:, :1] * f + lateral_ratio * z[:, 1:] * lat
    return np.asarray(off[piece])


def acquisition_gain(t: FloatArray, acquired_at: FloatArray, gain: float, tau_s: float
                     ) -> FloatArray:
    """Factor on the slow fit error after acquisition (``acquisition_fit_gain``).

    Args:
        t: ``(T,)`` times (s, the sensor's true time axis).
        acquired_at: ``(T,)`` start time of the tracking episode each sample belongs to
            (s), NaN where untracked.
        gain: Extra factor at the instant of acquisition (≥ 0).
        tau_s: e-folding time of its decay (s, > 0).

    Returns:
        ``(T,)`` factor ``1 + gain · exp(−(t − acquired_at) / tau_s)``; 1 where
        ``acquired_at`` is NaN (body not tracked) or ``gain`` is 0.

    Raises:
        InputError: ``gain`` < 0 or ``tau_s`` ≤ 0.
    """
    if gain < 0 or tau_s <= 0:
        raise InputError("acquisition_fit_gain must be ≥ 0 and acquisition_fit_tau_s > 0")
    since = np.asarray(t, dtype=float) - np.asarray(acquired_at, dtype=float)
    env = np.where(np.isnan(since), 0.0, np.exp(-np.clip(np.nan_to_num(since), 0.0, None)
                                                / tau_s))
    return np.asarray(1.0 + gain * env)


def observe_skeletons(
    sensor: SimSensor,
    rig: Rig | None,
    walker: Walker,
    times_true: NDArray[np.float64],
    rng: np.random.Generator,
    model: SkeletonErrorModel | None = None,
    body_id: int = 0,
    shared_seed: int | None = None,
) -> SkeletonSeries:
    """The skeleton stream one sensor reports for one walker.

    Args:
        sensor: The observing sensor.
        rig: The rig (unused by the model itself; kept for the API and future room
            occluders).
        walker: The subject.
        times_true: ``(T,)`` strictly increasing true capture times (e.g. from
            :func:`engine.sim.clock.frame_times`).
        rng: Random generator (all randomness of this observation).
        model: Error model (default :class:`SkeletonErrorModel`).
        body_id: Body index reported in ``meta``.
        shared_seed: Seed of the random numbers that all sensors observing the same
            walk share (errors with a common cause, ``far_leg_refit_shared``); None:
            every draw comes from ``rng``.

    Returns:
        A :class:`SkeletonSeries` in the SENSOR (depth camera) frame, metres, one row per
        frame; frames without a tracked body have every joint NOT_TRACKED and NaN.
        ``times`` are the sensor's LOCAL clock times; ``meta`` holds ``sensor_id``,
        ``frame`` ("sensor"), ``times_true``, ``times_local``, ``body_tracked`` (T,) bool,
        ``mirrored`` (T,) bool (labels swapped because seen from behind),
        ``leg_swapped`` (T,) bool (lower-leg labels swapped by a fitting failure),
        ``hidden_tracked`` (T, 25) bool (occluded but reported TRACKED), ``occluded``
        (T, 25) bool (ground-truth occlusion), ``acquired_at`` (T,) true time of the
        current tracking episode's first frame (NaN while untracked) and ``body_id``.
    """
    m = model or SkeletonErrorModel()
    t = np.asarray(times_true, dtype=float)
    if t.ndim != 1 or (len(t) > 1 and not np.all(np.diff(t) > 0)):
        raise InputError("times_true must be a strictly increasing 1-D array")
    T = len(t)
    o = sensor.position
    J = walker.joints(t)
    A, B, radii = walker.capsule_segments(t)
    in_view = sensor.in_depth_view(J, margin_px=2.0)
    clearance = occlusion_clearance(o, J, A, B, radii)
    occl = (clearance < -m.occlusion_depth_m) & in_view
    # partly hidden joints (sight line grazing another part) are fitted less well
    partial = np.clip((m.occlusion_depth_m + 0.05 - clearance) / 0.075, 0.0, 1.0)
    dist = np.linalg.norm(J - o, axis=-1)

    # ---- body detection with acquisition delay
    trunk = in_view[:, _IDX["SpineBase"]] & in_view[:, _IDX["SpineMid"]]
    detectable = trunk & (in_view.mean(axis=1) >= m.min_joints_in_view)
    tracked = np.zeros(T, dtype=bool)
    # start of the current tracking episode (first tracked frame), NaN while untracked
    acquired_at = np.full(T, np.nan)
    seen_since = np.nan
    delay = 0.0
    for k in range(T):
        if not detectable[k]:
            seen_since = np.nan
            continue
        if np.isnan(seen_since):
            seen_since = t[k]
            delay = 0.0 if m.acquisition_median_s <= 0 else float(np.clip(
                m.acquisition_median_s * np.exp(m.acquisition_sigma * rng.standard_normal()),
                0.15, 1.5))
        tracked[k] = t[k] - seen_since >= delay
        if tracked[k]:
            acquired_at[k] = t[k] if k == 0 or not tracked[k - 1] else acquired_at[k - 1]

    # ---- geometry of the view: which body half faces the sensor, back-facing
    fr = walker.bone_frames(t)["pelvis"]
    fwd = fr[:, :3, 0].copy()
    left = fr[:, :3, 1].copy()
    fwd[:, 2] = 0.0
    left[:, 2] = 0.0
    fwd /= np.linalg.norm(fwd, axis=1, keepdims=True)
    left /= np.linalg.norm(left, axis=1, keepdims=True)
    to_sensor = o - J  # (T, J, 3)
    u = to_sensor / np.linalg.norm(to_sensor, axis=-1, keepdims=True)
    u_h = u.copy()
    u_h[..., 2] = 0.0
    u_h /= np.maximum(np.linalg.norm(u_h, axis=-1, keepdims=True), 1e-9)
    facing_side = np.einsum("tjk,tk->tj", u_h, left) * _SIDE  # >0: joint's half faces sensor
    # a limb counts as fully turned away/towards once seen ≥ 30° from the side (the view
    # angles at which Wang 2015 found the turned-away half degraded)
    far = np.clip(-2.0 * facing_side, 0.0, 1.0)
    near = np.clip(2.0 * facing_side, 0.0, 1.0)
    back = np.einsum("tk,tk->t", u_h[:, _IDX["SpineBase"]], fwd) < -0.2

    # ---- errors (world frame)
    scale = dist / m.ref_distance_m * _JOINT_SCALE
    back_gain = np.where(back, m.back_facing_noise_gain, 1.0)[:, None]
    gain = (1.0 + m.far_noise_gain * far + m.partial_occlusion_gain * partial) * back_gain
    g_jit = m.far_noise_gain if m.far_jitter_gain is None else m.far_jitter_gain
    gain_jitter = (1.0 + g_jit * far + m.partial_occlusion_gain * partial) * back_gain
    dt = float(np.median(np.diff(t))) if T > 1 else 1.0 / 30.0
    a = float(np.exp(-dt / m.slow_tau_s)) if m.slow_tau_s > 0 else 0.0
    def aniso(n: FloatArray) -> FloatArray:
        # full SD along the line of sight, lateral_ratio × SD across it
        return m.lateral_ratio * n + (1.0 - m.lateral_ratio) * np.sum(n * u, -1,
                                                                      keepdims=True) * u

    # the fit error follows the pose: it evolves while the body moves (see
    # SkeletonErrorModel.still_speed_m_s)
    rate = None
    if m.still_speed_m_s > 0 and T > 1:
        speed = np.linalg.norm(np.gradient(J, t, axis=0), axis=-1).mean(axis=1)
        rate = np.clip(speed / m.still_speed_m_s, 0.0, 1.0)
    slow = aniso(_ar1(rng, (T, _N, 3), a, rate)) * (m.slow_sd_m * scale * gain)[..., None]
    # a fresh fit, or a fit to a clipped body, is worse; no new random draws, so the
    # other errors are unchanged (common random numbers with the terms off)
    if m.acquisition_fit_gain != 0:
        slow *= acquisition_gain(t, acquired_at, m.acquisition_fit_gain,
                                 m.acquisition_fit_tau_s)[:, None, None]
    if m.clipped_fit_gain != 0:
        if m.clipped_fit_gain < 0:
            raise InputError("clipped_fit_gain must be ≥ 0")
        slow *= (1.0 + m.clipped_fit_gain * (1.0 - in_view.mean(axis=1)))[:, None, None]
    jitter = (aniso(rng.standard_normal((T, _N, 3)))
              * (m.jitter_sd_m * scale * gain_jitter)[..., None])
    beta = np.where(_SIDE == 0, m.surface_bias_mid_m,
                    m.surface_bias_near_m * near + m.surface_bias_far_m * far
                    + m.surface_bias_near_m * (1 - near - far))
    bias = u_h * beta[..., None]
    # a partly hidden joint is fitted to what is still visible of its limb: along the
    # line of sight, turning to the body's forward axis (its front/back surface)
    along = np.sign(np.einsum("tjk,tk->tj", u_h, fwd))[..., None] * fwd[:, None, :]
    g = m.occlusion_pull_forward
    bias = bias + ((1.0 - g) * u_h + g * along) * (m.occlusion_pull_m * partial)[..., None]
    est = J + bias + slow + jitter
    if m.far_leg_refit_sd_m > 0 and T > 1:
        est[:, _LEGS] += _far_leg_refit(
            t, J, far, fwd, scale_d=dist[:, _IDX["SpineBase"]] / m.ref_distance_m,
            sd=m.far_leg_refit_sd_m, lateral_ratio=m.far_leg_refit_lateral_ratio,
            rng=rng, shared_seed=shared_seed if m.far_leg_refit_shared else None,
        )[:, None, :]

    # ---- occlusion → inferred / not tracked
    recent = np.zeros_like(occl)
    hang = max(round(m.occlusion_hangover_s / dt), 0)
    for s in range(hang + 1):
        recent[s:] |= occl[: T - s] if s else occl
    inferred = recent & in_view
    untracked = _runs_longer(occl, t, m.inferred_to_untracked_s) | ~in_view
    if m.inferred_sd_m > 0:
        a_inf = float(np.exp(-dt / 0.3))
        est = est + inferred[..., None] * _ar1(rng, (T, _N, 3), a_inf) * m.inferred_sd_m

    # some occlusion episodes are not recognised: the joint is reported TRACKED at a
    # confident but wrong position on the occluding surface in front of it
    hidden_tracked = np.zeros_like(occl)
    if m.hidden_reported_tracked > 0 and np.any(occl):
        start = occl & ~np.vstack([np.zeros((1, _N), dtype=bool), occl[:-1]])
        run = np.cumsum(start, axis=0)
        lucky = rng.random((int(run.max()) + 1, _N)) < m.hidden_reported_tracked
        hidden_tracked = occl & lucky[run, np.arange(_N)]
        est = est + hidden_tracked[..., None] * u_h * m.hidden_pull_m

    states = np.full((T, _N), TrackingState.TRACKED, dtype=np.uint8)
    states[inferred] = TrackingState.INFERRED
    states[untracked] = TrackingState.NOT_TRACKED
    states[hidden_tracked] = TrackingState.TRACKED

    # ---- fitting failures: mirrored when seen from behind, brief leg swaps
    mirrored = back & tracked if m.mirror_back_facing else np.zeros(T, dtype=bool)
    est[mirrored] = est[mirrored][:, _MIRROR]
    states[mirrored] = states[mirrored][:, _MIRROR]
    swapped = np.zeros(T, dtype=bool)
    if m.leg_swap_rate_hz > 0 and T > 1:
        gap = np.linalg.norm(J[:, _IDX["AnkleLeft"], :2] - J[:, _IDX["AnkleRight"], :2], axis=1)
        hidden = np.maximum(partial[:, _IDX["AnkleLeft"]], partial[:, _IDX["AnkleRight"]])
        cand = np.nonzero(tracked & (gap < 0.15) & (hidden > 0.5))[0]
        n_ev = rng.poisson(m.leg_swap_rate_hz * dt * int(tracked.sum())) if len(cand) else 0
        for _ in range(n_ev):
            t0 = t[rng.choice(cand)]
            dur = rng.uniform(*m.leg_swap_duration_s)
            swapped |= (t >= t0) & (t < t0 + dur) & tracked
        idx = np.nonzero(swapped)[0][:, None]
        le, ri = est[idx, _LOWER_LEG].copy(), est[idx, _LOWER_LEG_R].copy()
        est[idx, _LOWER_LEG], est[idx, _LOWER_LEG_R] = ri, le
        sl, sr = states[idx, _LOWER_LEG].copy(), states[idx, _LOWER_LEG_R].copy()
        states[idx, _LOWER_LEG], states[idx, _LOWER_LEG_R] = sr, sl

    states[~tracked] = TrackingState.NOT_TRACKED
    est[states == TrackingState.NOT_TRACKED] = np.nan
    pos = transform_points(sensor.T_sensor_world, est)
    t_local = np.asarray(sensor.clock.local(t), dtype=float).reshape(-1)
    meta: dict[str, Any] = {
        "sensor_id": sensor.id, "frame": "sensor", "units": "m", "body_id": body_id,
        "times_true": t.copy(), "times_local": t_local, "body_tracked": tracked,
        "mirrored": mirrored, "leg_swapped": swapped, "occluded": occl,
        "hidden_tracked": hidden_tracked, "acquired_at": acquired_at,
    }
    return SkeletonSeries(times=t_local, positions=pos, states=states, joint_set=_JS,
                          meta=meta)


def observation_errors(series: SkeletonSeries, sensor: SimSensor, walker: Walker
                       ) -> FloatArray:
    """``(T, 25, 3)`` world-frame error (estimate − truth) of a sensor's series.

    Joints that are not TRACKED are NaN; mirrored frames are compared label-for-label
    (so they show as large errors).
    """
    t = np.asarray(series.meta["times_true"], dtype=float)
    est = transform_points(sensor.T_world_sensor, series.tracked_positions())
    return est - walker.joints(t)
