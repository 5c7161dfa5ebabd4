"""Spatiotemporal gait parameters from per-foot trajectories.

Two event definitions (``method``):

* ``"crossing"`` — the seed paper's: a foot placement happens when one ankle passes the
  other along the walking direction. The foot that is passed is the one on the floor
  (the placed foot); its position at that instant is the placement.
* ``"heelstrike"`` — Zeni et al. (2008): foot strike at the maximum, foot off at the
  minimum of the heel (toe for foot off) position relative to the pelvis along the
  walking direction; each refined within a bounded window: the strike to the heel's
  landing (when it stops descending), the foot off to the toe's fastest rise (O'Connor et al.
  2007), with sub-frame interpolation.

Steps are assigned to the foot placed last (paper, Fig. 6): the step ending at a
placement/strike of foot B measures B relative to the other foot A: length along the
walking direction, width perpendicular to it on the floor, duration since A's event.
Strides join two events of the same foot. Walking speed is Σ step lengths / Σ step
times. The walking direction is found per straight pass (back-and-forth walks are split
at turns, and turns are dropped).
"""

from __future__ import annotations

import itertools
import json
import os
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from engine.errors import InputError, InsufficientDataError
from engine.io.markers import MarkerEvent, MarkerTrajectories
from engine.mocap import FeetTrajectories, feet_from_markers, feet_from_skeleton, load_feet
from engine.skeleton import SkeletonSeries
from engine.wording import count

FloatArray = NDArray[np.float64]
Method = Literal["crossing", "heelstrike"]
#: The tables :meth:`GaitAnalysis.to_records` gives.
Table = Literal["steps", "strides", "events", "passes", "summary"]

#: Below this centre speed (m/s) a subject is standing, not walking.
MIN_WALK_SPEED = 0.15
#: Heading change rate (deg/s) of the smoothed body centre above which it is turning.
MAX_STRAIGHT_TURN_RATE = 60.0
#: A pass shorter than this (s) or travelling less than MIN_PASS_M is dropped.
MIN_PASS_S = 0.8
MIN_PASS_M = 0.5
#: Consecutive foot placements closer than this fraction of the median step time, or
#: than MIN_STEP_S, are a glitch (a step is ≥ 0.25 s even at a running cadence of
#: 240 steps/min; step-time CV in gait is ≈ 3-10 %, so 40 % of the median is never a step).
MIN_STEP_FRACTION = 0.4
MIN_STEP_S = 0.2
#: Stance samples further than this (m, on the floor) from the median of the placement
#: window are outliers: ≈ 3 SD of a Kinect ankle's per-sample error (1–2 cm), far less
#: than the ≥ 10 cm a leg-label swap moves a foot.
STANCE_OUTLIER_M = 0.05
#: The stance average of a placement extends beyond ``placement_window_s`` while the
#: foot stays put, up to this far (s) from the crossing: the crossing falls near
#: mid-stance, and a stance lasts ≈ 0.6 s at ordinary speeds and up to ≈ 1 s when
#: walking slowly (≈ 60 % of the gait cycle; Perry & Burnfield, *Gait Analysis*, 2nd ed.).
STANCE_MAX_HALF_S = 0.5
#: The heel has landed when its downward velocity has fallen below this fraction of its
#: peak descent in late swing (see GaitAnalysis._refine_strike).
HEEL_STOP_FRACTION = 0.05
#: A placed foot stands still: at a crossing, the slower foot moving faster than this
#: fraction of the walking speed means the crossing is a tracking glitch (our analysis
#: only; the paper's rule keeps every crossing).
MAX_PLACED_SPEED_FRACTION = 0.5
#: Steps or strides longer than this multiple of the pass's median span missed events.
MAX_DURATION_RATIO = 2.0
#: A start from standing: both feet within STANDING_TOL_M of their place for at least
#: STANDING_MIN_S before the first swing. The tolerance is ≈ 3 SD of a fused Kinect
#: ankle's slowly varying error (2–3 cm) and well below the STANDING_LEFT_M that a
#: swinging foot covers within 0.1 s.
STANDING_TOL_M = 0.08
#: ... and the body centre progressing less than this (m) over that time (< 0.2 m/s,
#: a sixth of a comfortable walking speed).
STANDING_CENTRE_M = 0.04
STANDING_MIN_S = 0.3
#: A foot has left its standing place once it is this far ahead of it (m).
STANDING_LEFT_M = 0.1
#: How far back (s) before the first crossing a pass's standing start is looked for.
STANDING_LOOKBACK_S = 2.5
#: Gaps (s) in the body centre shorter than this do not split a straight pass: a
#: sensor group on one side loses the far ankle for ≈ 0.2-0.4 s as it passes behind the
#: near leg, which split a pass at every hidden crossing (a stride is ≥ 0.8 s, so a gap
#: this short cannot hide a turn).
MAX_CENTRE_GAP_S = 0.5


@dataclass(frozen=True)
class GaitEvent:
    """A detected gait event.

    Attributes:
        side: ``"L"`` or ``"R"``.
        kind: ``"placement"`` (method ``crossing``), ``"foot_strike"`` or ``"foot_off"``
            (method ``heelstrike``) — the kinds of :class:`engine.io.markers.MarkerEvent`,
            so :func:`engine.agreement.match_events` pairs them with a file's annotations.
        time_s: seconds on the input's time axis.
        pass_index: index of the straight pass in :attr:`GaitAnalysis.passes_`.
    """

    side: str  # "L" | "R"
    kind: str  # "foot_strike" | "foot_off" | "placement"
    time_s: float
    pass_index: int = 0


@dataclass(frozen=True)
class Step:
    """One step, assigned to the foot placed at its end (``side``; seed 000, Fig. 6).

    Attributes:
        side: the foot placed at the end of the step, ``"L"`` or ``"R"``.
        time_s: time of that placement / foot strike (s, the input's time axis).
        length_m: distance between the two feet along the pass's walking direction (m).
        width_m: distance between them perpendicular to it, on the floor (m, ≥ 0).
        duration_s: step time, since the other foot's previous event (s).
        pass_index: index of the straight pass in :attr:`GaitAnalysis.passes_`.
    """

    side: str
    time_s: float
    length_m: float
    width_m: float
    duration_s: float
    pass_index: int = 0


@dataclass(frozen=True)
class Stride:
    """One stride: two successive events of the same foot.

    Attributes:
        side: the foot, ``"L"`` or ``"R"``.
        time_s: time of the stride's second event (s, the input's time axis).
        length_m: distance between the two footprints along the walking direction (m).
        duration_s: stride time (s).
        pass_index: index of the straight pass in :attr:`GaitAnalysis.passes_`.
    """

    side: str
    time_s: float
    length_m: float
    duration_s: float
    pass_index: int = 0


@dataclass(frozen=True)
class WalkPass:
    """A straight walking segment and its direction on the floor.

    Attributes:
        t_start, t_end: its span (s, the input's time axis).
        direction: unit ``(x, y)`` walking direction on the floor (world frame, Z up).
        excluded_first: its first step/stride were dropped (``exclude_first``).
    """

    t_start: float
    t_end: float
    direction: tuple[float, float]
    excluded_first: bool = False


@dataclass
class _PassEvents:
    placements: list[tuple[str, float, FloatArray, FloatArray]] = field(default_factory=list)
    offs: list[tuple[str, float]] = field(default_factory=list)
    #: placements[0] is the standing foot's placement of a start from standing
    from_standing: bool = False


def _interp_rows(t: FloatArray, x: FloatArray, tq: float) -> FloatArray:
    return np.array([np.interp(tq, t, x[:, k]) for k in range(x.shape[1])])


def _interp_across(t: FloatArray, x: FloatArray, tq: float, max_gap_s: float) -> FloatArray:
    """``x`` at ``tq`` from its finite rows: linear between the finite rows on either side
    when they are at most ``max_gap_s`` apart (a foot hidden for a moment at a crossing),
    NaN otherwise."""
    ok: NDArray[np.bool_] = np.asarray(np.isfinite(x).all(axis=1), dtype=bool)
    j = int(np.searchsorted(t, tq))
    if j < len(t) and t[j] == tq and ok[j]:
        return np.array(x[j], dtype=float)
    before = np.flatnonzero(ok[:j])
    after = np.flatnonzero(ok[j:])
    if len(before) == 0 or len(after) == 0:
        return np.full(x.shape[1], np.nan)
    a, b = int(before[-1]), j + int(after[0])
    if t[b] - t[a] > max(max_gap_s, 1.5 * float(np.median(np.diff(t)))):
        return np.full(x.shape[1], np.nan)
    u = (tq - t[a]) / (t[b] - t[a]) if t[b] > t[a] else 0.0
    return np.asarray((1.0 - u) * x[a] + u * x[b], dtype=float)


def _nan_fill(t: FloatArray, x: FloatArray) -> FloatArray:
    """NaNs replaced by linear interpolation/edge values (for smoothing only)."""
    out = np.array(x, dtype=float, copy=True)
    for k in range(out.shape[1]):
        ok = np.isfinite(out[:, k])
        if ok.sum() >= 2 and not ok.all():
            out[~ok, k] = np.interp(t[~ok], t[ok], out[ok, k])
    return out


def _bridge_short_gaps(times: FloatArray, ok: NDArray[np.bool_], max_gap_s: float
                       ) -> NDArray[np.bool_]:
    """``ok`` with its interior runs of False spanning less than ``max_gap_s`` (from the
    last good sample before to the first after) set True."""
    out = np.array(ok, dtype=bool, copy=True)
    good = np.flatnonzero(ok)
    for a, b in itertools.pairwise(good):
        if b > a + 1 and times[b] - times[a] < max_gap_s:
            out[a + 1:b] = True
    return out


def find_passes(times: FloatArray, centre: FloatArray, rate: float) -> list[WalkPass]:
    """Split a recording into straight walking passes.

    The horizontal body centre is smoothed over ~0.8 s (about one stride, which removes
    the side-to-side sway of each step); samples faster than :data:`MIN_WALK_SPEED` and
    turning slower than :data:`MAX_STRAIGHT_TURN_RATE` form straight runs (gaps in the
    centre shorter than :data:`MAX_CENTRE_GAP_S` are bridged); a run's direction is its
    principal axis on the floor, oriented along its travel.

    Args:
        times: ``(T,)`` seconds.
        centre: ``(T, 3)`` body centre (pelvis or mid-feet), Z up.
        rate: sampling rate (Hz).

    Returns:
        The straight passes in time order (start and end times in s, unit direction
        on the floor).
    """
    ok: NDArray[np.bool_] = np.asarray(np.isfinite(centre[:, :2]).all(axis=1), dtype=bool)
    if ok.sum() < 3:
        return []
    c = _nan_fill(times, centre[:, :2])
    c[: np.argmax(ok)] = c[np.argmax(ok)]
    ok = _bridge_short_gaps(times, ok, MAX_CENTRE_GAP_S)
    # scipy where it is used: the server imports this module at start and needs none
    from scipy.ndimage import uniform_filter1d

    win = max(3, round(0.8 * rate))
    cs = uniform_filter1d(c, win, axis=0, mode="nearest")
    # Velocity and turn rate over ±0.25 s baselines: per-sample derivatives of noisy
    # positions would split a straight pass at every noise spike.
    k = max(1, round(0.25 * rate))
    n = len(times)
    ia = np.clip(np.arange(n) - k, 0, n - 1)
    ib = np.clip(np.arange(n) + k, 0, n - 1)
    dt = np.maximum(times[ib] - times[ia], 1e-9)
    v = (cs[ib] - cs[ia]) / dt[:, None]
    speed = np.linalg.norm(v, axis=1)
    heading = np.unwrap(np.arctan2(v[:, 1], v[:, 0]))
    turn = np.degrees(np.abs(heading[ib] - heading[ia]) / dt)
    straight = (speed > MIN_WALK_SPEED) & (turn < MAX_STRAIGHT_TURN_RATE) & ok
    passes: list[WalkPass] = []
    idx = np.flatnonzero(straight)
    if len(idx) == 0:
        return []
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    # Re-join runs split by a short interruption (< 0.3 s) without a change of heading.
    merged = [runs[0]]
    for r in runs[1:]:
        prev = merged[-1]
        dh = np.degrees(abs(np.angle(np.exp(1j * (heading[r[0]] - heading[prev[-1]])))))
        if times[r[0]] - times[prev[-1]] < 0.3 and dh < 30.0:
            merged[-1] = np.arange(prev[0], r[-1] + 1)
        else:
            merged.append(r)
    runs = merged
    for r in runs:
        # The ±k baselines blur a run's ends into the standing/turning around it.
        if r[0] > 0:
            r = r[k:]
        if len(r) and r[-1] < n - 1 and len(r) > k:
            r = r[:-k]
        if len(r) < 3:
            continue
        t0, t1 = times[r[0]], times[r[-1]]
        seg = c[r]
        travel = cs[r[-1]] - cs[r[0]]
        if t1 - t0 < MIN_PASS_S or np.linalg.norm(travel) < MIN_PASS_M:
            continue
        d = seg - seg.mean(axis=0)
        _, _, vt = np.linalg.svd(d, full_matrices=False)
        u = vt[0] / np.linalg.norm(vt[0])
        if u @ travel < 0:
            u = -u
        # A pass that begins at the first sample with the subject already at speed (its
        # first 0.5 s cover ≥ 80 % of the distance the pass's mean speed would) did not
        # start from standing: its first step is a normal one. Raw positions, not the
        # smoothed ones, whose edge padding slows the first samples down.
        t_a = min(t0 + 0.5, t1)
        k_a = int(np.searchsorted(times, t_a))
        v_start = float((c[min(k_a, r[-1])] - c[r[0]]) @ u) / max(t_a - t0, 1e-9)
        v_pass = float((c[r[-1]] - c[r[0]]) @ u) / (t1 - t0)
        started_moving = bool(r[0] == np.argmax(ok) and v_start >= 0.8 * v_pass)
        passes.append(WalkPass(float(t0), float(t1), (float(u[0]), float(u[1])),
                               excluded_first=not started_moving))
    return passes


def _segments(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    idx = np.flatnonzero(mask)
    if len(idx) == 0:
        return []
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    return [(int(r[0]), int(r[-1]) + 1) for r in runs]


def _peaks(t: FloatArray, y: FloatArray, rate: float, height: float, prominence: float,
           min_period_s: float) -> list[float]:
    """Sub-frame times of the local maxima of ``y`` (NaN-safe).

    A height threshold (rather than prominence alone) keeps peaks near the start of a
    recording, whose left flank is cut off and whose prominence is therefore small.
    """
    from scipy.signal import find_peaks

    out: list[float] = []
    for a, b in _segments(np.isfinite(y)):
        seg = y[a:b]
        if len(seg) < 3:
            continue
        pk, _ = find_peaks(seg, height=height, prominence=prominence,
                           distance=max(1, round(min_period_s * rate)))
        for p in pk:
            i = a + p
            if 0 < p < len(seg) - 1:
                y0, y1, y2 = y[i - 1], y[i], y[i + 1]
                den = y0 - 2 * y1 + y2
                off = 0.5 * (y0 - y2) / den if den != 0 else 0.0
                off = float(np.clip(off, -0.5, 0.5))
                out.append(float(t[i] + off * (t[i + 1] - t[i - 1]) / 2))
            else:
                out.append(float(t[i]))
    return out


@dataclass(frozen=True)
class GaitCycle:
    """One gait cycle of a foot: from its strike to its next strike, with its foot off.

    Attributes:
        side: the foot, ``"L"`` or ``"R"``.
        time_s: its foot strike that starts the cycle (s, the input's time axis).
        duration_s: to the same foot's next strike (stride time, s).
        stance_s: strike to foot off (s); swing is ``duration_s - stance_s``.
        double_support_s: both feet on the floor within the cycle (s): from the strike to
            the other foot's off, plus from the other foot's strike to this foot's off;
            None when the other foot's events are not both found in between.
    """

    side: str
    time_s: float
    duration_s: float
    stance_s: float
    double_support_s: float | None

    @property
    def stance_pct(self) -> float:
        """Stance in % of the cycle."""
        return 100.0 * self.stance_s / self.duration_s

    @property
    def swing_pct(self) -> float:
        """Swing in % of the cycle."""
        return 100.0 - self.stance_pct

    @property
    def double_support_pct(self) -> float | None:
        """Double support in % of the cycle (None when not computable)."""
        if self.double_support_s is None:
            return None
        return 100.0 * self.double_support_s / self.duration_s


#: A strike-to-strike interval longer than this (s) spans missed events, not one cycle.
MAX_CYCLE_S = 2.5


def gait_cycles(events: list[Any]) -> list[GaitCycle]:
    """Gait cycles from foot strikes and foot offs (``side``, ``kind``, ``time_s``).

    A cycle runs from a foot's strike to its next strike (at most :data:`MAX_CYCLE_S`)
    with exactly one foot off of that foot in between; other cycles (a missed or extra
    event) are left out. Works on :class:`GaitEvent` and on any event objects of the same
    shape (e.g. :class:`engine.io.markers.MarkerEvent`, a simulation's true events).

    Args:
        events: gait events, in any order; kinds other than ``"foot_strike"`` and
            ``"foot_off"`` are ignored.

    Returns:
        The cycles of both feet, sorted by their starting strike.
    """
    fs = {s: sorted(e.time_s for e in events if e.kind == "foot_strike" and e.side == s)
          for s in "LR"}
    fo = {s: sorted(e.time_s for e in events if e.kind == "foot_off" and e.side == s)
          for s in "LR"}
    out: list[GaitCycle] = []
    for s in "LR":
        o = "R" if s == "L" else "L"
        for a, b in itertools.pairwise(fs[s]):
            cyc = b - a
            if cyc <= 0 or cyc > MAX_CYCLE_S:
                continue
            offs = [x for x in fo[s] if a < x < b]
            if len(offs) != 1:
                continue
            # Double support: from own strike to the other foot's off, and from the
            # other foot's strike to own off.
            o_off = [x for x in fo[o] if a < x < offs[0]]
            o_fs = [x for x in fs[o] if a < x < offs[0]]
            ds = ((o_off[0] - a) + (offs[0] - o_fs[0])
                  if len(o_off) == 1 and len(o_fs) == 1 and o_off[0] < o_fs[0] else None)
            out.append(GaitCycle(s, float(a), float(cyc), float(offs[0] - a),
                                 None if ds is None else float(ds)))
    return sorted(out, key=lambda c: c.time_s)


def measured_points(feet: FeetTrajectories, method: Method) -> dict[str, str]:
    """Which point of each foot ``method`` measures, in words with its labels.

    Args:
        feet: Per-foot trajectories (their ``primary`` point and ``sources``).
        method: ``"crossing"`` (the primary point: an ankle joint centre, ankle, heel or
            a named point) or ``"heelstrike"`` (the heel, else a named point or the ankle).

    Returns:
        ``{"L": ..., "R": ...}``, e.g. ``"ankle: LANK"``, ``"heel: LHEE"``, ``"ankle joint
        centre: midpoint of LANK and LMED"``.
    """
    src = getattr(feet, "sources", {}) or {}
    out = {}
    for side in ("L", "R"):
        if method == "crossing":
            part = feet.primary[side]
        else:
            part = next((p for p in ("explicit", "heel", "ankle") if p in feet.points[side]),
                        feet.primary[side])
        label = src.get(f"{side}_{part}", "")
        if part == "ankle_centre":
            out[side] = label or "ankle joint centre"
        else:
            word = "named point" if part == "explicit" else part
            out[side] = f"{word}: {label}" if label else word
    return out


class GaitAnalysis:
    """Gait events, steps, strides and summary from per-foot trajectories.

    Args:
        method: ``"crossing"`` (paper: ankle crossings → foot placements) or
            ``"heelstrike"`` (Zeni: foot strike / foot off relative to the pelvis).
        exclude_first: drop the first step of each pass and the first stride of the foot
            placed first (the paper's acceleration rule; from standing, the foot placed
            first is the one that stood while the other made the first step, see
            :meth:`_standing_placement`). ``"auto"`` does this only for passes that start
            from standing or a turn, not for passes already at speed at the start of the
            recording. ``"L"`` / ``"R"``: the paper's literal rule for subjects asked to
            start with that foot — drop its first step and the other foot's first stride
            in each pass (with a standing found, exactly the step and stride from it;
            otherwise the first ones detected).
        min_event_period_s: two events of the same kind and foot are at least this far
            apart (a stride is ≥ 0.6 s even when running slowly).
        placement_window_s: crossing method: the placed foot's position is its robust
            mean over ± this window around the crossing (mid-stance; the foot stands
            still for most of a ±0.3 s window at walking speeds), continued beyond it
            for the rest of the stance (:data:`STANCE_MAX_HALF_S`), instead of its
            position at the crossing instant (0: the paper's rule); the crossing time is then
            refined to where the swinging foot passes that position.
        refine_events: heel-strike method: move Zeni's events to the heel's landing and
            the toe's fastest rise. ``"auto"`` (default) does so for a foot with a heel
            point (markers, or a point named by the user), at any rate, and refines foot
            off alone from a toe marker without a heel; a foot measured by a depth
            camera's skeleton (:attr:`FeetTrajectories.from_skeleton`) keeps Zeni's
            extrema (see :meth:`_zeni_events`). ``True`` always, ``False`` never (Zeni's extrema,
            sub-frame interpolated).
        direction: a fixed walking direction ``(x, y)`` on the floor (e.g. a walkway's
            axis in the lab frame) along which lengths and widths are measured in every
            pass; None (default) finds it per pass from the footprints. A fixed axis
            that is off the true line of progression by an angle ψ biases left and right
            step widths by ∓ψ·step length (the pattern of seed 000's Tables 2–3).
        max_crossing_gap_s: crossing method: a crossing hidden in a gap of one ankle's
            trajectory shorter than this (s) is still found, between the samples on
            either side of the gap (with :data:`placement_window_s` > 0 its instant is
            where a shape-preserving interpolation of the swinging foot passes the placed
            one). Sensors on one side of a walkway lose the far ankle for ≈ 0.2–0.4 s as
            it passes behind the near leg, i.e. at the crossing itself; without this such
            crossings are missed and the steps around them dropped. 0: only crossings
            between consecutive samples (the paper's data had its gaps filled only up to
            the fusion's 0.2 s).

    Attributes (after :meth:`fit`; seconds on the input's time axis, metres on the floor):
        passes_: straight passes with their directions.
        events_: detected events, sorted by time.
        steps_: included steps.
        strides_: included strides.
        summary_: summary parameters (see ``docs/gait-json.md``).

    Tables: :meth:`to_records` gives any of these as flat rows (``pandas.DataFrame``
    takes them as they are); :meth:`to_dict` the JSON document of ``gaitrig gait --json``.

    Example:
        >>> ga = GaitAnalysis("heelstrike").fit("walk.c3d")  # doctest: +SKIP
        >>> ga.summary_["walking_speed_m_s"], ga.to_records("steps")[0]  # doctest: +SKIP
    """

    def __init__(self, method: Method = "crossing",
                 exclude_first: bool | Literal["auto", "L", "R"] = "auto",
                 min_event_period_s: float = 0.4, placement_window_s: float = 0.3,
                 direction: tuple[float, float] | None = None,
                 refine_events: bool | Literal["auto"] = "auto",
                 max_crossing_gap_s: float = 0.5) -> None:
        if method not in ("crossing", "heelstrike"):
            raise InputError(f"method must be 'crossing' or 'heelstrike', got {method!r}")
        if exclude_first not in (True, False, "auto", "L", "R"):
            raise InputError("exclude_first must be True, False, 'auto', 'L' or 'R'")
        self.method: Method = method
        self.exclude_first = exclude_first
        self.min_event_period_s = float(min_event_period_s)
        if refine_events not in (True, False, "auto"):
            raise InputError("refine_events must be True, False or 'auto'")
        self.refine_events = refine_events
        if not 0.0 <= placement_window_s <= 0.3:
            raise InputError("placement_window_s must be within [0, 0.3] s")
        self.placement_window_s = float(placement_window_s)
        if not 0.0 <= max_crossing_gap_s <= 1.0:
            raise InputError("max_crossing_gap_s must be within [0, 1] s (a longer gap "
                             "can hide a whole step)")
        self.max_crossing_gap_s = float(max_crossing_gap_s)
        self.direction: tuple[float, float] | None = None
        if direction is not None:
            d = np.asarray(direction, dtype=float).ravel()
            n = float(np.linalg.norm(d)) if d.shape == (2,) else 0.0
            if not np.isfinite(n) or n < 1e-9:
                raise InputError("direction must be a non-zero (x, y) vector on the floor")
            self.direction = (float(d[0] / n), float(d[1] / n))

    # ------------------------------------------------------------------ fitting
    def fit(self, trajectories: FeetTrajectories | SkeletonSeries | MarkerTrajectories
            | str | os.PathLike[str]) -> GaitAnalysis:
        """Detect passes, events, steps and strides; compute the summary.

        Args:
            trajectories: per-foot trajectories (:mod:`engine.mocap`), or a world-frame
                Z-up skeleton, or mocap markers (mapped automatically), or the path of a
                .c3d/.trc/.csv file (read with :func:`engine.mocap.load_feet`'s
                detection; call ``load_feet`` yourself to give marker names, units or
                the up axis).

        Returns:
            self, with the ``*_`` result attributes set.

        Raises:
            InputError: no usable foot data, an unreadable file, or an object of another
                type.
            InsufficientDataError: no straight walking found or fewer than two steps.
        """
        if isinstance(trajectories, str | os.PathLike):
            trajectories = load_feet(os.fspath(trajectories))
        if isinstance(trajectories, SkeletonSeries):
            feet = feet_from_skeleton(trajectories)
        elif isinstance(trajectories, MarkerTrajectories):
            feet = feet_from_markers(trajectories)
        elif hasattr(trajectories, "times") and hasattr(trajectories, "foot"):
            feet = trajectories
        else:
            raise InputError(
                f"GaitAnalysis.fit takes FeetTrajectories (engine.mocap.load_feet), "
                f"MarkerTrajectories, a world-frame Z-up SkeletonSeries or a .c3d/.trc/.csv "
                f"path, not {type(trajectories).__name__}")
        t = np.asarray(feet.times, dtype=float)
        if len(t) < 5:
            raise InsufficientDataError(f"only {len(t)} frames; a gait analysis needs a walk "
                                        "of several steps")
        rate = feet.rate
        # The body centre (passes, Zeni's reference) from the file's own points: an ankle
        # joint centre estimated from a lateral marker changes neither method's passes.
        pL, pR = (feet.points[s]["ankle"] if feet.primary[s] == "ankle_centre"
                  else feet.foot(s) for s in ("L", "R"))
        # The pelvis when it is seen at least as often as both feet together (or in most
        # frames): with sensors on one side only, the far ankle is hidden for a moment
        # at every crossing while the pelvis stays in view.
        mid_feet = 0.5 * (pL + pR)
        n_pelvis = (int(np.isfinite(feet.pelvis).all(axis=1).sum())
                    if feet.pelvis is not None else 0)
        n_mid = int(np.isfinite(mid_feet).all(axis=1).sum())
        if feet.pelvis is not None and (n_pelvis > len(t) // 2 or n_pelvis >= max(n_mid, 3)):
            centre = feet.pelvis
        else:
            centre = mid_feet
        self.passes_ = find_passes(t, centre, rate)
        if self.direction is not None:
            # A fixed axis, oriented along each pass's travel (back-and-forth walks).
            fx = np.array(self.direction)
            passes = []
            for p in self.passes_:
                u = fx if fx @ np.array(p.direction) >= 0 else -fx
                passes.append(WalkPass(p.t_start, p.t_end, (float(u[0]), float(u[1])),
                                       p.excluded_first))
            self.passes_ = passes
        if not self.passes_:
            why = ("no straight walking found (the body centre must travel ≥ "
                   f"{MIN_PASS_M} m at ≥ {MIN_WALK_SPEED} m/s for ≥ {MIN_PASS_S} s)")
            raise InsufficientDataError(reason=why)
        events: list[GaitEvent] = []
        steps: list[Step] = []
        strides: list[Stride] = []
        for k, wp in enumerate(self.passes_):
            t_prev = self.passes_[k - 1].t_end if k else -np.inf
            pe = (self._crossing_events(feet, wp, t_prev) if self.method == "crossing"
                  else self._zeni_events(feet, wp, centre))
            if self.direction is None:
                wp = self._progression_line(pe, wp)
            self.passes_[k] = wp
            kind = "placement" if self.method == "crossing" else "foot_strike"
            events += [GaitEvent(s, kind, tt, k) for s, tt, _, _ in pe.placements]
            events += [GaitEvent(s, "foot_off", tt, k) for s, tt in pe.offs]
            st, sd = self._steps(pe, wp, k)
            steps += st
            strides += sd
        self.events_ = sorted(events, key=lambda e: e.time_s)
        self.steps_ = steps
        self.strides_ = strides
        if len(steps) < 2:
            # Say how much walking was seen: a long walk of which the sensors saw only a
            # short stretch (one sensor pair covers ≈ 3.5 m) needs more coverage, not a
            # longer walk.
            seen = [(0.0, 0.0)]
            for p in self.passes_:
                c = centre[(t >= p.t_start) & (t <= p.t_end)]
                c = c[np.isfinite(c).all(axis=1)]
                if len(c) >= 2:
                    seen.append((float(np.linalg.norm(c[-1, :2] - c[0, :2])),
                                 p.t_end - p.t_start))
            longest_m, longest_s = max(seen)
            why = (f"only {count(len(steps), 'step')} found in "
                   f"{count(len(self.passes_), 'pass', 'passes')}; at least two steps are "
                   "needed")
            # the advice is on recording: a reference file cannot follow it
            what = (f"The longest stretch of straight walking seen was {longest_m:.1f} m "
                    f"({longest_s:.1f} s): record a longer walk, or, if the subject walked "
                    "farther, place or add sensors to cover more of the walkway")
            raise InsufficientDataError(reason=why, advice=what, sep=". ")
        self.summary_ = self._summary(float(rate))
        self.summary_["foot_points"] = measured_points(feet, self.method)
        # the notes are about the crossing method's point (a lateral ankle marker's centre)
        self.summary_["notes"] = (list(getattr(feet, "notes", []))
                                  if self.method == "crossing" else [])
        return self

    def _frame(self, wp: WalkPass) -> tuple[FloatArray, FloatArray]:
        d = np.array([wp.direction[0], wp.direction[1], 0.0])
        lat = np.cross([0.0, 0.0, 1.0], d)  # points to the walker's left
        return d, lat

    def _crossing_events(self, feet: FeetTrajectories, wp: WalkPass,
                         t_prev: float = -np.inf) -> _PassEvents:
        t = feet.times
        m = (t >= wp.t_start) & (t <= wp.t_end)
        d, _ = self._frame(wp)
        pL, pR = feet.foot("L"), feet.foot("R")
        diff = (pL - pR) @ d
        diff[~m] = np.nan
        xL, xR = pL @ d, pR @ d
        # Crossings between consecutive samples, and across a gap of one ankle shorter
        # than max_crossing_gap_s (the far ankle hidden behind the near leg as it passes
        # it, seen from one side): the gap's bracketing samples are interpolated.
        cross: list[tuple[int, float]] = []
        fin = np.flatnonzero(np.isfinite(diff))
        for i, i2 in itertools.pairwise(fin):
            if i2 > i + 1 and t[i2] - t[i] > self.max_crossing_gap_s:
                continue
            a, b = diff[i], diff[i2]
            if a == 0 or a * b < 0:
                u = a / (a - b) if a != b else 0.0
                cross.append((int(i), float(t[i] + u * (t[i2] - t[i]))))
        # Remove wiggles: consecutive crossings whose excursion between them is tiny
        # (noise around a crossing) are dropped in pairs.
        amp = np.nanpercentile(np.abs(diff), 90) if np.isfinite(diff).any() else 0.0
        thr = max(0.02, 0.2 * amp)
        changed = True
        while changed and len(cross) >= 2:
            changed = False
            for j in range(len(cross) - 1):
                seg = diff[cross[j][0] + 1: cross[j + 1][0] + 1]
                fin = np.abs(seg[np.isfinite(seg)])
                if len(fin) == 0 or fin.max() < thr:
                    del cross[j: j + 2]
                    changed = True
                    break
        # Remove glitches: two crossings much closer in time than the typical step (a
        # brief left/right label swap or a jump of one ankle) are dropped in pairs.
        # The extra pair is not always the two ends of the shortest interval: of the pairs
        # touching it, the one whose removal leaves the most regular step times goes.
        while len(cross) >= 3:
            times_c = np.array([c[1] for c in cross])
            gaps = np.diff(times_c)
            med = float(np.median(gaps))
            j = int(np.argmin(gaps))
            if gaps[j] >= max(MIN_STEP_S, MIN_STEP_FRACTION * med):
                break
            best, best_cost = j, np.inf
            for a in (j - 1, j, j + 1):
                if a < 0 or a + 1 >= len(cross):
                    continue
                rest = np.delete(times_c, [a, a + 1])
                cost = (float(np.sum(np.log(np.diff(rest) / med) ** 2))
                        if len(rest) >= 2 else 0.0)
                if cost < best_cost:
                    best, best_cost = a, cost
            del cross[best: best + 2]
        pe = _PassEvents()
        okL, okR = np.isfinite(xL), np.isfinite(xR)
        mid = 0.5 * (xL + xR)
        okm = np.isfinite(mid) & m
        v_pass = (float(abs(mid[okm][-1] - mid[okm][0]) / (t[okm][-1] - t[okm][0]))
                  if okm.sum() >= 2 and t[okm][-1] > t[okm][0] else 0.0)
        for _i, tc in cross:
            # The foot on the floor is the one moving slower along the direction; speeds
            # over ±0.1 s (not per sample, which measurement noise would dominate).
            h = 0.1
            vl = np.interp(tc + h, t[okL], xL[okL]) - np.interp(tc - h, t[okL], xL[okL])
            vr = np.interp(tc + h, t[okR], xR[okR]) - np.interp(tc - h, t[okR], xR[okR])
            side = "L" if vl < vr else "R"
            if (self.placement_window_s > 0 and v_pass > 0
                    and abs(min(vl, vr)) / (2 * h) > MAX_PLACED_SPEED_FRACTION * v_pass):
                # Neither foot stands still: not a placement but a tracker's glitch (e.g.
                # its legs' labels swapped while they cross); the steps around it are
                # dropped rather than measured from a moving "placed" foot.
                continue
            placed = self._stance_position(t, feet.foot(side), tc)
            if self.placement_window_s > 0:
                tc = self._refine_crossing(t, xR if side == "L" else xL, float(placed @ d), tc)
            other = _interp_across(t, feet.foot("R" if side == "L" else "L"), tc,
                                   self.max_crossing_gap_s)
            pe.placements.append((side, tc, placed, other))
        if pe.placements and v_pass > 0:
            first = self._standing_placement(feet, d, pe.placements[0], t_prev)
            if first is not None:
                pe.placements.insert(0, first)
                pe.from_standing = True
        return pe

    def _standing_placement(self, feet: FeetTrajectories, d: FloatArray,
                            first: tuple[str, float, FloatArray, FloatArray],
                            t_prev: float) -> tuple[str, float, FloatArray, FloatArray] | None:
        """The standing foot's placement when a pass starts from standing, or None.

        Feet standing side by side do not cross when the first foot leaves, so the first
        crossing found is already the second placement: the first foot, landed, passed
        by the other foot's first swing. The placement before it is the foot that stood
        while the first foot swung (seed 000, Fig. 6: the first left step and the first
        right stride both start at the standing right foot; they are what the
        acceleration rule excludes). Its time is when the first foot left its side.

        Args:
            feet: Foot trajectories.
            d: Walking direction (3,).
            first: The first crossing placement ``(side, time, position, other)``.
            t_prev: End of the previous pass: the standing is looked for after it.
        """
        t = feet.times
        tc1 = first[1]
        w = np.flatnonzero((t >= max(tc1 - STANDING_LOOKBACK_S, t_prev)) & (t <= tc1))
        if len(w) < 3:
            return None
        tw = t[w]
        pos = {f: feet.foot(f)[w] for f in ("L", "R")}
        x = {f: pos[f] @ d for f in ("L", "R")}
        ok = {f: np.isfinite(x[f]) for f in ("L", "R")}
        if ok["L"].sum() < 3 or ok["R"].sum() < 3:
            return None
        # The standing: the last stretch of ≥ STANDING_MIN_S before the first crossing in
        # which each foot stays within STANDING_TOL_M of its own median. Displacement,
        # not speed: a fused Kinect ankle wanders by a few cm within a tenth of a second
        # (speed noise of the order of a slow walk), and the far foot, partly hidden by
        # the other leg, drops out for single frames, which must not split a standing.
        # The body must not progress either: in the double support of a slow walk both
        # feet stay near their places while the pelvis moves on.
        if feet.pelvis is not None and np.isfinite(feet.pelvis[w]).all(axis=1).sum() >= 3:
            xc = feet.pelvis[w] @ d
        else:
            xc = 0.5 * (x["L"] + x["R"])
        okc = np.isfinite(xc)
        end = -1
        for e in range(len(w) - 1, -1, -1):
            if tw[e] - tw[0] < STANDING_MIN_S:
                break
            seg = (tw >= tw[e] - STANDING_MIN_S) & (tw <= tw[e])
            if (all(self._stays(x[f][seg & ok[f]], int(seg.sum())) for f in ("L", "R"))
                    and self._still_centre(xc[seg & okc], int(seg.sum()))):
                end = e
                break
        if end < 0:
            return None
        start = int(np.flatnonzero(tw >= tw[end] - STANDING_MIN_S)[0])
        med = {f: float(np.median(x[f][start:end + 1][ok[f][start:end + 1]])) for f in "LR"}
        # the standing began where a foot was last away from its place
        while start > 0 and all(not ok[f][start - 1] or abs(x[f][start - 1] - med[f])
                                <= STANDING_TOL_M for f in ("L", "R")):
            start -= 1
        t0 = float(tw[end])
        # the foot that stood is the one that leaves its standing place last (the first
        # crossing may belong to either foot: the tracker can miss the first one)
        leave = {}
        for f in ("L", "R"):
            x_stand = float(np.nanmedian(x[f][start:end + 1]))
            gone = np.flatnonzero(ok[f][end:] & (x[f][end:] - x_stand > STANDING_LEFT_M))
            leave[f] = float(tw[end + gone[0]]) if len(gone) else np.inf
        if not np.isfinite(min(leave.values())):
            return None
        s0 = "R" if leave["L"] < leave["R"] else "L"
        s1 = "L" if s0 == "R" else "R"
        p0, p1 = pos[s0], pos[s1]
        if self.placement_window_s > 0:
            placed = np.nanmedian(p0[start:end + 1], axis=0)
        else:
            placed = _interp_rows(tw[ok[s0]], p0[ok[s0]], t0)
        if first[0] == s0 and abs(float((first[2] - placed) @ d)) < STANDING_LEFT_M:
            # the "standing" was a long double support of a slow start: its front foot's
            # placement is the first crossing's, already found
            return None
        other = _interp_rows(tw[ok[s1]], p1[ok[s1]], t0)
        return s0, t0, np.asarray(placed, dtype=float), other

    @staticmethod
    def _stays(xs: FloatArray, n: int) -> bool:
        """Whether a foot's positions along the walk (its finite samples of an ``n``-sample
        stretch) stay within STANDING_TOL_M of their median, with at least half seen."""
        if len(xs) < max(3, n // 2):
            return False
        return bool(np.max(np.abs(xs - np.median(xs))) <= STANDING_TOL_M)

    @staticmethod
    def _still_centre(xs: FloatArray, n: int) -> bool:
        """Whether the body centre (finite samples of an ``n``-sample stretch, along the
        walk) progresses less than STANDING_CENTRE_M from the stretch's first third to
        its last (medians: robust to the tracker's jitter)."""
        if len(xs) < max(3, n // 2):
            return False
        k = max(1, len(xs) // 3)
        return bool(abs(float(np.median(xs[-k:]) - np.median(xs[:k]))) < STANDING_CENTRE_M)

    @staticmethod
    def _refine_crossing(t: FloatArray, x_swing: FloatArray, x_placed: float, tc: float
                         ) -> float:
        """The instant the swinging foot passes the placed foot's stance estimate.

        The placed foot stands still, so its position averaged over the stance window
        is less noisy than its per-sample position; the crossing is where the swinging
        foot (fast, so its noise shifts the time little) passes that position. Searched
        within ±0.1 s of the sample crossing; kept when not found there.
        """
        m = np.flatnonzero((t >= tc - 0.1) & (t <= tc + 0.1) & np.isfinite(x_swing))
        if len(m) < 2:
            return GaitAnalysis._crossing_in_gap(t, x_swing, x_placed, tc)
        roots = []
        for a, b in itertools.pairwise(m):
            ya, yb = x_swing[a] - x_placed, x_swing[b] - x_placed
            if b == a + 1 and ya < 0 <= yb:
                roots.append(float(t[a] + ya / (ya - yb) * (t[b] - t[a])))
        if roots:
            return min(roots, key=lambda r: abs(r - tc))
        return GaitAnalysis._crossing_in_gap(t, x_swing, x_placed, tc)

    @staticmethod
    def _crossing_in_gap(t: FloatArray, x_swing: FloatArray, x_placed: float, tc: float
                         ) -> float:
        """When the swinging foot is hidden around ``tc``: the instant a shape-preserving
        (PCHIP) interpolation of its finite samples within ±0.5 s passes ``x_placed``,
        inside the gap that holds ``tc``; ``tc`` when there is no such gap or root. A
        swinging foot moves monotonically forward, which PCHIP keeps (a straight line
        across the gap would put the crossing at the gap's mean speed)."""
        from scipy.interpolate import PchipInterpolator

        w = np.flatnonzero((t >= tc - 0.5) & (t <= tc + 0.5) & np.isfinite(x_swing))
        before, after = w[t[w] <= tc], w[t[w] > tc]
        if len(before) < 2 or len(after) < 2 or after[0] == before[-1] + 1:
            return tc
        ta, tb = float(t[before[-1]]), float(t[after[0]])
        grid = np.linspace(ta, tb, max(3, int(np.ceil((tb - ta) / 0.002)) + 1))
        y = PchipInterpolator(t[w], x_swing[w])(grid) - x_placed
        up = np.flatnonzero((y[:-1] < 0) & (y[1:] >= 0))
        if len(up) == 0:
            return tc
        k = up[np.argmin(np.abs(grid[up] - tc))]
        return float(grid[k] + y[k] / (y[k] - y[k + 1]) * (grid[k + 1] - grid[k]))

    def _zeni_events(self, feet: FeetTrajectories, wp: WalkPass,
                     centre: FloatArray) -> _PassEvents:
        t = feet.times
        m = (t >= wp.t_start) & (t <= wp.t_end)
        d, _ = self._frame(wp)
        pe = _PassEvents()
        strikes: list[tuple[str, float]] = []
        for side in ("L", "R"):
            heel = feet.point_for(side, ("explicit", "heel", "ankle"))
            toe = feet.point_for(side, ("toe", "explicit", "heel", "ankle"))
            # The refinements look for the contact transients of a heel and a toe marker.
            # A depth camera's skeleton has neither: its ankle stops descending at foot
            # flat (≈ 8 % of the cycle after contact; Perry & Burnfield), not at heel
            # contact, its foot joint is a model's mid-forefoot estimate, and the fused
            # skeleton is low-passed at 6 Hz, which smears those transients over tens of
            # ms. On fused 30 Hz skeletons the toe-rise foot off had an SD of 17–19 ms
            # (Zeni's minimum: 6–8 ms) and step times an RPC of 70–89 ms (14–16 ms), see
            # bench/gait_events.py; the real Vicon trial resampled to 30 Hz keeps its
            # markers' refined events within 10 ms (Zeni alone: 11–43 ms early).
            # A toe MARKER's rise times foot off well at any rate (the real trial's
            # ankle+toe markers: −4…+11 ms refined, −31…−11 ms Zeni alone), so "auto"
            # refines foot off from a toe marker even without a heel marker.
            own = feet.points[side]
            if self.refine_events == "auto":
                refine = "explicit" in own or "heel" in own
                refine_off = refine or ("toe" in own and not feet.from_skeleton)
            else:
                refine = refine_off = bool(self.refine_events)
            rel_h = (heel - centre) @ d
            rel_t = (toe - centre) @ d
            rel_h[~m] = np.nan
            rel_t[~m] = np.nan
            for y, store in ((rel_h, "fs"), (-rel_t, "fo")):
                fin = y[np.isfinite(y)]
                if len(fin) < 3:
                    continue
                rng = float(np.percentile(fin, 95) - np.percentile(fin, 5))
                height = float(np.median(fin)) + 0.25 * rng
                prom = max(0.01, 0.1 * rng)
                for tt in _peaks(t, y, feet.rate, height, prom, self.min_event_period_s):
                    if store == "fs":
                        strikes.append((side, self._refine_strike(t, heel, tt)
                                        if refine else tt))
                    else:
                        pe.offs.append((side, self._refine_off(t, toe, tt) if refine_off
                                         else tt))
        strikes.sort(key=lambda x: x[1])
        for side, tt in strikes:
            other = "R" if side == "L" else "L"
            pts = ("explicit", "heel", "ankle")
            placed = _interp_rows(t, feet.point_for(side, pts), tt)
            opp = _interp_rows(t, feet.point_for(other, pts), tt)
            pe.placements.append((side, tt, placed, opp))
        pe.offs.sort(key=lambda x: x[1])
        return pe

    @staticmethod
    def _progression_line(pe: _PassEvents, wp: WalkPass) -> WalkPass:
        """Refine a pass's direction to the line of progression of its footprints.

        Midpoints of consecutive left/right placements lie on the line of progression
        whatever the step width, while the body centre sways by a few cm each step;
        their principal axis therefore gives the direction along which lengths and
        widths are measured. Kept unchanged with fewer than three midpoints.
        """
        mids = [0.5 * (a[2][:2] + b[2][:2]) for a, b in zip(pe.placements[:-1],
                                                         pe.placements[1:], strict=True)
                if a[0] != b[0]]
        if len(mids) < 3:
            return wp
        M = np.array(mids)
        _, _, vt = np.linalg.svd(M - M.mean(axis=0), full_matrices=False)
        u = vt[0] / np.linalg.norm(vt[0])
        if u @ np.array(wp.direction) < 0:
            u = -u
        if u @ np.array(wp.direction) < np.cos(np.radians(20.0)):
            return wp  # footprints disagree with the body's travel: keep the latter
        return WalkPass(wp.t_start, wp.t_end, (float(u[0]), float(u[1])), wp.excluded_first)

    def _stance_position(self, t: FloatArray, x: FloatArray, tc: float) -> FloatArray:
        """The placed foot's position at a crossing.

        With ``placement_window_s = 0`` the position at the crossing instant (the
        paper). Otherwise a robust mean over the stance around it: the crossing is
        mid-stance, so most of the ±window is the foot standing still, which averages
        measurement noise down (the trackers' errors are correlated over ≈ 0.3 s, so
        every stance sample counts); what the foot does at the stance's ends (landing,
        heel rise) both feet do alike, so step lengths and widths, which are differences
        of placements, stay unbiased. Samples in the window far from its median (a brief
        leg swap of the tracker) are left out; beyond the window the stance continues
        for as long as the foot stays within :data:`STANCE_OUTLIER_M` of that median
        without a break (at most :data:`STANCE_MAX_HALF_S` from the crossing).
        """
        p = _interp_across(t, x, tc, self.max_crossing_gap_s)
        if self.placement_window_s <= 0:
            return p
        m = (t >= tc - self.placement_window_s) & (t <= tc + self.placement_window_s)
        w = x[m]
        w = w[np.isfinite(w).all(axis=1)]
        if len(w) < 3:
            return p
        # Robust mean: samples further than STANCE_OUTLIER_M from the median (a leg-label
        # swap, a foot still landing) are left out, the rest averaged.
        med = np.median(w, axis=0)
        keep = np.linalg.norm(w[:, :2] - med[:2], axis=1) <= STANCE_OUTLIER_M
        if keep.sum() < 3:
            return med
        # The stance outlasts the window: beyond its ends, add the samples that follow on
        # without a break while the foot is still within STANCE_OUTLIER_M of its stance
        # position (up to STANCE_MAX_HALF_S), so the whole stance is averaged. The
        # window's own outlier test is kept (a leg swap inside it is not bridged).
        near: NDArray[np.bool_] = np.asarray(np.isfinite(x).all(axis=1), dtype=bool)
        near[near] = np.linalg.norm(x[near, :2] - med[:2], axis=1) <= STANCE_OUTLIER_M
        idx = np.flatnonzero(m)
        lo, hi = idx[0], idx[-1]
        while lo > 0 and near[lo - 1] and t[lo - 1] >= tc - STANCE_MAX_HALF_S:
            lo -= 1
        while hi < len(t) - 1 and near[hi + 1] and t[hi + 1] <= tc + STANCE_MAX_HALF_S:
            hi += 1
        sel = np.zeros(len(t), dtype=bool)
        fin_w = np.flatnonzero(m)[np.isfinite(x[m]).all(axis=1)]
        sel[fin_w[keep]] = True
        sel[lo:idx[0]] = True
        sel[idx[-1] + 1:hi + 1] = True
        return self._time_mean(t, x, sel, med, tc)

    @staticmethod
    def _time_mean(t: FloatArray, x: FloatArray, sel: NDArray[np.bool_], med: FloatArray,
                   tc: float) -> FloatArray:
        """Time average of the linearly interpolated ``x`` over the stance samples
        ``sel``, continued past each end of the run to where the foot leaves
        :data:`STANCE_OUTLIER_M` of ``med`` (or reaches :data:`STANCE_MAX_HALF_S`).

        A plain mean of the samples counts a stance's ends (landing, heel rise, a few cm
        from the median) by how many samples happen to fall there: at 50 Hz step lengths
        moved by 1.5 mm against 100 Hz. The time average does not depend on the rate.
        """
        d = np.linalg.norm(x[:, :2] - med[:2], axis=1)  # NaN where missing
        on = np.flatnonzero(sel)
        i = np.arange(max(0, int(on[0]) - 1), min(len(t) - 1, int(on[-1]) + 1))
        a, b = i, i + 1  # every interval touching the stance
        dt = t[b] - t[a]
        ok = np.isfinite(d[a]) & np.isfinite(d[b]) & (sel[a] | sel[b])
        # an interval with one end out of the stance counts up to where the foot leaves
        # the radius (linear interpolation), or up to the STANCE_MAX_HALF_S limit
        s_a = sel[a]
        ds, do = np.where(s_a, d[a], d[b]), np.where(s_a, d[b], d[a])
        ts, to = np.where(s_a, t[a], t[b]), np.where(s_a, t[b], t[a])
        with np.errstate(divide="ignore", invalid="ignore"):
            f_far = np.clip((STANCE_OUTLIER_M - ds) / (do - ds), 0.0, 1.0)
            lim = tc + np.sign(to - tc) * STANCE_MAX_HALF_S
            f_late = np.clip(np.abs(lim - ts) / dt, 0.0, 1.0)
        f = np.where(do > STANCE_OUTLIER_M, f_far,
                     np.where(np.abs(to - tc) > STANCE_MAX_HALF_S, f_late, 0.0))
        both = sel[a] & sel[b]
        f0 = np.where(both | s_a, 0.0, 1.0 - f)
        f1 = np.where(both | ~s_a, 1.0, f)
        f0, f1, a, b, dt = f0[ok], f1[ok], a[ok], b[ok], dt[ok]
        pa = x[a] + f0[:, None] * (x[b] - x[a])
        pb = x[a] + f1[:, None] * (x[b] - x[a])
        w = (f1 - f0) * dt
        dur = float(w.sum())
        if not dur > 0.0:
            return np.asarray(x[sel].mean(axis=0))
        return np.asarray((0.5 * (pa + pb) * w[:, None]).sum(axis=0) / dur)

    @staticmethod
    def _refine_strike(t: FloatArray, heel: FloatArray, t_zeni: float) -> float:
        """Move a Zeni foot strike to the heel's landing.

        Zeni's maximum of heel-minus-pelvis precedes ground contact by a few tens of ms
        (the heel is still descending). The heel lands when it stops descending; its
        lowest point comes later, as the heel pad and shoe sole compress with a
        vertical velocity that only creeps to zero. Contact is therefore taken where
        the downward velocity falls below :data:`HEEL_STOP_FRACTION` of its peak in late
        swing (a velocity threshold as Ghoussayni et al. 2004, Gait Posture 20:266,
        scaled to the swing's own descent so that it holds at any speed or height
        scale), sub-frame interpolated; without such a crossing, the lowest point. The
        search is bounded to [−30, +120] ms around Zeni's estimate so that noisy
        heights cannot move an event to another step; Zeni's time is kept when neither
        is found there.
        """
        m = (t >= t_zeni - 0.03) & (t <= t_zeni + 0.12)
        idx = np.flatnonzero(m)
        if len(idx) < 3 or not np.isfinite(heel[idx, 2]).all():
            return t_zeni
        vz = np.gradient(heel[idx, 2], t[idx])
        late = np.flatnonzero((t >= t_zeni - 0.15) & (t <= t_zeni + 0.12))
        z_late = heel[late, 2]
        ok = np.isfinite(z_late)
        peak = (float(-np.gradient(z_late[ok], t[late][ok]).min())
                if ok.sum() >= 3 else 0.0)
        for thr in ((HEEL_STOP_FRACTION * peak, 0.0) if peak > 0 else (0.0,)):
            for j in range(len(idx) - 1):
                if vz[j] < -thr <= vz[j + 1]:
                    u = (vz[j] + thr) / (vz[j] - vz[j + 1])
                    return float(t[idx[j]] + u * (t[idx[j + 1]] - t[idx[j]]))
        return t_zeni

    @staticmethod
    def _refine_off(t: FloatArray, toe: FloatArray, t_zeni: float) -> float:
        """Move a Zeni foot off to the toe's fastest rise (O'Connor et al. 2007).

        Zeni's minimum of toe-minus-pelvis lags or leads lift-off by tens of ms; the
        toe's upward velocity peaks as it leaves the floor (the foot-velocity algorithm,
        O'Connor et al., Gait Posture 25:469). Bounded to [−80, +120] ms around Zeni's
        estimate; Zeni's time is kept when no interior peak lies in that window.
        """
        m = (t >= t_zeni - 0.08) & (t <= t_zeni + 0.12)
        idx = np.flatnonzero(m)
        if len(idx) < 5 or not np.isfinite(toe[idx, 2]).all():
            return t_zeni
        vz = np.gradient(toe[idx, 2], t[idx])
        j = int(np.argmax(vz))
        if not 0 < j < len(idx) - 1 or vz[j] <= 0:
            return t_zeni
        y0, y1, y2 = vz[j - 1], vz[j], vz[j + 1]
        den = y0 - 2 * y1 + y2
        off = float(np.clip(0.5 * (y0 - y2) / den, -0.5, 0.5)) if den != 0 else 0.0
        return float(t[idx[j]] + off * (t[idx[j + 1]] - t[idx[j - 1]]) / 2)

    def _steps(self, pe: _PassEvents, wp: WalkPass, k: int) -> tuple[list[Step], list[Stride]]:
        d, lat = self._frame(wp)
        pl = pe.placements
        steps: list[Step] = []
        step_end: list[int] = []  # index in pl of each step's placement
        for j in range(1, len(pl)):
            (sa, ta, pa, _), (sb, tb, pb, _) = pl[j - 1], pl[j]
            if sa == sb:
                continue  # a missed event: this pair is no step
            # Footprint to footprint, for both methods: each foot where it was placed (at
            # its crossing, or at its own strike). Not both feet at B's strike: by then A's
            # heel has risen and its ankle rolled forward over the toes, which shortens
            # the step by 3-4 cm for ankles (1-2 cm for heel markers) on the Vicon trial,
            # and disagrees with walkway (GAITRite) footprints, the normative data's basis.
            vec = pb - pa
            steps.append(Step(sb, tb, float(vec @ d), float(abs(vec @ lat)), float(tb - ta), k))
            step_end.append(j)
        strides: list[Stride] = []
        stride_end: list[int] = []
        for j in range(2, len(pl)):
            (s0, t0, p0, _), (s1, _, _, _), (s2, t2, p2, _) = pl[j - 2], pl[j - 1], pl[j]
            # Only s, other, s: a stride over a missed event would be two strides long.
            if s0 == s2 != s1:
                strides.append(Stride(s2, t2, float((p2 - p0) @ d), float(t2 - t0), k))
                stride_end.append(j)
        literal = self.exclude_first in ("L", "R")
        excl = (literal or (wp.excluded_first if self.exclude_first == "auto"
                            else bool(self.exclude_first)))
        if excl and pe.from_standing and (not literal or pl[0][0] != self.exclude_first):
            # Known start from standing (for the literal rule: by the other foot than the
            # standing one, as asked): the acceleration rule means the first foot's step
            # from the standing foot (placements 0 → 1) and the standing foot's first
            # stride (0 → 2). Where the tracker missed the first foot's landing they do not
            # exist, and the steps found after it are normal ones, kept.
            steps = [x for x, j in zip(steps, step_end, strict=True) if j != 1]
            strides = [x for x, j in zip(strides, stride_end, strict=True) if j != 2]
        elif literal:
            # the paper's literal rule: the subject starts with this foot; its first step
            # and the other foot's first stride go, whatever the system detected first
            first_step = next((i for i, x in enumerate(steps)
                               if x.side == self.exclude_first), None)
            if first_step is not None:
                del steps[first_step]
            first_stride = next((i for i, x in enumerate(strides)
                                 if x.side != self.exclude_first), None)
            if first_stride is not None:
                del strides[first_stride]
        elif excl and pl:
            steps = steps[1:]
            first = next((i for i, x in enumerate(strides) if x.side == pl[0][0]), None)
            if first is not None:
                del strides[first]
        # A step spanning events missed on both feet (e.g. a long occlusion) still
        # alternates sides but lasts ~3 steps: drop steps/strides over twice the pass's
        # median (step-time CV is < 10 % in health and rarely > 30 % in pathology).
        if len(steps) >= 3:
            med = float(np.median([x.duration_s for x in steps]))
            steps = [x for x in steps if x.duration_s <= MAX_DURATION_RATIO * med]
        if len(strides) >= 3:
            med = float(np.median([x.duration_s for x in strides]))
            strides = [x for x in strides if x.duration_s <= MAX_DURATION_RATIO * med]
        return steps, strides

    # ------------------------------------------------------------------ summary
    def _summary(self, rate: float) -> dict[str, Any]:
        st, sd = self.steps_, self.strides_

        def stats(vals: list[tuple[str, float]]) -> dict[str, float | None]:
            a = np.array([v for _, v in vals], dtype=float)
            L = np.array([v for s, v in vals if s == "L"], dtype=float)
            R = np.array([v for s, v in vals if s == "R"], dtype=float)
            mean = float(a.mean()) if len(a) else None
            sdv = float(a.std(ddof=1)) if len(a) > 1 else None
            mL = float(L.mean()) if len(L) else None
            mR = float(R.mean()) if len(R) else None
            asym = (100.0 * abs(mL - mR) / (0.5 * (mL + mR))
                    if mL is not None and mR is not None and (mL + mR) != 0 else None)
            return {"mean": mean, "sd": sdv,
                    "cv_pct": (100.0 * sdv / abs(mean)) if sdv is not None and mean else None,
                    "left_mean": mL, "right_mean": mR, "asymmetry_pct": asym}

        tot_len = sum(s.length_m for s in st)
        tot_t = sum(s.duration_s for s in st)
        out: dict[str, Any] = {
            "method": self.method,
            # the analysed series' rate: what event timing can resolve (report notes)
            "frame_rate_hz": rate,
            "n_passes": len(self.passes_),
            "n_steps": len(st),
            "n_strides": len(sd),
            "walking_speed_m_s": tot_len / tot_t if tot_t > 0 else None,
            "cadence_steps_min": 60.0 * len(st) / tot_t if tot_t > 0 else None,
            "step_length_m": stats([(s.side, s.length_m) for s in st]),
            "step_width_m": stats([(s.side, s.width_m) for s in st]),
            "step_time_s": stats([(s.side, s.duration_s) for s in st]),
            "stride_length_m": stats([(s.side, s.length_m) for s in sd]),
            "stride_time_s": stats([(s.side, s.duration_s) for s in sd]),
        }
        out.update(self._phases())
        return out

    def _phases(self) -> dict[str, Any]:
        """Stance, swing and double support in % of the gait cycle (heel-strike only)."""
        none = {"stance_pct": None, "swing_pct": None, "double_support_pct": None}
        if self.method != "heelstrike":
            return none
        cycles = gait_cycles(self.events_)
        stance: dict[str, list[float]] = {
            s: [c.stance_pct for c in cycles if c.side == s] for s in "LR"}
        dsup = [d for c in cycles if (d := c.double_support_pct) is not None]
        allst = stance["L"] + stance["R"]
        if not allst:
            return none

        def side_stats(v: list[float]) -> float | None:
            return float(np.mean(v)) if v else None

        return {
            "stance_pct": {"mean": float(np.mean(allst)), "left_mean": side_stats(stance["L"]),
                           "right_mean": side_stats(stance["R"])},
            "swing_pct": {"mean": 100.0 - float(np.mean(allst)),
                          "left_mean": None if not stance["L"]
                          else 100.0 - float(np.mean(stance["L"])),
                          "right_mean": None if not stance["R"]
                          else 100.0 - float(np.mean(stance["R"]))},
            "double_support_pct": {"mean": side_stats(dsup)} if dsup else None,
        }

    # ------------------------------------------------------------------ output
    def _check_fitted(self) -> None:
        if not hasattr(self, "summary_"):
            raise InputError("this GaitAnalysis has no results yet: call fit(...) first")

    def to_records(self, table: Table = "steps") -> list[dict[str, Any]]:
        """One table of the results as flat rows, for ``pandas.DataFrame(rows)`` or CSV.

        Units are in the column names (SI: ``_s``, ``_m``, ``_pct``); times are on the
        input's time axis; ``pass_index`` says which straight pass a row belongs to.

        Args:
            table: ``"steps"`` (side, time_s, length_m, width_m, duration_s, pass_index),
                ``"strides"`` (side, time_s, length_m, duration_s, pass_index),
                ``"events"`` (side, kind, time_s, pass_index), ``"passes"`` (pass_index,
                t_start_s, t_end_s, direction_x, direction_y, excluded_first) or
                ``"summary"`` (one row per parameter of :attr:`summary_`: parameter,
                mean, sd, cv_pct, left_mean, right_mean, asymmetry_pct; None where a
                statistic does not apply or cannot be computed).

        Returns:
            The rows, one dict per step / stride / event / pass / parameter.

        Raises:
            InputError: an unknown table, or :meth:`fit` was not called.
        """
        self._check_fitted()
        if table == "steps":
            return [asdict(r) for r in self.steps_]
        if table == "strides":
            return [asdict(r) for r in self.strides_]
        if table == "events":
            return [asdict(r) for r in self.events_]
        if table == "passes":
            return [{"pass_index": k, "t_start_s": p.t_start, "t_end_s": p.t_end,
                     "direction_x": p.direction[0], "direction_y": p.direction[1],
                     "excluded_first": p.excluded_first} for k, p in enumerate(self.passes_)]
        if table == "summary":
            cols = ("mean", "sd", "cv_pct", "left_mean", "right_mean", "asymmetry_pct")
            out: list[dict[str, Any]] = []
            for key, val in self.summary_.items():
                if key in ("method", "frame_rate_hz", "n_passes", "n_steps", "n_strides",
                           "foot_points", "notes"):  # facts of the analysis, not parameters
                    continue
                stats = val if isinstance(val, dict) else {"mean": val}
                out.append({"parameter": key, **{c: stats.get(c) for c in cols}})
            return out
        raise InputError(f"unknown table {table!r}; use steps, strides, events, passes "
                         "or summary")

    def to_dict(self) -> dict[str, Any]:
        """The stable JSON document (``docs/gait-json.md``).

        Returns:
            ``{"events", "steps", "strides", "summary"}`` with plain floats (rounded to 1 µ of
            their SI unit; NaN as None) and ints.

        Raises:
            InputError: :meth:`fit` was not called.
        """
        self._check_fitted()
        def clean(o: Any) -> Any:
            if isinstance(o, dict):
                return {k: clean(v) for k, v in o.items()}
            if isinstance(o, list | tuple):
                return [clean(v) for v in o]
            if isinstance(o, np.floating | float):
                return None if not np.isfinite(o) else round(float(o), 6)
            if isinstance(o, np.integer):
                return int(o)
            return o

        def strip(d: dict[str, Any]) -> dict[str, Any]:
            return {k: v for k, v in d.items() if k != "pass_index"}

        return clean({
            "events": [{"side": e.side, "kind": e.kind, "time_s": e.time_s}
                       for e in self.events_],
            "steps": [strip(asdict(s)) for s in self.steps_],
            "strides": [strip(asdict(s)) for s in self.strides_],
            "summary": self.summary_,
        })

    def marker_events(self) -> list[MarkerEvent]:
        """Detected events in the form the C3D/TRC writers take (``EVENT`` group).

        Returns:
            One :class:`~engine.io.markers.MarkerEvent` per detected event (time s, side, kind,
            Vicon-style label).

        Raises:
            InputError: :meth:`fit` was not called.
        """
        self._check_fitted()
        labels = {"foot_strike": "Foot Strike", "foot_off": "Foot Off",
                  "placement": "Foot Placement"}
        return [MarkerEvent(e.time_s, e.side, e.kind, labels[e.kind]) for e in self.events_]

    def to_json(self, indent: int | None = None) -> str:
        """:meth:`to_dict` serialised as one JSON object.

        Args:
            indent: JSON indentation; None writes one line.

        Returns:
            The JSON text.
        """
        return json.dumps(self.to_dict(), indent=indent)
