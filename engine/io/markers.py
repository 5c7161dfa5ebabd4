"""Marker trajectories read from mocap files, with unit and vertical-axis detection.

:class:`MarkerTrajectories` is the common in-memory form of a C3D or TRC file: positions
are always in metres in the file's own axes (no rotation is applied on read), so a
file written back is the file read. :func:`detect_vertical_axis` and :func:`to_z_up`
turn the file's axes into the project's Z-up convention when an analysis needs it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine import nanstats as ns
from engine.errors import InputError

#: metres per unit for the unit strings found in C3D/TRC files.
UNIT_SCALE: dict[str, float] = {"mm": 1e-3, "cm": 1e-2, "dm": 1e-1, "m": 1.0}

AXES = ("x", "y", "z")


@dataclass(frozen=True)
class MarkerEvent:
    """One annotated event (e.g. a Vicon Nexus foot strike).

    Attributes:
        time_s: seconds on the file's time axis.
        side: ``"L"``, ``"R"`` or ``""`` (general / unknown).
        kind: ``"foot_strike"``, ``"foot_off"``, ``"placement"`` or the file's label
            lower-cased.
        label: the label as written in the file.
    """

    time_s: float
    side: str
    kind: str
    label: str = ""


def normalise_event(label: str, context: str, time_s: float) -> MarkerEvent:
    """Map a file's event label/context to a :class:`MarkerEvent`.

    Args:
        label: The event's label (``"Foot Strike"``, ``"Heel Strike"``, ``"Toe Off"`` ...).
        context: Its context (``"Left"``, ``"Right"``; anything else: no side).
        time_s: Its time, s.

    Returns:
        The event with kind ``foot_strike``, ``foot_off``, ``placement`` or the label in
        snake case, and side ``L``, ``R`` or ``""``.
    """
    ctx = context.strip().lower()
    side = "L" if ctx.startswith("l") else "R" if ctx.startswith("r") else ""
    key = re.sub(r"[^a-z]", "", label.lower())
    if key in ("footstrike", "heelstrike", "initialcontact", "fs", "hs", "ic"):
        kind = "foot_strike"
    elif key in ("footoff", "toeoff", "finalcontact", "fo", "to"):
        kind = "foot_off"
    elif key in ("footplacement", "placement"):
        kind = "placement"
    else:
        kind = label.strip().lower().replace(" ", "_")
    return MarkerEvent(float(time_s), side, kind, label)


@dataclass
class MarkerTrajectories:
    """Labelled 3-D marker trajectories.

    Attributes:
        times: ``(T,)`` seconds, strictly increasing.
        positions: ``(T, M, 3)`` metres, NaN where a marker is missing (infinities
            become NaN).
        labels: ``M`` marker labels as in the file.
        rate: sampling rate in Hz.
        units: the length unit the file was written in (``"mm"``, ``"m"`` ...).
        events: annotated events, in file order.
        meta: free-form provenance (source path, description ...).
    """

    times: NDArray[np.float64]
    positions: NDArray[np.float64]
    labels: list[str]
    rate: float
    units: str = "m"
    events: list[MarkerEvent] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.times = np.asarray(self.times, dtype=float)
        self.positions = np.array(self.positions, dtype=float)
        # an "inf" cell in a text file is as missing as an empty one
        self.positions[np.isinf(self.positions)] = np.nan
        self.labels = [str(s) for s in self.labels]
        T = len(self.times)
        if self.positions.ndim != 3 or self.positions.shape != (T, len(self.labels), 3):
            raise InputError(
                f"marker positions must have shape ({T}, {len(self.labels)}, 3), "
                f"got {self.positions.shape}"
            )
        if T > 1 and not np.all(np.diff(self.times) > 0):
            raise InputError("marker times must be strictly increasing")
        if not (np.isfinite(self.rate) and self.rate > 0):
            raise InputError(f"sampling rate must be positive, got {self.rate}")

    def __len__(self) -> int:
        return len(self.times)

    def __repr__(self) -> str:
        # A notebook shows the object: its shape, span and labels, not the arrays.
        T = len(self.times)
        span = f"{self.times[0]:.2f}–{self.times[-1]:.2f} s" if T else "empty"
        shown = ", ".join(self.labels[:12]) + (", …" if len(self.labels) > 12 else "")
        return (f"MarkerTrajectories({T} frames, {span}, {self.rate:g} Hz, "
                f"{len(self.labels)} markers [{shown}], file units {self.units!r} "
                f"(positions in m), {len(self.events)} events)")

    def index(self, label: str) -> int:
        """Index of ``label`` (exact match) on the marker axis.

        Args:
            label: The marker's label as in the file.

        Returns:
            Its position in ``labels``.

        Raises:
            InputError: no such label (the message lists the labels).
        """
        try:
            return self.labels.index(label)
        except ValueError:
            raise InputError(
                f"marker {label!r} not found; available: {', '.join(self.labels)}"
            ) from None

    def marker(self, label: str) -> NDArray[np.float64]:
        """``(T, 3)`` trajectory of one marker (metres, file axes, time first axis).

        Args:
            label: The marker's label (exact match).

        Returns:
            A view into ``positions`` (NaN where the marker was not seen).

        Raises:
            InputError: no such label.
        """
        return self.positions[:, self.index(label)]


def check_time_unit(times: NDArray[np.float64], name: str) -> None:
    """Refuse a time column that is not in seconds (ms, µs, 100 ns ticks ...).

    Gait needs at least a few samples per second, so a median frame step of more than
    half a second means another unit: without this the analysis would only say that no
    walking was found.

    Args:
        times: ``(T,)`` the file's time column.
        name: The file's name, for the message.

    Raises:
        InputError: a median step above 0.5 (the message names the likely unit).
    """
    if len(times) > 1:
        dt = float(np.median(np.diff(times)))
        if dt > 0.5:
            raise InputError(f"{name}: the times advance {dt:g} per frame; the time column "
                             "must be in seconds (is it in milliseconds or ticks?)")


#: Spelled-out unit names (singular, plural, British or US spelling) → symbol.
_UNIT_WORDS = {"millimeter": "mm", "millimetre": "mm", "centimeter": "cm",
               "centimetre": "cm", "decimeter": "dm", "decimetre": "dm", "meter": "m",
               "metre": "m"}


def normalise_units(units: str) -> str | None:
    """The symbol (``"mm"``, ``"cm"``, ``"dm"``, ``"m"``) of a file's unit string, or None.

    Exporters write the unit in any case, padded, in brackets or spelled out
    (``"MM"``, ``" mm"``, ``"[mm]"``, ``"Millimeter"``, ``"metres"``); None for an empty
    or unknown string (the caller then guesses the unit from the body size).

    Args:
        units: The file's unit string.

    Returns:
        ``"mm"``, ``"cm"``, ``"dm"``, ``"m"`` or None.
    """
    u = units.strip().strip("[]()").strip().rstrip(".").lower()
    u = _UNIT_WORDS.get(u.removesuffix("s") if len(u) > 2 else u, u)
    return u if u in UNIT_SCALE else None


def rounded_grid(times: NDArray[np.float64], rate: float | None = None
                 ) -> NDArray[np.float64]:
    """The uniform grid that ``times`` are, printed with few decimals.

    Exporters print times with 3 decimals (steps of 6 and 7 ms at 150 Hz, 33 and 34 ms
    at 30 Hz); that jitter goes into the velocities that time gait events. A time column
    within 1 ms (and a quarter frame) of a uniform grid is that grid; any other (dropped
    frames, a clock that drifts) is returned unchanged.

    Args:
        times: ``(T,)`` seconds, increasing.
        rate: the grid's rate (Hz) when the file states it; else fitted (least squares).

    Returns:
        ``(T,)`` times, s: the grid, or ``times`` unchanged.
    """
    if len(times) < 3:
        return times
    i = np.arange(len(times), dtype=float)
    step = (1.0 / rate if rate is not None and np.isfinite(rate) and rate > 0
            else float(np.polyfit(i, times, 1)[0]))
    grid = i * step
    t0 = float(np.mean(times - grid))
    dev = float(np.max(np.abs(times - (t0 + grid))))
    return t0 + grid if 1e-9 < dev <= min(1e-3, 0.25 * step) else times


def unit_scale(units: str) -> float:
    """Metres per ``units`` (``"mm"``, ``"cm"``, ``"m"``, spelled out or in any case).

    Args:
        units: A file's unit string (``"mm"``, ``"millimeters"``, ``"M"`` ...).

    Returns:
        The factor to metres (0.001 for mm).

    Raises:
        InputError: not a length unit.
    """
    u = normalise_units(units)
    if u is None:
        raise InputError(f"unknown length unit {units!r}; use one of mm, cm, m")
    return UNIT_SCALE[u]


def file_units(units: str, positions: ArrayLike, labels: list[str]) -> str:
    """The unit of a file's numbers: its header's, or guessed from the body size.

    The header's unit is normalised (:func:`normalise_units`); the body size decides
    (:func:`detect_units`) when the header gives none or one that is not a length unit
    (``--units`` then overrides it).

    Args:
        units: The header's unit string.
        positions: ``(T, M, 3)`` marker positions in that unit.
        labels: The ``M`` marker labels.

    Returns:
        ``"mm"``, ``"cm"``, ``"dm"`` or ``"m"``.

    Raises:
        InputError: no unit in the header and too few markers to guess one.
    """
    return normalise_units(units) or detect_units(positions, labels)


#: Body-part name stems (after the side token is removed), most preferred first. Stems
#: of two letters (IOR ``LM``, ``CA``) only match after a side prefix (``L_LM``).
PART_STEMS: dict[str, tuple[str, ...]] = {
    "ankle": ("ank", "ankle", "lmal", "malleolus", "latmal", "latmalleolus",
              "lateralmalleolus", "mal", "ajc", "anklejc", "fal", "lma", "lm"),
    "heel": ("hee", "heel", "fcc", "cal", "calc", "calcaneus", "pca", "dhe", "phe", "lhe",
             "ca"),
    "toe": ("toe", "ttoe", "mt2", "fm2", "mth2", "mt1", "fm1", "toetip", "bigtoe",
            "footindex", "2nd", "foot", "foo"),
    "asis": ("asi", "asis", "ias"),
    "psis": ("psi", "psis", "ips"),
    "hip": ("hip", "hjc"),
}
#: Words after a part's name that say which point of it is marked, as in ``L.Ankle.Lat``
#: (OpenSim), ``LAnkleOut``, ``LHeelBack``, ``LToeTip`` (Qualisys): tried after the bare
#: name. Medial points (``Ankle.Med``) are not taken for the ankle (they serve to place
#: its joint centre: :func:`find_medial_ankle`).
PART_QUALIFIERS = ("lat", "lateral", "out", "outer", "back", "post", "posterior", "tip")
#: Ankle stems (of :data:`PART_STEMS`) that name a marker on the LATERAL malleolus (Plug-in
#: Gait / Helen Hayes ``LANK``, CAST ``L_FAL``, ``LLMA``, IOR ``L_LM``): the ankle joint
#: centre lies ankle width / 2 + marker radius medial of it. A bare ``Ankle`` (Kinect
#: ``AnkleLeft``, OpenPose ``LAnkle``, MediaPipe ``left_ankle``) and ``AJC`` name the joint
#: itself; with a lateral qualifier (``L.Ankle.Lat``, ``LAnkleOut``) it is the malleolus.
LATERAL_ANKLE_STEMS = ("ank", "lmal", "malleolus", "latmal", "latmalleolus",
                       "lateralmalleolus", "mal", "fal", "lma", "lm")
#: Qualifiers (:data:`PART_QUALIFIERS`) that make any ankle name a lateral-malleolus one.
LATERAL_QUALIFIERS = ("lat", "lateral", "out", "outer")
#: Medial malleolus names: Plug-in Gait's optional ``LMED``, Oxford Foot Model / Qualisys
#: ``LMMA``, ``L_MMAL``, ``LMedMal``, CAST ``L_TAM``, IOR ``L_MM`` (two letters: side in
#: front only), and any ankle name with a medial qualifier (OpenSim ``L.Ankle.Med``,
#: ``LAnkleIn``).
MEDIAL_ANKLE_STEMS = ("med", "mma", "mmal", "medmal", "medmalleolus", "medialmalleolus",
                      "tam", "mm")
#: Qualifiers after an ankle name that make it the medial malleolus.
MEDIAL_QUALIFIERS = ("med", "medial", "in", "inner")
#: One-marker pelvis/sacrum names (bare, lower-case, alphanumeric).
PELVIS_SINGLE = ("sacr", "sacrum", "vsacral", "sacral", "pelvis", "spinebase", "hipcenter",
                 "midhip", "root")
_HEAD = ("c7", "head", "lfhd", "rfhd", "lbhd", "rbhd")
_SIDE_TOKENS = {"L": ("l", "left", "lt"), "R": ("r", "right", "rt")}


def label_key(label: str) -> str:
    """Bare, lower-case, alphanumeric form of a label (``Subject:`` prefix removed).

    Args:
        label: A marker label (``"Sub01:L_Heel"``).

    Returns:
        The key (``"lheel"``).
    """
    return re.sub(r"[^a-z0-9]", "", label.split(":")[-1].lower())


def side_part_keys(side: str, stem: str,
                   qualifiers: tuple[str, ...] = PART_QUALIFIERS) -> list[str]:
    """The label keys (:func:`label_key`) naming ``stem`` on ``side``, in order.

    Side token before or after the stem, then with a word of ``qualifiers``.

    Args:
        side: ``"L"`` or ``"R"``.
        stem: A part's stem (``"hee"``, ``"ank"`` ...).
        qualifiers: Words that may follow the stem (default :data:`PART_QUALIFIERS`).

    Returns:
        The candidate keys, most likely first.
    """
    ks: list[str] = []
    for q in ("",) + (qualifiers if len(stem) > 2 else ()):
        for tok in _SIDE_TOKENS[side]:
            ks.append(tok + stem + q)
            if len(stem) > 2:
                ks.append(stem + q + tok)
    return ks


def find_marker(labels: list[str], side: str, part: str) -> str | None:
    """Label of the ``part`` marker of ``side``, or None.

    Args:
        labels: The file's marker labels.
        side: ``"L"`` or ``"R"``.
        part: A :data:`PART_STEMS` key: ``ankle``, ``heel``, ``toe``, ``asis``, ``psis``,
            ``hip``.

    Returns:
        The label as in the file, or None when no label names that part.
    """
    keys = [label_key(lab) for lab in labels]
    for stem in PART_STEMS[part]:
        for k in side_part_keys(side, stem):
            if k in keys:
                return labels[keys.index(k)]
    return None


def is_lateral_ankle(label: str, side: str) -> bool:
    """Whether an ankle marker's label names the lateral malleolus of ``side``.

    Args:
        label: The label :func:`find_marker` gave for the ankle (``"LANK"``,
            ``"Sub:L.Ankle.Lat"``).
        side: ``"L"`` or ``"R"``.

    Returns:
        True for :data:`LATERAL_ANKLE_STEMS` and ankle names with a
        :data:`LATERAL_QUALIFIERS` word; False for joint names (``AnkleLeft``, ``LAJC``).
    """
    k = label_key(label)
    keys = {x for stem in LATERAL_ANKLE_STEMS for x in side_part_keys(side, stem)}
    keys |= {x for stem in ("ankle", "ank") for x in side_part_keys(side, stem,
                                                                    LATERAL_QUALIFIERS)
             if x not in side_part_keys(side, stem, ())}  # a bare "Ankle" is the joint
    return k in keys


def find_medial_ankle(labels: list[str], side: str) -> str | None:
    """Label of the medial malleolus marker of ``side``, or None.

    Args:
        labels: The file's marker labels.
        side: ``"L"`` or ``"R"``.

    Returns:
        The label as in the file (:data:`MEDIAL_ANKLE_STEMS`, or an ankle name with a
        :data:`MEDIAL_QUALIFIERS` word such as ``L.Ankle.Med``), or None.
    """
    keys = [label_key(lab) for lab in labels]
    cands = [x for stem in MEDIAL_ANKLE_STEMS for x in side_part_keys(side, stem, ())]
    for stem in ("ankle", "ank", "malleolus", "mal"):
        cands += [x for x in side_part_keys(side, stem, MEDIAL_QUALIFIERS)
                  if x not in side_part_keys(side, stem, ())]
    for k in cands:
        if k in keys:
            return labels[keys.index(k)]
    return None


def _keys_of(parts: tuple[str, ...]) -> set[str]:
    return {k for p in parts for stem in PART_STEMS[p] for side in _SIDE_TOKENS
            for k in side_part_keys(side, stem)}


_FOOT_KEYS = _keys_of(("ankle", "heel", "toe"))
_UPPER_KEYS = _keys_of(("asis", "psis", "hip")) | set(PELVIS_SINGLE) | set(_HEAD)


def _group(labels: list[str], keys: set[str]) -> list[int]:
    """Indices of the labels whose :func:`label_key` is in ``keys``."""
    return [i for i, lab in enumerate(labels) if label_key(lab) in keys]


def characteristic_length(positions: ArrayLike, labels: list[str]) -> float:
    """A body length in the file's units, used to guess units.

    Leg length (pelvis markers to foot markers) when both are labelled, else the median
    over frames of the largest marker extent along any axis (≈ body height).

    Args:
        positions: ``(T, M, 3)`` marker positions, file units.
        labels: The ``M`` marker labels.

    Returns:
        The length, file units.

    Raises:
        InputError: no frame with two or more markers.
    """
    P = np.asarray(positions, dtype=float)
    up = _group(labels, _UPPER_KEYS)
    feet = _group(labels, _FOOT_KEYS)
    # missing markers are expected in mocap data: the ns.* reductions give NaN silently
    if up and feet:
        d = ns.nanmean(P[:, up], axis=1) - ns.nanmean(P[:, feet], axis=1)
        L = float(ns.nanmedian(np.linalg.norm(d, axis=-1)))
        if np.isfinite(L) and L > 0:
            return L
    ext = ns.nanmax(P, axis=1) - ns.nanmin(P, axis=1)
    L = float(ns.nanmedian(ns.nanmax(ext, axis=-1)))
    if not np.isfinite(L) or L <= 0:
        why = "cannot guess the length unit: no frame with two or more markers"
        raise InputError(reason=why, advice="{units:give}")
    return L


def detect_units(positions: ArrayLike, labels: list[str]) -> str:
    """Guess ``"mm"``, ``"cm"`` or ``"m"`` from the size of the body.

    A leg is 0.5–1.2 m and a body 0.3–2.2 m tall (feet-only sets are short), so a
    characteristic length below 5 means metres, below 300 centimetres, else millimetres.

    Args:
        positions: ``(T, M, 3)`` marker positions in the file's unknown unit.
        labels: The ``M`` marker labels (tell feet, pelvis and head markers apart).

    Returns:
        ``"m"``, ``"cm"`` or ``"mm"``.

    Raises:
        InputError: no frame with two or more markers.
    """
    L = characteristic_length(positions, labels)
    if L < 5.0:
        return "m"
    if L < 300.0:
        return "cm"
    return "mm"


def labelled_vertical_axis(positions: ArrayLike, labels: list[str]) -> str | None:
    """Vertical axis told by labelled markers: the one along which pelvis/head sit above feet.

    Args:
        positions: ``(T, M, 3)`` marker positions.
        labels: The ``M`` marker labels.

    Returns:
        The axis with sign (``"z"``, ``"-y"`` ...) along which the labelled pelvis/head
        markers sit furthest above the labelled foot markers, or None when the set lacks
        either group.
    """
    P = np.asarray(positions, dtype=float)
    up = _group(labels, _UPPER_KEYS)
    feet = _group(labels, _FOOT_KEYS)
    if up and feet:
        d = ns.nanmedian(ns.nanmean(P[:, up], axis=1) - ns.nanmean(P[:, feet], axis=1),
                         axis=0)
        if np.all(np.isfinite(d)):
            a = int(np.argmax(np.abs(d)))
            return ("" if d[a] > 0 else "-") + AXES[a]
    return None


def detect_vertical_axis(positions: ArrayLike, labels: list[str]) -> str:
    """Guess the vertical axis of a marker set, with sign (``"z"``, ``"-y"`` ...).

    With labelled pelvis/head and foot markers the vertical axis is the one along which
    the upper body sits furthest from the feet (sign included). Otherwise, with left and
    right foot markers of the same kind (:func:`floor_axis`), it is the axis along
    which the feet are at one level whenever they stand still (the floor); without
    those, the axis with the largest per-frame marker spread (a standing or walking
    body is taller than wide) and the least travel of the marker centroid (people walk
    on a floor). Its sign is then the one towards which labelled foot markers' heights
    are skewed (long stances on the floor, short swings above it), else positive.

    Args:
        positions: ``(T, M, 3)`` in any length unit, time first.
        labels: ``M`` marker labels.

    Returns:
        One of ``x, y, z, -x, -y, -z``.

    Raises:
        InputError: too few markers, or the feet do not tell the vertical from the
            lateral axis (the message says to give ``--up``).
    """
    P = np.asarray(positions, dtype=float)
    labelled = labelled_vertical_axis(P, labels)
    if labelled is not None:
        return labelled
    feet = _group(labels, _FOOT_KEYS)
    a_floor = floor_axis(P, labels)
    if a_floor is not None:
        a = a_floor
    else:
        spread = ns.nanmedian(ns.nanstd(P, axis=1), axis=0)
        centroid = ns.nanmean(P, axis=1)
        travel = ns.nanstd(centroid, axis=0)
        if not np.all(np.isfinite(spread)):
            why = "cannot detect the vertical axis: too few markers"
            raise InputError(reason=why, advice="{up:give}")
        score = spread / (travel + spread.max() * 0.1 + 1e-12)
        a = int(np.argmax(score))
    return ("-" if feet and _height_skew(P[:, feet, a]) < 0 else "") + AXES[a]


#: A foot marker stands still while its speed is below this fraction of its 95th
#: percentile speed (the swing's): ≈ 0.2 m/s at ordinary walking speeds.
STILL_SPEED_FRACTION = 0.05
#: The floor axis must spread the still feet at most 1/this of the next axis.
FLOOR_AXIS_MARGIN = 1.5


def floor_axis(positions: ArrayLike, labels: list[str]) -> int | None:
    """Index of the vertical axis (0, 1, 2) as told by the feet, or None.

    Whenever a foot stands still it is on the floor: along the vertical axis the left
    and right foot markers of one kind (ankle, heel, toe) are then all at one level,
    while along the lateral axis they are a step width apart and along the walking
    direction spread over the walkway. So the vertical is the axis with the least spread
    of the still samples, pooled per kind over both feet. Unlike body shape or travel
    this holds for feet-only files and whatever the heading (a walk along an axis once
    made the lateral axis pass for the vertical one).

    Args:
        positions: ``(T, M, 3)`` marker positions.
        labels: The ``M`` marker labels.

    Returns:
        None without a left/right pair of one kind or with too few still samples.

    Raises:
        InputError: the spreads along two axes are too close to tell (give ``--up``).
    """
    P = np.asarray(positions, dtype=float)
    spreads = []
    for part in ("ankle", "heel", "toe"):
        pair = [find_marker(labels, side, part) for side in ("L", "R")]
        if pair[0] is None or pair[1] is None:
            continue
        X = P[:, [labels.index(pair[0]), labels.index(pair[1])]]  # (T, 2, 3)
        if len(X) < 5:
            continue
        v = np.linalg.norm(np.gradient(X, axis=0), axis=-1)  # per sample: rate-free
        fast = np.array([np.percentile(c[np.isfinite(c)], 95) if np.isfinite(c).any()
                         else np.nan for c in v.T])
        with np.errstate(invalid="ignore"):
            still = v < STILL_SPEED_FRACTION * fast  # NaN compares False
        if still.sum() < max(5, 0.1 * np.isfinite(v).sum()):
            continue
        S = X[still]  # (n, 3); a central difference can be finite beside a NaN sample
        S = S[np.isfinite(S).all(axis=1)]
        if len(S) < 5:
            continue
        spreads.append([float(np.std(S[:, k])) for k in range(3)])
    if not spreads:
        return None
    score = np.mean(spreads, axis=0)
    if not np.all(np.isfinite(score)):
        return None
    order = np.argsort(score)
    if score[order[1]] < FLOOR_AXIS_MARGIN * score[order[0]]:
        a, b = sorted((AXES[order[0]], AXES[order[1]]))
        why = (f"cannot tell the vertical axis from the foot markers ({a} or {b}: the feet "
               "stand at one level along both)")
        raise InputError(reason=why, advice="{up:give}", example=a)
    return int(order[0])


def _height_skew(h: NDArray[np.float64]) -> float:
    """Mean skewness over markers of ``(T, M)`` heights.

    A walking foot rests on the floor (its lowest height) for most of the time and
    rises only in short swings, so its height is skewed towards up: a negative skew
    along the chosen axis means the axis points down.
    """
    d = h - ns.nanmean(h, axis=0)
    sd = ns.nanstd(h, axis=0)
    ok = np.isfinite(sd) & (sd > 0)
    if not ok.any():
        return 0.0
    return float(np.mean(ns.nanmean(d[:, ok] ** 3, axis=0) / sd[ok] ** 3))


def up_rotation(up: str) -> NDArray[np.float64]:
    """3×3 rotation taking the ``up`` axis (e.g. ``"y"``, ``"-z"``) to +Z.

    Positive axes use a cyclic permutation (keeps handedness and the other axes'
    order); negative ones add a half-turn about the new X axis.

    Args:
        up: The vertical axis with sign: ``"x"``, ``"y"``, ``"z"``, ``"-y"`` ...

    Returns:
        ``R`` (3×3) with ``R @ p`` the point in the Z-up frame.

    Raises:
        InputError: ``up`` is not an axis.
    """
    u = up.strip().lower()
    neg = u.startswith("-")
    a = u.lstrip("+-")
    if a not in AXES:
        raise InputError(f"vertical axis must be one of x, y, z (optionally -x ...), got {up!r}")
    k = AXES.index(a)
    # row i of R picks old axis (k + 1 + i) mod 3 so that old axis k becomes new z.
    R = np.zeros((3, 3))
    for i in range(3):
        R[i, (k + 1 + i) % 3] = 1.0
    if neg:
        R = np.diag([1.0, -1.0, -1.0]) @ R
    return R


def to_z_up(positions: ArrayLike, up: str) -> NDArray[np.float64]:
    """Rotate ``(..., 3)`` points so that the ``up`` axis becomes +Z.

    Args:
        positions: ``(..., 3)`` points (any unit; time first when a series).
        up: The vertical axis with sign: ``"x"``, ``"y"``, ``"z"``, ``"-y"`` ...

    Returns:
        The rotated points, same shape (:func:`up_rotation` applied).

    Raises:
        InputError: ``up`` is not an axis.
    """
    return np.asarray(positions, dtype=float) @ up_rotation(up).T
