"""From mocap files or skeletons to the per-foot trajectories the gait engine needs.

Marker names are matched automatically for the common conventions
(:func:`engine.io.markers.find_marker`: Vicon Plug-in Gait ``LANK/LHEE/LTOE``, OpenSim
``L.Ankle.Lat``, CAST ``L_FAL/L_FCC``, IOR ``L_LM/L_CA``, ``LeftAnkle``, ``AnkleLeft``,
``l_ankle``, subject prefixes such as ``Subject:LHEE``; case-insensitive) and can be
overridden by explicit ``left``/``right`` names. Everything returned is in metres, Z up.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from engine import nanstats
from engine.errors import InputError, cli_say, fill
from engine.io.markers import (
    PELVIS_SINGLE,
    MarkerEvent,
    MarkerTrajectories,
    characteristic_length,
    detect_units,
    detect_vertical_axis,
    find_marker,
    find_medial_ankle,
    is_lateral_ankle,
    label_key,
    labelled_vertical_axis,
    to_z_up,
    unit_scale,
    up_rotation,
)
from engine.skeleton import SkeletonSeries
from engine.wording import count

FloatArray = NDArray[np.float64]

#: Short gaps in mocap data (marker drop-outs) are bridged up to this length.
MAX_GAP_S = 0.2
#: Marker diameter when a file with a lateral-malleolus marker gives none (C3D
#: ``PROCESSING:MarkerDiameter``): Vicon's 14 mm markers, Plug-in Gait's default.
DEFAULT_MARKER_DIAMETER_M = 0.014
#: Ankle width (across the malleoli, Plug-in Gait's ``AnkleWidth``) when a file has
#: neither a medial malleolus marker nor the subject's measurement, nor one given
#: (``ankle_width_m``, ``--ankle-width-mm``): a round figure between adult women's and
#: men's bimalleolar breadths in the 2012 US Army anthropometric survey (ANSUR II; Gordon
#: et al. 2014, NATICK/TR-15/007). What is known: a figure derived from the public ANSUR II
#: data, bimalleolar breadth ≈ 0.0426 × stature for men and ≈ 0.0412 × stature for women,
#: which at mean statures of ≈ 1.756 m and ≈ 1.629 m gives ≈ 75 mm and ≈ 67 mm. What is
#: not: that derivation was not checked against the report's own tables (its means, or
#: their spread), and soldiers need not be a clinic's patients. A width off by x moves
#: each foot's point by x/2, step widths by about x.
DEFAULT_ANKLE_WIDTH_M = 0.070
#: Ankle widths accepted when given (m): wider than any adult ankle's range, narrower
#: than a width in cm or m read as mm (7, 0.07) or one in mm read as m.
ANKLE_WIDTH_RANGE_M = (0.040, 0.150)
#: How ankle markers are taken (``ankle_markers``, ``--ankle-markers``): ``"auto"`` by
#: their names (:func:`engine.io.markers.is_lateral_ankle`, or a medial marker beside),
#: ``"lateral"`` all on the lateral malleolus (their joint centre estimated),
#: ``"joint"`` all joint centres already (measured as they are).
ANKLE_MARKER_RULES = ("auto", "lateral", "joint")
#: Below this heel→toe length on the floor a frame gives no foot axis (the foot is seen
#: end-on or a marker jumped); the axis is interpolated from the neighbouring frames.
MIN_FOOT_AXIS_M = 0.05

# The marker-name matcher (find_marker, PART_STEMS) lives in engine.io.markers, with the
# unit and vertical-axis detection that use the same names.
_key = label_key


def resolve_label(labels: list[str], name: str) -> str:
    """Match a user-given marker name (case-insensitive, subject prefix optional).

    Args:
        labels: The file's marker labels.
        name: The name given (``"LHEE"``, ``"lhee"``, ``"Subject:LHEE"`` ...).

    Returns:
        The matching label as in the file.

    Raises:
        InputError: no label matches (the message lists them).
    """
    if name in labels:
        return name
    k = _key(name)
    hits = [lab for lab in labels if _key(lab) == k]
    if not hits:
        raise InputError(f"marker {name!r} not found; available labels: {', '.join(labels)}")
    return hits[0]


@dataclass
class FeetTrajectories:
    """Per-foot trajectories in metres, Z up, on a common time axis.

    Attributes:
        times: ``(T,)`` seconds.
        rate: sampling rate (Hz).
        points: ``{"L": {"ankle"|"heel"|"toe": (T, 3)}, "R": {...}}``; at least one of
            ankle/heel per side.
        primary: ``{"L": part, "R": part}`` — the point used for spatial parameters
            and crossing detection (``"explicit"`` when chosen by name).
        pelvis: ``(T, 3)`` pelvis/sacrum centre, or None.
        sources: role → label(s) the data came from, for reports.
        events: annotated events carried over from the file.
        from_skeleton: the points are a body-tracking skeleton's joints (a model's
            estimate, e.g. its "foot" joint), not markers on the foot.
        notes: data-quality remarks on the points (a population ankle width used, a
            lateral-malleolus marker kept as it is), for reports.

    A foot whose ankle marker sits on the lateral malleolus (``LANK``) also has an
    ``"ankle_centre"`` point, the ankle joint centre estimated from it
    (:func:`ankle_joint_centre`), and that is its primary point; ``sources`` says how
    it was formed (``"L_ankle_centre"``).
    """

    times: FloatArray
    rate: float
    points: dict[str, dict[str, FloatArray]]
    primary: dict[str, str]
    pelvis: FloatArray | None = None
    sources: dict[str, str] = field(default_factory=dict)
    events: list[MarkerEvent] = field(default_factory=list)
    from_skeleton: bool = False
    notes: list[str] = field(default_factory=list)

    def __repr__(self) -> str:
        # A notebook shows the object: what it holds, not seven arrays of numbers.
        span = (f"{self.times[0]:.2f}–{self.times[-1]:.2f} s" if len(self.times)
                else "empty")
        parts = {s: sorted(p) for s, p in self.points.items()}
        return (f"FeetTrajectories({len(self.times)} frames, {span}, {self.rate:g} Hz, "
                f"points={parts}, primary={self.primary}, "
                f"pelvis={'yes' if self.pelvis is not None else 'no'}, "
                f"{len(self.events)} events, sources={self.sources})")

    def foot(self, side: str, part: str | None = None) -> FloatArray:
        """``(T, 3)`` trajectory (m, Z up) of ``part`` (default: the primary point) of ``side``.

        Args:
            side: ``"L"`` or ``"R"``.
            part: ``"ankle"``, ``"heel"``, ``"toe"`` ... (a key of ``points[side]``); None: the
                side's primary point.

        Returns:
            The trajectory, time first axis (NaN where the marker was missing).
        """
        pts = self.points[side]
        return pts[part or self.primary[side]]

    def point_for(self, side: str, prefer: tuple[str, ...]) -> FloatArray:
        """First available of ``prefer`` for ``side`` (else the primary point).

        Args:
            side: ``"L"`` or ``"R"``.
            prefer: Parts in order of preference (e.g. ``("heel", "ankle")``).

        Returns:
            ``(T, 3)`` trajectory in metres, Z up.
        """
        for p in prefer:
            if p in self.points[side]:
                return self.points[side][p]
        return self.foot(side)


def fill_gaps(times: FloatArray, x: FloatArray, max_gap_s: float = MAX_GAP_S) -> FloatArray:
    """Linear interpolation over NaN runs no longer than ``max_gap_s`` (per column).

    Args:
        times: ``(T,)`` s.
        x: ``(T, ...)`` samples, time first.
        max_gap_s: Longest NaN run filled, s.

    Returns:
        A filled copy; longer runs and runs at the ends stay NaN.
    """
    out = np.array(x, dtype=float, copy=True)
    flat = out.reshape(len(times), -1)
    for c in range(flat.shape[1]):
        v = flat[:, c]
        ok = np.isfinite(v)
        if ok.all() or ok.sum() < 2:
            continue
        idx = np.flatnonzero(ok)
        gaps = np.flatnonzero(np.diff(idx) > 1)
        for g in gaps:
            a, b = idx[g], idx[g + 1]
            if times[b] - times[a] <= max_gap_s + 1e-9:
                v[a + 1:b] = np.interp(times[a + 1:b], [times[a], times[b]], [v[a], v[b]])
    return out


def medial_directions(ankle: FloatArray, heel: FloatArray, toe: FloatArray,
                      other: FloatArray) -> FloatArray | None:
    """Per frame, the unit vector on the floor from a foot's lateral side to its medial side.

    Perpendicular to the foot's heel→toe axis on the floor (Z up), pointing towards the
    other foot: the sign is taken once for the whole walk (the median over frames of the
    other foot's side), so it holds for left-handed (mirrored) files and any heading.
    Frames without a foot axis (a marker missing, heel and toe less than
    :data:`MIN_FOOT_AXIS_M` apart on the floor) take it interpolated from their
    neighbours.

    Args:
        ankle: ``(T, 3)`` the foot's lateral ankle marker, m, Z up.
        heel: ``(T, 3)`` its heel marker.
        toe: ``(T, 3)`` its toe marker.
        other: ``(T, 3)`` a point of the other foot (its ankle marker).

    Returns:
        ``(T, 3)`` unit vectors with zero Z, or None when fewer than two frames give a
        foot axis or the other foot's side cannot be told.
    """
    f = toe[:, :2] - heel[:, :2]
    n_f = np.linalg.norm(f, axis=1)
    ok = np.isfinite(n_f) & (n_f >= MIN_FOOT_AXIS_M)
    if ok.sum() < 2:
        return None
    n = np.full((len(f), 2), np.nan)
    n[ok] = np.stack([-f[ok, 1], f[ok, 0]], axis=1) / n_f[ok, None]  # the foot's left
    if not ok.all():
        # the angle, unwrapped, is interpolated (components would pass through zero)
        ang = np.unwrap(np.arctan2(n[ok, 1], n[ok, 0]))
        i = np.arange(len(f))
        a = np.interp(i, i[ok], ang)
        n = np.stack([np.cos(a), np.sin(a)], axis=1)
    return _towards_other_foot(n, ankle, other)


def _towards_other_foot(n: FloatArray, ankle: FloatArray, other: FloatArray
                        ) -> FloatArray | None:
    """``(T, 2)`` floor directions ``n`` as ``(T, 3)`` vectors, signed once for the whole
    walk to point towards the other foot (the median over frames); None when its side
    cannot be told."""
    side = nanstats.nanmedian(np.sum((other[:, :2] - ankle[:, :2]) * n, axis=1))
    if not np.isfinite(side) or side == 0.0:
        return None
    out = np.zeros((len(n), 3))
    out[:, :2] = np.sign(side) * n
    return out


def ankle_joint_centre(ankle: FloatArray, medial: FloatArray | None,
                       heel: FloatArray | None, toe: FloatArray | None, other: FloatArray,
                       ankle_width_m: float | None,
                       marker_diameter_m: float = DEFAULT_MARKER_DIAMETER_M,
                       ) -> tuple[FloatArray, str] | None:
    """The ankle joint centre from a lateral-malleolus marker, as Plug-in Gait estimates it.

    In order: the midpoint of the lateral and medial malleolus markers; else the lateral
    marker moved medially by ``ankle_width_m / 2 + marker_diameter_m / 2`` on the floor,
    perpendicular to the foot's heel→toe axis (:func:`medial_directions`). Frames where
    the medial marker is missing take the second rule with the half distance between
    the two markers measured in the others.

    Args:
        ankle: ``(T, 3)`` lateral malleolus marker, m, Z up.
        medial: ``(T, 3)`` medial malleolus marker, or None.
        heel: ``(T, 3)`` heel marker, or None.
        toe: ``(T, 3)`` toe marker, or None.
        other: ``(T, 3)`` a point of the other foot (tells medial from lateral).
        ankle_width_m: distance across the malleoli, m (None: the medial marker only).
        marker_diameter_m: the markers' diameter, m.

    Returns:
        ``(T, 3)`` the centre (m, Z up, NaN where it cannot be formed) and the rule used
        (``"medial"`` or ``"width"``), or None when neither rule applies (no medial
        marker, and no heel and toe to give the foot's axis or no width).
    """
    axis = (medial_directions(ankle, heel, toe, other)
            if heel is not None and toe is not None else None)
    if medial is not None and np.isfinite(medial).all(axis=1).sum() >= 2:
        c = 0.5 * (ankle + medial)
        miss = ~np.isfinite(medial).all(axis=1)
        if axis is not None and miss.any():
            half = float(nanstats.nanmedian(np.linalg.norm((medial - ankle)[:, :2], axis=1)))
            c[miss] = ankle[miss] + 0.5 * half * axis[miss]
        return c, "medial"
    if axis is None or ankle_width_m is None:
        return None
    return ankle + (0.5 * ankle_width_m + 0.5 * marker_diameter_m) * axis, "width"


#: Length of the moving average that gives the direction of travel (a stride or so).
TRAVEL_SMOOTH_S = 1.0
#: Below this speed on the floor a frame gives no direction of travel (standing, turning).
MIN_TRAVEL_SPEED_M_S = 0.2


def travel_directions(centre: FloatArray, rate: float) -> FloatArray | None:
    """Per frame, the unit direction of travel on the floor of a body point.

    The point is averaged over :data:`TRAVEL_SMOOTH_S` (the feet's side-to-side sway
    cancels over a stride) and differentiated; frames slower than
    :data:`MIN_TRAVEL_SPEED_M_S` take the direction interpolated from their neighbours.

    Args:
        centre: ``(T, 3)`` a body point (the midpoint of the ankle markers), m, Z up,
            on a uniform time axis; NaN where unknown.
        rate: Frames per second.

    Returns:
        ``(T, 3)`` unit vectors with zero Z, or None when fewer than two frames move.
    """
    c = centre[:, :2].copy()
    ok = np.isfinite(c).all(axis=1)
    if ok.sum() < 2:
        return None
    i = np.arange(len(c))
    for k in range(2):  # the edges held, gaps bridged, for the average
        c[:, k] = np.interp(i, i[ok], c[ok, k])
    n = max(1, round(TRAVEL_SMOOTH_S * rate) // 2)
    pad = np.concatenate([np.repeat(c[:1], n, axis=0), c, np.repeat(c[-1:], n, axis=0)])
    kern = np.ones(2 * n + 1) / (2 * n + 1)
    sm = np.stack([np.convolve(pad[:, k], kern, mode="valid") for k in range(2)], axis=1)
    v = np.gradient(sm, axis=0) * rate
    speed = np.linalg.norm(v, axis=1)
    moving = ok & (speed >= MIN_TRAVEL_SPEED_M_S)
    if moving.sum() < 2:
        return None
    ang = np.unwrap(np.arctan2(v[moving, 1], v[moving, 0]))
    a = np.interp(i, i[moving], ang)
    out = np.zeros((len(c), 3))
    out[:, 0], out[:, 1] = np.cos(a), np.sin(a)
    return out


def walking_medial_directions(travel: FloatArray, ankle: FloatArray,
                              other: FloatArray) -> FloatArray | None:
    """A foot's medial direction without its heel→toe axis: across the walking direction.

    Perpendicular to the direction of travel on the floor, pointing towards the other
    foot (the sign taken once for the walk, as :func:`medial_directions` does). The
    foot's turn-out is not known: each 10° of it moves a point placed 4 cm along this
    direction about 7 mm along the walk and under 1 mm across it.

    Args:
        travel: ``(T, 3)`` unit direction of travel (:func:`travel_directions`).
        ankle: ``(T, 3)`` the foot's lateral ankle marker, m, Z up.
        other: ``(T, 3)`` a point of the other foot.

    Returns:
        ``(T, 3)`` unit vectors with zero Z, or None when the other foot's side cannot
        be told.
    """
    n = np.stack([-travel[:, 1], travel[:, 0]], axis=1)  # the walk's left
    return _towards_other_foot(n, ankle, other)


def _ankle_centres(pts: dict[str, dict[str, FloatArray]], sources: dict[str, str],
                   labels: list[str], P: FloatArray, t: FloatArray,
                   meta: dict[str, object], forced: bool = False,
                   given: dict[str, float] | None = None) -> list[str]:
    """Add the ``ankle_centre`` point of each foot whose ankle marker is lateral.

    ``forced``: every ankle marker is lateral, whatever its name (``--ankle-markers
    lateral``), and a foot whose centre cannot be placed is an error, not a note.
    ``given``: ankle widths per side (m) used instead of the file's and the population's.

    A foot whose centre cannot be placed (no heel→toe axis, no medial marker) while the
    other foot's can is moved medially across the walking direction
    (:func:`walking_medial_directions`) by its own ankle width (the file's, else the
    population one): one foot at its joint and the other at its lateral marker would make
    every step width about half an ankle width plus a marker radius (≈ 4 cm) too wide.
    With neither foot placeable both markers are kept (the same point on each foot).

    Returns the notes to report (a population width used, a foot placed across the
    walking direction, a marker kept as it is).
    """
    notes: list[str] = []
    by_default: list[tuple[str, float]] = []  # (marker, offset cm) placed by the default
    file_widths = meta.get("ankle_width_m")
    file_widths = file_widths if isinstance(file_widths, dict) else {}
    widths = given if given is not None else file_widths
    d = meta.get("marker_diameter_m")
    diameter = float(d) if isinstance(d, int | float) else DEFAULT_MARKER_DIAMETER_M
    d_from = "PROCESSING:MarkerDiameter" if isinstance(d, int | float) else "default"
    words = {"L": "left", "R": "right"}
    # per lateral foot: (label, medial label, width or None, other foot's point)
    todo: dict[str, tuple[str, str | None, float | None, FloatArray]] = {}
    for side in ("L", "R"):
        other = "R" if side == "L" else "L"
        lab = sources.get(f"{side}_ankle")
        ref = pts[other].get("ankle", pts[other].get("heel"))
        med_lab = find_medial_ankle(labels, side)
        # a bare "Ankle" is a joint's name, unless a medial marker says it is a malleolus
        # (OpenSim's L.Ankle beside L.Ankle.Med)
        if (lab is None or ref is None
                or not (forced or is_lateral_ankle(lab, side) or med_lab is not None)):
            continue
        w = widths.get(side)
        todo[side] = (lab, med_lab, float(w) if isinstance(w, int | float) else None, ref)

    def width_words(side: str, lab: str, width: float | None) -> tuple[float, str]:
        off_cm = 100 * (0.5 * (width or DEFAULT_ANKLE_WIDTH_M) + 0.5 * diameter)
        src = f"PROCESSING:{side}AnkleWidth" if width is not None else "population default"
        if given is not None:
            src = "given"
            w_file = file_widths.get(side)
            if (isinstance(w_file, int | float)
                    and round(1000 * w_file) != round(1000 * given[side])):
                src += f", instead of PROCESSING:{side}AnkleWidth {1000 * w_file:.0f} mm"
        if width is None:
            by_default.append((lab, off_cm))
        return off_cm, (f"ankle joint centre: {lab} moved {off_cm:.1f} cm medially (ankle "
                        f"width {1000 * (width or DEFAULT_ANKLE_WIDTH_M):.0f} mm: {src}; "
                        f"marker diameter {1000 * diameter:.0f} mm: {d_from}")

    unplaced: list[str] = []
    for side, (lab, med_lab, width, ref) in todo.items():
        medial = (fill_gaps(t, P[:, labels.index(med_lab)]) if med_lab is not None
                  else None)
        res = ankle_joint_centre(pts[side]["ankle"], medial, pts[side].get("heel"),
                                 pts[side].get("toe"), ref,
                                 width if width is not None else DEFAULT_ANKLE_WIDTH_M,
                                 diameter)
        if res is None:
            unplaced.append(side)
            continue
        centre, rule = res
        pts[side]["ankle_centre"] = centre
        if rule == "medial":
            sources[f"{side}_ankle_centre"] = (f"ankle joint centre: midpoint of {lab} and "
                                               f"{med_lab}")
            if given is not None:
                notes.append(f"The ankle width given for the {words[side]} foot "
                             f"({1000 * given[side]:.0f} mm) was not used: its medial "
                             f"malleolus marker {med_lab} places the joint centre, midway "
                             f"between it and {lab}.")
        else:
            sources[f"{side}_ankle_centre"] = width_words(side, lab, width)[1] + ")"
    for side in unplaced:
        lab, _, width, ref = todo[side]
        other = "R" if side == "L" else "L"
        n = None
        if "ankle_centre" in pts[other] and len(t) > 1:
            travel = travel_directions(0.5 * (pts[side]["ankle"] + pts[other]["ankle"]),
                                       float(1.0 / np.median(np.diff(t))))
            if travel is not None:
                n = walking_medial_directions(travel, pts[side]["ankle"], ref)
        if n is None:
            if forced:
                why = (f"the {words[side]} ankle joint centre cannot be placed from {lab}: "
                       "the file has no medial malleolus marker and no heel and toe markers "
                       "of that foot (its axis), nor the other foot's centre to place it "
                       "across the walking direction")
                needs = "it needs that foot's heel and toe markers (named like LHEE, LTOE)"
                raise InputError(
                    reason="{ankle_markers=lateral}: " + why,
                    advice=f"{needs}, or {{ankle_markers:clear}} to measure {lab} as it is "
                           "(with a note)")
            notes.append(f"The {words[side]} ankle marker {lab} is on the lateral malleolus "
                         "and no heel and toe markers give the foot's axis to find the joint "
                         f"centre from it: {lab} itself is measured, which puts the "
                         "crossing method's step widths about 8 cm wider (an ankle width "
                         "and a marker) than between the ankle joints.")
            continue
        off_cm, how = width_words(side, lab, width)
        pts[side]["ankle_centre"] = pts[side]["ankle"] + 0.01 * off_cm * n
        sources[f"{side}_ankle_centre"] = how + "; across the walking direction)"
        notes.append(f"The {words[side]} foot has no heel and toe markers to give its axis: "
                     f"its ankle joint centre was placed {off_cm:.1f} cm medial of {lab} "
                     "across the walking direction (the foot's turn-out unknown: each 10° "
                     "of it moves the centre about 7 mm along the walk, under 1 mm across), "
                     f"as the {words[other]} foot's was placed from its markers; measuring "
                     f"{lab} itself would make every step width about {off_cm:.0f} cm "
                     "wider.")
    if by_default:
        by_default.sort(key=lambda x: [v[0] for v in todo.values()].index(x[0]))  # L, R
        labs = " and ".join(lab for lab, _ in by_default)
        which = "joint centres were" if len(by_default) == 2 else "joint centre was"
        notes.append(f"The ankle {which} placed {by_default[0][1]:.1f} cm medial of {labs} "
                     f"with a population ankle width of {1000 * DEFAULT_ANKLE_WIDTH_M:.0f} mm "
                     "(the file gives neither medial malleolus markers nor the subject's "
                     "ankle widths): an ankle 1 cm wider or narrower than that makes the "
                     "crossing method's step widths about 1 cm narrower or wider.")
    return notes


def _check_units(P: FloatArray, labels: list[str], units: str) -> None:
    """A unit given by the user must give a body of human size (leg or height)."""
    L = characteristic_length(P, labels)
    if not 0.2 < L < 5.0:
        why = f"the body measures {L:.3g} m (leg length or height)"
        raise InputError(reason=f"with {{units={units.strip()}}} {why}",
                         advice="{units:change}")


def _check_up(P: FloatArray, labels: list[str], up: str) -> None:
    """A vertical axis given by the user must not contradict labelled pelvis/head and
    foot markers (a wrong one turns a height into a step width without a word)."""
    up_rotation(up)  # "w" is not an axis: say so rather than that it contradicts the body
    found = labelled_vertical_axis(P, labels)
    if found is not None and found != up.strip().lower().lstrip("+"):
        why = f"contradicts the markers: the pelvis/head are above the feet along {found}"
        raise InputError(reason=f"{{up={up.strip()}}} {why}", advice="{up:change}",
                         example=found)


def ankle_widths_by_side(ankle_width_m: float | tuple[float, ...] | None
                         ) -> dict[str, float] | None:
    """Check given ankle widths and return them per side.

    Args:
        ankle_width_m: One width for both feet, ``(left, right)``, or None; metres.

    Returns:
        ``{"L": m, "R": m}``, or None when none was given.

    Raises:
        InputError: not one or two numbers, or a width outside
            :data:`ANKLE_WIDTH_RANGE_M` (the message says how to give it).
    """
    if ankle_width_m is None:
        return None
    vals = (list(ankle_width_m) if isinstance(ankle_width_m, tuple | list | np.ndarray)
            else [ankle_width_m])
    def refused(why: str) -> InputError:
        return InputError(reason=why, advice="give the distance across the malleoli in "
                          "millimetres, one value for both feet or left,right: "
                          "{ankle_width_mm=70} or {ankle_width_mm=68,72}")

    if len(vals) not in (1, 2):
        raise refused(f"{len(vals)} ankle widths given")
    try:
        ws = [float(v) for v in vals]
    except (TypeError, ValueError):
        raise refused(f"ankle width {vals!r} is not a number") from None
    lo, hi = ANKLE_WIDTH_RANGE_M
    for side, w in zip(("left", "right") if len(ws) == 2 else ("both feet",), ws,
                       strict=True):
        if not (np.isfinite(w) and lo <= w <= hi):
            raise refused(f"an ankle width of {1000 * w:g} mm ({side}) is outside "
                          f"{1000 * lo:.0f}-{1000 * hi:.0f} mm (adult ankles measure about "
                          "55-90 mm)")
    return {"L": ws[0], "R": ws[-1]}


def _check_ankle_options(ankle_markers: str, widths: dict[str, float] | None,
                         named: bool) -> None:
    """Ankle options that cannot apply are refused (they would be silently ignored)."""
    if ankle_markers not in ANKLE_MARKER_RULES:
        raise InputError(reason=f"{{ankle_markers}} {ankle_markers!r} is not one of "
                         f"{', '.join(ANKLE_MARKER_RULES)}", option="ankle_markers")
    if named and (ankle_markers == "lateral" or widths is not None):
        lateral = ankle_markers == "lateral"
        given = "{ankle_markers=lateral" if lateral else "{ankle_width_mm"
        raise InputError(reason=given + "} applies to the ankle markers found by name; "
                         "with {markers} given, the named markers are measured as they are",
                         advice=given + ":clear}, or {markers:clear} to have the ankle "
                                "joint centres estimated", sep=": ")
    if ankle_markers == "joint" and widths is not None:
        raise InputError(reason="{ankle_width_mm} places joint centres from "
                         "lateral-malleolus markers; with {ankle_markers=joint} the markers "
                         "are the joint centres", advice="leave one of the two out",
                         option="ankle_width_mm", sep=": ")


def feet_from_markers(
    markers: MarkerTrajectories,
    left: str | None = None,
    right: str | None = None,
    up: str | None = None,
    units: str | None = None,
    ankle_markers: str = "auto",
    ankle_width_m: float | tuple[float, ...] | None = None,
) -> FeetTrajectories:
    """Map a mocap file's markers to per-foot trajectories (metres, Z up).

    Args:
        markers: as read by :func:`engine.io.c3d.read_c3d` / :func:`engine.io.trc.read_trc`.
        left: explicit left-foot marker (overrides the automatic choice of the point
            used for spatial parameters and crossings); give both or neither.
        right: explicit right-foot marker.
        up: vertical axis of the file (``x``, ``y``, ``z``, optionally ``-``); detected
            when None.
        units: unit the file's numbers are really in, overriding its header.
        ankle_markers: how the ankle markers are taken (:data:`ANKLE_MARKER_RULES`):
            ``"auto"`` by their names (``LANK`` lateral, ``L_Ankle`` a joint),
            ``"lateral"`` all on the lateral malleolus (joint centres estimated; an
            error when one cannot be), ``"joint"`` all joint centres already (measured
            as they are, even beside a medial marker).
        ankle_width_m: ankle width(s) across the malleoli, m: one for both feet or
            ``(left, right)``, used instead of the file's ``PROCESSING`` widths and the
            population default (:data:`DEFAULT_ANKLE_WIDTH_M`); within
            :data:`ANKLE_WIDTH_RANGE_M`.

    Returns:
        Per-foot trajectories in metres, Z up, on the file's time axis, with the labels
        used and what was detected (units, up axis); ``notes`` and the ``ankle_centre``
        sources say which ankle rule and widths were used.

    Raises:
        InputError: no usable ankle/heel data (the message says what is missing and
            lists the available labels), only one of ``left``/``right`` given, an ankle
            width out of range, or ankle options that cannot apply (with ``left``/
            ``right``, a width with ``"joint"``, a width or ``"lateral"`` without lateral
            ankle markers, a lateral marker whose centre cannot be placed).
    """
    labels = markers.labels
    if (left is None) != (right is None):
        raise InputError(advice="{markers:both}")
    given = ankle_widths_by_side(ankle_width_m)
    _check_ankle_options(ankle_markers, given, left is not None)
    if len(markers) < 2:
        # said before the marker search, which would call the markers unusable
        raise InputError(f"the file holds {count(len(markers), 'frame')}; gait needs a recording "
                         "of at least two steps of walking")
    P = markers.positions
    if units is not None:
        P = P / unit_scale(markers.units) * unit_scale(units)
        _check_units(P, labels, units)
    else:
        # A header that disagrees with the body size by 10x or more is wrong (seen in
        # exports that write "m" over millimetre data); trust the body size then.
        raw = P / unit_scale(markers.units)
        guess = detect_units(raw, labels)
        plausible = 0.3 < characteristic_length(P, labels) < 3.0
        if guess != markers.units.strip().lower() and not plausible:
            P = raw * unit_scale(guess)
    if up is not None:
        _check_up(P, labels, up)
    up_axis = up or detect_vertical_axis(P, labels)
    P = to_z_up(P, up_axis)
    t = markers.times

    pts: dict[str, dict[str, FloatArray]] = {"L": {}, "R": {}}
    sources: dict[str, str] = {"up": up_axis}
    primary: dict[str, str] = {}
    explicit: dict[str, str] = {}
    scope = labels  # where the other foot points and the pelvis are looked for
    if left is not None and right is not None:
        explicit = {"L": resolve_label(labels, left), "R": resolve_label(labels, right)}
        prefixes = {lab.rpartition(":")[0] for lab in explicit.values()}
        if len(prefixes) == 1 and "" not in prefixes:
            # a subject chosen by prefix: take its heels, toes and pelvis, not another's
            scope = [x for x in labels if x.rpartition(":")[0] in prefixes | {""}]
    empty: list[str] = []  # ankle/heel markers that are there but never seen
    for side in ("L", "R"):
        for part in ("ankle", "heel", "toe"):
            lab = find_marker(scope, side, part)
            same = [x for x in scope if _key(x) == _key(lab)] if lab is not None else []
            if len(same) > 1 and left is None:
                # e.g. two subjects' Plug-in Gait sets: analysing the first silently
                # could report the wrong person.
                why = f"several markers are named like {lab!r}: {', '.join(same)}"
                raise InputError(reason=why, advice="choose one subject's feet {markers:by}",
                                 example=same[0])
            if lab is not None:
                x = fill_gaps(t, P[:, labels.index(lab)])
                if np.isfinite(x).all(axis=1).sum() >= 2:
                    pts[side][part] = x
                    sources[f"{side}_{part}"] = lab
                elif part != "toe":
                    empty.append(lab)
    if explicit:
        for side, lab in explicit.items():
            x = fill_gaps(t, P[:, labels.index(lab)])
            if np.isfinite(x).all(axis=1).sum() < 2:
                raise InputError(f"marker {lab!r} has no data")
            pts[side]["explicit"] = x
            sources[f"{side}_explicit"] = lab
            primary[side] = "explicit"
    else:
        missing = []
        for side, word in (("L", "left"), ("R", "right")):
            have = [p for p in ("ankle", "heel") if p in pts[side]]
            if not have:
                missing.append(f"{word} ankle or heel")
            else:
                primary[side] = have[0]
        if missing and empty:
            why = (f"no usable {' and no '.join(missing)} marker: {', '.join(empty)} "
                   f"{'holds' if len(empty) == 1 else 'hold'} no data (missing in every "
                   "frame but at most one)")
            raise InputError(reason=why, advice="name other foot markers {markers:by}")
        if missing:
            names = "LANK/RANK, LHEE/RHEE, L.Ankle, L_FAL, L_FCC, AnkleLeft"
            what, available = (f"no usable {' and no '.join(missing)} marker",
                               "available labels: " + ", ".join(labels))
            advice = "name the foot markers {markers:by}"
            raise InputError(
                # the command line's own reason points to its documentation of the names,
                # which a page has not (a page says the reason given here)
                f"{what} (looked for names like {names}: docs/gait-json.md lists them); "
                f"{available}; {fill(advice, cli_say)}",
                reason=f"{what} (markers named like {names} are recognised); {available}",
                advice=advice)
    notes: list[str] = []
    ankles = [sources[f"{s}_ankle"] for s in ("L", "R") if f"{s}_ankle" in sources]
    if not explicit and ankle_markers != "auto":
        if not ankles:
            why = ("the file has no ankle marker (looked for names like LANK, L_Ankle, "
                   "L.Ankle.Lat, L_FAL)")
            raise InputError(reason=f"{{ankle_markers={ankle_markers}}}: {why}",
                             advice="{ankle_markers:clear}")
        notes.append(f"The ankle {'markers' if len(ankles) == 2 else 'marker'} "
                     f"{' and '.join(ankles)} {'were' if len(ankles) == 2 else 'was'} taken "
                     + ("for lateral-malleolus markers, as asked (ankle markers: lateral)."
                        if ankle_markers == "lateral" else
                        "for the ankle joint centres, as asked (ankle markers: joint), and "
                        "measured as they are."))
    if not explicit and ankle_markers != "joint":
        # A lateral-malleolus marker (LANK) is 3-4 cm outside the joint the crossing
        # method was designed for (a skeleton's ankle): its joint centre is measured.
        notes += _ankle_centres(pts, sources, scope, P[:, [labels.index(x) for x in scope]],
                                t, markers.meta, ankle_markers == "lateral", given)
        if given is not None and not any(f"{s}_ankle_centre" in sources for s in ("L", "R")):
            names = " and ".join(ankles) or "the file's ankle markers"
            why = (f"is not used: {names} {'are' if len(ankles) != 1 else 'is'} taken for "
                   "ankle joint centres by name (or no ankle marker was found)")
            raise InputError(reason="{ankle_width_mm} " + why,
                             advice="give {ankle_markers=lateral} if they are on the lateral "
                                    "malleoli, or {ankle_width_mm:clear}")
        for side in ("L", "R"):
            if primary[side] == "ankle" and "ankle_centre" in pts[side]:
                primary[side] = "ankle_centre"
    pelvis = _pelvis(scope, P[:, [labels.index(x) for x in scope]], t)
    if pelvis is not None:
        sources["pelvis"] = pelvis[1]
    return FeetTrajectories(t, float(markers.rate), pts, primary,
                            None if pelvis is None else pelvis[0], sources,
                            list(markers.events), notes=notes)


def _pelvis(labels: list[str], P: FloatArray, t: FloatArray) -> tuple[FloatArray, str] | None:
    """Pelvis centre: the mean of the PSIS and ASIS pairs found (either pair will do),
    else a one-marker sacrum/pelvis, else the mean of the two hips; None without any."""
    idx: list[int] = []
    for part in ("psis", "asis"):
        pair = [find_marker(labels, side, part) for side in ("L", "R")]
        if pair[0] is not None and pair[1] is not None:
            idx += [labels.index(pair[0]), labels.index(pair[1])]
    if not idx:
        keys = [_key(lab) for lab in labels]
        single = next((keys.index(s) for s in PELVIS_SINGLE if s in keys), None)
        if single is not None:
            return fill_gaps(t, P[:, single]), labels[single]
        hips = [find_marker(labels, side, "hip") for side in ("L", "R")]
        if hips[0] is None or hips[1] is None:
            return None
        idx = [labels.index(hips[0]), labels.index(hips[1])]
    x = fill_gaps(t, nanstats.nanmean(P[:, idx], axis=1))  # NaN: no marker
    return x, "+".join(labels[i] for i in idx)


def feet_from_skeleton(series: SkeletonSeries, up: str | None = "z",
                       tracked_only: bool = True) -> FeetTrajectories:
    """Per-foot trajectories of a skeleton (ankle joints; foot joints as toes).

    Args:
        series: A skeleton in a world frame (time first axis, metres).
        up: Its vertical axis (``"z"`` for the project's world frame; None to detect,
            e.g. for a CSV file in a camera's Y-down frame).
        tracked_only: Treat INFERRED joints as missing (the paper's rule).

    Returns:
        The ankles (``ankle`` points; foot joints as ``toe``) in metres, Z up, on the
        series' time axis.

    Raises:
        InputError: the skeleton has no tracked ankle of a side.
    """
    js = series.joint_set
    P = series.tracked_positions() if tracked_only else series.positions.copy()
    up_axis = up or detect_vertical_axis(P, list(js.joints))
    P = to_z_up(P, up_axis)
    t = series.times
    rate = float(1.0 / np.median(np.diff(t))) if len(t) > 1 else 30.0
    pts: dict[str, dict[str, FloatArray]] = {"L": {}, "R": {}}
    sources: dict[str, str] = {"up": up_axis}
    for side, word in (("L", "left"), ("R", "right")):
        for part, role in (("ankle", f"ankle_{word}"), ("toe", f"foot_{word}")):
            name = js.roles[role]
            x = fill_gaps(t, P[:, js.index(name)])
            if np.isfinite(x).all(axis=1).sum() >= 2:
                pts[side][part] = x
                sources[f"{side}_{part}"] = name
        if "ankle" not in pts[side]:
            raise InputError(f"the skeleton has no tracked {js.roles[f'ankle_{word}']} "
                             "positions; gait needs both ankles")
    pelvis = fill_gaps(t, P[:, js.role_index("pelvis")])
    has_pelvis = np.isfinite(pelvis).all(axis=1).sum() >= 2
    return FeetTrajectories(t, rate, pts, {"L": "ankle", "R": "ankle"},
                            pelvis if has_pelvis else None, sources, from_skeleton=True)


def load_feet(path: str | Path, left: str | None = None, right: str | None = None,
              up: str | None = None, units: str | None = None, ankle_markers: str = "auto",
              ankle_width_m: float | tuple[float, ...] | None = None) -> FeetTrajectories:
    """Read a C3D, TRC or skeleton CSV file and return its per-foot trajectories.

    What was detected is in the result: ``sources`` (the marker/joint labels used per
    foot point and the pelvis, and the up axis), ``events`` (the file's annotated
    events, e.g. Vicon Nexus foot strikes); ``print(feet)`` shows both.

    Args:
        path: a ``.c3d``, ``.trc`` or skeleton ``.csv`` (``time,<Joint>_x,_y,_z[,_state]``)
            file.
        left, right: the foot marker (or joint) names to analyse, both or neither
            (``gaitrig gait --left/--right``); default: found automatically (Plug-in Gait
            ``LANK/LHEE/LTOE``, ``L.Ankle``, ``LeftAnkle``, ``Subject:`` prefixes, ...).
        up: the vertical axis of the file, ``"x"``, ``"y"``, ``"z"`` or ``"-x"``, ``"-y"``,
            ``"-z"`` (``--up``); default: detected from the body.
        units: ``"mm"``, ``"cm"`` or ``"m"`` (``--units``), overriding the file's own
            unit or the one guessed from the body size.
        ankle_markers: ``"auto"``, ``"lateral"`` or ``"joint"`` (``--ankle-markers``):
            whether the ankle markers are on the lateral malleolus (their joint centre
            estimated) or joint centres already; ``"auto"`` tells by their names
            (:func:`feet_from_markers`). A skeleton CSV's ankles are joints.
        ankle_width_m: ankle width(s), m, one or ``(left, right)`` (``--ankle-width-mm``),
            instead of the file's ``PROCESSING`` widths or the population default
            (TRC and CSV files carry none).

    Returns:
        Per-foot trajectories in metres, Z up, on the file's time axis.

    Raises:
        InputError: unknown extension, unreadable file, no usable foot data, a
            ``left``/``right``/``up``/``units`` that contradicts the file, or ankle
            options that cannot apply to it (the message says which).
    """
    from engine.io.c3d import read_c3d
    from engine.io.csv import read_skeleton_csv
    from engine.io.trc import read_trc

    p = Path(path)
    if p.is_dir():
        raise InputError(f"{p} is a folder; give a .c3d, .trc or .csv file")
    ext = p.suffix.lower()
    # the options are refused before the file is read
    _check_ankle_options(ankle_markers, ankle_widths_by_side(ankle_width_m), left is not None)
    if ext == ".c3d":
        data: MarkerTrajectories | SkeletonSeries = read_c3d(p)
    elif ext == ".trc":
        data = read_trc(p)
    elif ext == ".csv":
        _refuse_skeleton_ankle_options(ankle_markers, ankle_width_m)
        data = read_skeleton_csv(p)
    else:
        raise InputError(f"unsupported file type {p.suffix!r}; use .c3d, .trc or .csv")
    return feet_from_file_data(data, left, right, up, units, ankle_markers, ankle_width_m)


def _refuse_skeleton_ankle_options(ankle_markers: str,
                                   ankle_width_m: float | tuple[float, ...] | None) -> None:
    """Refuse ankle options given for a skeleton CSV (its ankles are joints)."""
    if ankle_markers == "lateral" or ankle_widths_by_side(ankle_width_m) is not None:
        lateral = ankle_markers == "lateral"
        why = "applies to marker files (.c3d, .trc); a skeleton CSV's ankles are joints"
        raise InputError(reason=("{ankle_markers=lateral} " if lateral
                                 else "{ankle_width_mm} ") + why,
                         advice="leave it out",
                         option="ankle_markers" if lateral else "ankle_width_mm", sep=": ")


def feet_from_file_data(data: MarkerTrajectories | SkeletonSeries, left: str | None = None,
                        right: str | None = None, up: str | None = None,
                        units: str | None = None, ankle_markers: str = "auto",
                        ankle_width_m: float | tuple[float, ...] | None = None
                        ) -> FeetTrajectories:
    """:func:`load_feet` of a file already read (a server checking an upload reads it
    once for both its own use and the gait analysis).

    Args:
        data: what :func:`engine.io.c3d.read_c3d` or :func:`engine.io.trc.read_trc`
            (markers) or :func:`engine.io.csv.read_skeleton_csv` (a skeleton) returned;
            not changed (a skeleton's units are scaled in a copy).
        left, right, up, units, ankle_markers, ankle_width_m: :func:`load_feet`'s.

    Returns:
        Per-foot trajectories in metres, Z up, as :func:`load_feet` returns for the file.

    Raises:
        InputError: as :func:`load_feet`, but for reading the file.
    """
    given = ankle_widths_by_side(ankle_width_m)
    _check_ankle_options(ankle_markers, given, left is not None)
    if isinstance(data, MarkerTrajectories):
        return feet_from_markers(data, left, right, up, units, ankle_markers, ankle_width_m)
    _refuse_skeleton_ankle_options(ankle_markers, ankle_width_m)
    s = copy.copy(data)  # its positions are rescaled below: the caller's stay as read
    joints = list(s.joint_set.joints)
    if units is not None:
        s.positions = s.positions * unit_scale(units)
        _check_units(s.positions, joints, units)
    else:
        # The format is metres, but a file in mm or cm would give 1000 m steps:
        # its body size tells the unit, as for C3D/TRC files without one. Too few
        # joints to tell leave the format's metres (missing feet are named below).
        try:
            size: float | None = characteristic_length(s.positions, joints)
        except InputError:
            size = None
        if size is not None and not 0.3 < size < 3.0:
            s.positions = s.positions * unit_scale(detect_units(s.positions, joints))
    if left is not None or right is not None:
        m = MarkerTrajectories(s.times, s.tracked_positions(), list(s.joint_set.joints),
                               float(1.0 / np.median(np.diff(s.times))) if len(s) > 1 else 30.0,
                               "m")
        return feet_from_markers(m, left, right, up, None)
    if up is not None:
        _check_up(s.tracked_positions(), joints, up)
    return feet_from_skeleton(s, up=up)
