"""Per-subject gait report: one Jinja2 template rendered to HTML (console) and PDF.

The report is built from the gait engine's JSON result (schema in
``docs/gait-json.md``: ``events``, ``steps``, ``strides``, ``summary``) of one or more
trials, plus optional trajectories, data-quality facts and agreement statistics. All
numbers in the tables are computed here from the per-step lists, so a report never
depends on which summary keys an older result happens to carry.
"""

from __future__ import annotations

import base64
import datetime as _dt
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from engine import __version__
from engine.errors import InputError, InsufficientDataError
from engine.report.normative import (
    DEFAULT_MDC_VALUES,
    DEFAULT_NORMATIVE_RANGES,
    MdcValue,
    NormativeRange,
    normative_lookup,
)

if TYPE_CHECKING:
    from jinja2 import Environment

    from engine.report.progress import Change, Progress, ProgressParameter, SessionTrials

_MONTHS = ("Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec")


def day_text(iso: str) -> str:
    """A calendar day ("2026-11-28") as the report prints it: "28 Nov 2026".

    The report (HTML and PDF from one template) has no reader's locale, unlike the console
    (``gaitrig.day()`` writes the browser's own order): the month in letters and the
    four-digit year cannot be read the wrong way round (03/04: March or April?), in any
    country. English month names, whatever the server's locale.

    Args:
        iso: the day as ISO 8601 text (a date-time's first ten characters are used).

    Returns:
        "28 Nov 2026"; text that is not an ISO date is returned as it is.
    """
    try:
        d = _dt.date.fromisoformat(iso.strip()[:10]) if iso else None
    except ValueError:
        d = None
    return f"{d.day} {_MONTHS[d.month - 1]} {d.year}" if d else iso


TEMPLATE_DIR = Path(__file__).with_name("templates")
#: Trials per foot-placement figure (one panel each): six fit on an A4 page.
PLACEMENT_TRIALS_PER_FIGURE = 6
#: Below this many steps a trial is flagged as a short or interrupted walk.
FEW_STEPS_PER_TRIAL = 4
#: Steps per side below which means and CVs are flagged as uncertain.
MIN_STEPS_PER_SIDE = 10
#: Paired values below which r, p and ICC of an agreement row are flagged as unreliable.
MIN_AGREEMENT_PAIRS = 10
#: Expected timing uncertainty (ms, 95 % of events) of heel-strike events on a fused
#: depth-camera skeleton at 30 Hz, from the sensors, fusion and sampling: bench
#: gait_events.py, six-sensor skeletons against the same method on the true joints at
#: 100 Hz, |error| 95th percentile 11 ms for foot strikes, 13–17 ms for foot offs.
EVENT_TIMING_P95_MS_30HZ = 17.0
#: The method's own accuracy against force plates (Zeni et al., Gait Posture 2008,
#: 27:710): 98 % of overground events within two frames at 60 Hz.
EVENT_METHOD_P98_MS = 33.0
#: Below this rate (Hz) a frame (≥ 20 ms) is ≥ 2 % of a gait cycle: stance, swing and
#: double support, differences of two events in % of the cycle, are marked less certain.
PHASE_MIN_RATE_HZ = 50.0


@dataclass(frozen=True)
class Parameter:
    """A reported parameter: where its per-item values come from and how to show them."""

    key: str
    label: str
    source: str  # "steps", "strides", "summary" or "pooled" (speed, cadence)
    field: str
    unit: str  # display unit
    scale: float  # SI → display
    decimals: int
    sided: bool


PARAMETERS: tuple[Parameter, ...] = (
    # "pooled": over every step of every trial (see pace()), not a mean of trial values
    Parameter("walking_speed_m_s", "Walking speed", "pooled", "walking_speed_m_s", "m/s",
              1.0, 2, False),
    Parameter("cadence_steps_min", "Cadence", "pooled", "cadence_steps_min", "steps/min",
              1.0, 1, False),
    Parameter("step_length_m", "Step length", "steps", "length_m", "cm", 100.0, 1, True),
    Parameter("stride_length_m", "Stride length", "strides", "length_m", "cm", 100.0, 1, True),
    Parameter("step_width_m", "Step width", "steps", "width_m", "cm", 100.0, 1, True),
    Parameter("step_time_s", "Step time", "steps", "duration_s", "s", 1.0, 3, True),
    Parameter("stride_time_s", "Stride time", "strides", "duration_s", "s", 1.0, 3, True),
    Parameter("stance_pct", "Stance", "summary", "stance_pct", "% cycle", 1.0, 1, True),
    Parameter("swing_pct", "Swing", "summary", "swing_pct", "% cycle", 1.0, 1, True),
    Parameter("double_support_pct", "Double support", "summary", "double_support_pct",
              "% cycle", 1.0, 1, False),
)


@dataclass
class TrialData:
    """One analysed walk.

    Attributes:
        name: label shown in the report (e.g. recording id and pass).
        result: gait JSON object (``events``, ``steps``, ``strides``, ``summary``).
        placements: optional foot placements ``{"side", "time_s", "position": [x, y, z]}``
            with x along and y across the walking direction (m), for the top view.
        times: optional ``(T,)`` times of the ankle trajectories.
        ankle_heights: optional ``{"L": (T,), "R": (T,)}`` vertical ankle positions (m).
        source: the recording id (or file) the trial came from, when ``name`` is the
            clinician's label for it; listed beside the name in "Trials used".
    """

    name: str
    result: dict[str, Any]
    placements: list[dict[str, Any]] | None = None
    times: np.ndarray | None = None
    ankle_heights: dict[str, np.ndarray] | None = None
    source: str = ""


@dataclass
class QualityInfo:
    """Facts about the recording that tell how far the numbers can be trusted."""

    sensors_used: list[str] = field(default_factory=list)
    joints_tracked_pct: float | None = None
    gaps_filled: int | None = None
    clock_offsets_ms: dict[str, float] = field(default_factory=dict)
    #: lowest and highest offset per sensor when the report spans several recordings
    clock_offset_range_ms: dict[str, tuple[float, float]] = field(default_factory=dict)
    clock_uncertainty_ms: dict[str, float] = field(default_factory=dict)
    calibration_residuals_mm: dict[str, float] = field(default_factory=dict)
    calibration_version: str | None = None
    notes: list[str] = field(default_factory=list)
    recordings: int = 1  # how many recordings the facts summarise


@dataclass
class AgreementRow:
    """Agreement of one parameter with a reference system (units as displayed)."""

    parameter: str
    level: str
    n: int
    r: float
    p: float
    bias: float
    rpc: float
    cv_pct: float
    icc_a1: float
    unit: str = ""


@dataclass
class ReportData:
    """Everything one report shows."""

    subject_code: str
    trials: list[TrialData]
    title: str = "Gait report"
    subject_info: dict[str, Any] = field(default_factory=dict)
    session_label: str = ""
    session_date: str = ""
    quality: QualityInfo = field(default_factory=QualityInfo)
    agreement: list[AgreementRow] = field(default_factory=list)
    agreement_figures: list[tuple[str, bytes]] = field(default_factory=list)
    agreement_basis: str = ""  # which recordings and reference the agreement rests on
    normative: tuple[NormativeRange, ...] | list[NormativeRange] = DEFAULT_NORMATIVE_RANGES
    clinician_notes: str = ""
    #: the subject's sessions, when the report spans several: two or more add the
    #: section "Change over sessions" (:mod:`engine.report.progress`)
    sessions: list[SessionTrials] = field(default_factory=list)
    #: published MDC95 values for that section
    mdc: tuple[MdcValue, ...] | list[MdcValue] = DEFAULT_MDC_VALUES


@dataclass
class TableRow:
    """One row of the report's spatiotemporal table (values in the displayed unit).

    Attributes:
        label: Parameter name as shown.
        unit: Displayed unit (cm, s, steps/min, %).
        side: ``"L"``, ``"R"`` or ``""`` (both sides pooled).
        n: Number of values.
        mean: Mean.
        sd: Standard deviation.
        cv_pct: Coefficient of variation, %.
        decimals: Decimals shown.
        asymmetry_pct: Left/right asymmetry, % (None where not computed).
        normative: The normative range compared with, if any.
        normative_display: The range as shown.
        normative_ref: Number of its source in the table's footnote.
        flag: ``""``, ``"below"`` or ``"above"`` the normative range.
    """

    label: str
    unit: str
    side: str  # "L", "R" or "" (both)
    n: int
    mean: float
    sd: float
    cv_pct: float
    decimals: int
    asymmetry_pct: float | None = None
    normative: NormativeRange | None = None
    normative_display: str = ""
    normative_ref: int | None = None  # number of the source in the table's footnote
    flag: str = ""  # "", "below", "above"


def _collect(param: Parameter, trials: list[TrialData], side: str | None) -> np.ndarray:
    vals: list[float] = []
    for tr in trials:
        res = tr.result
        if param.source == "summary":
            summ = res.get("summary", {}) or {}
            v = summ.get(param.field)
            if isinstance(v, dict):
                # Gait JSON phases: {"mean", "left_mean", "right_mean"} (docs/gait-json.md).
                v = v.get({None: "mean", "L": "left_mean", "R": "right_mean"}[side])
            elif side is not None:
                v = summ.get(f"{param.field}_{side}")
            if isinstance(v, int | float):
                vals.append(float(v))
        else:
            for item in res.get(param.source, []) or []:
                if side is not None and item.get("side") != side:
                    continue
                v = item.get(param.field)
                if v is not None:
                    vals.append(float(v))
    arr = np.asarray(vals, dtype=float)
    return arr[np.isfinite(arr)]


@dataclass(frozen=True)
class Pace:
    """Walking speed and cadence of some steps, pooled over them (gait JSON definition).

    Attributes:
        n_steps: steps with a step time.
        time_s: Σ step times, s.
        length_m: Σ step lengths of the steps that have a length and a time, m.
        speed_m_s: Σ step lengths / Σ step times (of the steps with both), or NaN.
        cadence_steps_min: 60 · steps / Σ step times, or NaN.
    """

    n_steps: int
    time_s: float
    length_m: float
    speed_m_s: float
    cadence_steps_min: float


def _finite(v: Any) -> bool:
    return isinstance(v, int | float) and math.isfinite(v)


def pace(trials: list[TrialData]) -> Pace:
    """Walking speed and cadence pooled over all steps of ``trials``.

    The session's speed is Σ step lengths / Σ step times over every step of every trial
    (the per-trial definition of the gait JSON's ``walking_speed_m_s``, extended to the
    session) and cadence 60 · steps / Σ step times: a long walk weighs by its steps, a
    two-step trial does not count as much as a 20-step one, as a mean of the trials'
    values would have it.

    Args:
        trials: Analysed trials.

    Returns:
        Speed (m/s), cadence (steps/min), Σ step times (s), Σ lengths (m) and the steps.
    """
    steps = [s for t in trials for s in t.result.get("steps", []) or []
             if _finite(s.get("duration_s")) and s["duration_s"] > 0]
    t_all = float(sum(s["duration_s"] for s in steps))
    both = [s for s in steps if _finite(s.get("length_m"))]
    t_len = float(sum(s["duration_s"] for s in both))
    length = float(sum(s["length_m"] for s in both))
    return Pace(len(steps), t_all, length, length / t_len if t_len > 0 else math.nan,
                60.0 * len(steps) / t_all if t_all > 0 else math.nan)


_PACE_ATTRS = {"walking_speed_m_s": "speed_m_s", "cadence_steps_min": "cadence_steps_min"}


def _pooled(param: Parameter, trials: list[TrialData]) -> tuple[int, float, float, float]:
    """N (trials with a value), the pooled value, and SD/CV between the trials' values.

    A trial whose steps carry no times keeps its summary value for the per-trial spread,
    but adds nothing to the pooled value; with no step times at all the pooled value is
    the mean of the trials' summary values.
    """
    attr = _PACE_ATTRS[param.key]
    per_trial = []
    for t in trials:
        v = getattr(pace([t]), attr)
        if not math.isfinite(v):
            v = (t.result.get("summary", {}) or {}).get(param.field)
        if _finite(v):
            per_trial.append(float(v))
    n, mean, sd, _ = _stats(np.asarray(per_trial, dtype=float))
    pooled = getattr(pace(trials), attr)
    if math.isfinite(pooled):
        mean = pooled
    cv = 100.0 * sd / abs(mean) if n > 1 and mean else math.nan
    return n, mean, sd, cv


def trial_paces(trials: list[TrialData]) -> list[tuple[str, Pace]]:
    """``(name, pace)`` of each trial, for the report's per-trial table.

    Args:
        trials: Analysed trials.

    Returns:
        ``(trial name, its Pace)`` in trial order.
    """
    return [(t.name, pace([t])) for t in trials]


def _stats(vals: np.ndarray) -> tuple[int, float, float, float]:
    n = len(vals)
    if n == 0:
        return 0, math.nan, math.nan, math.nan
    mean = float(np.mean(vals))
    sd = float(np.std(vals, ddof=1)) if n > 1 else math.nan
    cv = 100.0 * sd / abs(mean) if n > 1 and mean != 0 else math.nan
    return n, mean, sd, cv


def spatiotemporal_table(
    trials: list[TrialData],
    normative: tuple[NormativeRange, ...] | list[NormativeRange] = DEFAULT_NORMATIVE_RANGES,
) -> list[TableRow]:
    """Mean ± SD, CV, left/right and asymmetry of every parameter with data.

    Walking speed and cadence are pooled over all steps of all trials (:func:`pace`), with
    N = trials and SD/CV between the trials' own values; the other parameters are means
    over steps, strides or (stance, swing, double support) trials.

    Asymmetry is the symmetry index ``100·|L − R| / ((L + R) / 2)`` (Robinson et al.,
    J Manipulative Physiol Ther 1987), 0 % = perfectly symmetric.

    Args:
        trials: Analysed trials.
        normative: Ranges to compare with.

    Returns:
        The table's rows (displayed units).
    """
    norms = normative_lookup(normative)
    rows: list[TableRow] = []
    for p in PARAMETERS:
        norm = norms.get(p.key)
        sides: list[str | None] = [None, "L", "R"] if p.sided else [None]
        per_side: dict[str, TableRow] = {}
        for side in sides:
            if p.source == "pooled":
                n, mean, sd, cv = _pooled(p, trials)
            else:
                vals = _collect(p, trials, side)
                if side is None and len(vals) == 0 and p.sided:
                    vals = np.concatenate([_collect(p, trials, "L"), _collect(p, trials, "R")])
                n, mean, sd, cv = _stats(vals)
            if n == 0:
                continue
            row = TableRow(p.label, p.unit, side or "", n, mean * p.scale, sd * p.scale, cv,
                           p.decimals, normative=norm if side is None else None)
            if norm is not None and side is None:
                lo, hi = norm.low * p.scale, norm.high * p.scale
                row.normative_display = f"{lo:.{p.decimals}f}–{hi:.{p.decimals}f}"
                row.flag = "below" if row.mean < lo else "above" if row.mean > hi else ""
            rows.append(row)
            if side:
                per_side[side] = row
        if "L" in per_side and "R" in per_side:
            lm, rm = per_side["L"].mean, per_side["R"].mean
            denom = (lm + rm) / 2.0
            asym = 100.0 * abs(lm - rm) / abs(denom) if denom else math.nan
            for r in rows:
                if r.label == p.label and r.side == "":
                    r.asymmetry_pct = asym
    return rows


def quality_notes(data: ReportData, table: list[TableRow]) -> list[str]:
    """Plain-language warnings about data quality, derived from the facts given.

    Args:
        data: The report's data (quality facts, trials).
        table: Its spatiotemporal table.

    Returns:
        The warnings, one sentence each (empty when there is nothing to say).
    """
    q = data.quality
    notes = list(q.notes)
    for t in data.trials:
        n = len(t.result.get("steps", []) or [])
        if n == 0:
            notes.append(f"Trial {t.name}: no usable steps were found; it adds nothing to "
                         "the step and stride rows.")
        elif n < FEW_STEPS_PER_TRIAL:
            notes.append(f"Trial {t.name}: only {n} step{'s' if n > 1 else ''} "
                         "(a short or interrupted walk); check that it was a full pass.")
    per_side = {side: sum(1 for t in data.trials for s in t.result.get("steps", []) or []
                          if s.get("side") == side) for side in ("L", "R")}
    if min(per_side.values()) < MIN_STEPS_PER_SIDE:
        notes.append(f"Only {per_side['L']} left and {per_side['R']} right steps were "
                     "analysed: means are uncertain and variability (CV) is not reliable "
                     f"below about {MIN_STEPS_PER_SIDE} steps per side.")
    if q.joints_tracked_pct is not None and q.joints_tracked_pct < 80.0:
        # The share is over every frame of the recording, including those before the
        # subject walks in and while they turn out of view: not only occlusions.
        notes.append(f"Lower-body joints were tracked in only {q.joints_tracked_pct:.0f} % "
                     "of the recording's frames: the subject was out of the sensors' view "
                     "for part of the recording (before the start, turning at the ends) or "
                     "joints were occluded; gaps show in the ankle trajectories.")
    for node, off in q.clock_uncertainty_ms.items():
        if off > 2.0:
            notes.append(f"Sensor {node}: clock uncertainty {off:.1f} ms exceeds 2 ms; "
                         "step times may be less accurate.")
    for node, res in q.calibration_residuals_mm.items():
        if res > 10.0:
            notes.append(f"Sensor {node}: calibration residual {res:.1f} mm is high; "
                         "recalibrate before relying on step width.")
    if len(q.sensors_used) == 1:
        notes.append("Recorded from one sensor only (one-sided): step width and length of "
                     "the far leg are biased; use sensors on both sides of the walkway.")
    notes += _event_notes(data)
    return notes


def _event_notes(data: ReportData) -> list[str]:
    """The event method and its expected timing uncertainty (documented constants)."""
    summ = [t.result.get("summary", {}) or {} for t in data.trials]
    if not any(s.get("method") == "heelstrike" for s in summ):
        return []
    rates = [float(r) for s in summ if isinstance(r := s.get("frame_rate_hz"), int | float)]
    low = min(rates) if rates else None
    text = ("Gait events: foot strike and foot off by Zeni et al. (2008), the foot's "
            "farthest point ahead of and behind the pelvis; against force plates the "
            f"method is within {EVENT_METHOD_P98_MS:.0f} ms for 98 % of events.")
    if low is not None and low < PHASE_MIN_RATE_HZ:
        text += (f" At {low:.0f} Hz the sensors and sampling add about "
                 f"±{EVENT_TIMING_P95_MS_30HZ:.0f} ms (95 %, simulated six-sensor "
                 "recordings at 30 Hz). One frame is "
                 f"{1000.0 / low:.0f} ms, about {100.0 / (1.1 * low):.0f} % of a typical "
                 "1.1 s gait cycle: "
                 "double support, stance and swing are less certain than the other rows "
                 "and small differences in them should not be read as change.")
    return [text]


def _png_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def build_context(data: ReportData) -> dict[str, Any]:
    """Template context: tables, figures (as data URIs) and notes.

    Args:
        data: Everything the report shows.

    Returns:
        The Jinja2 template's variables.

    Raises:
        InsufficientDataError: no analysed trial.
        InputError: a trial whose result is not a gait JSON object.
    """
    # matplotlib where figures are drawn: the server imports this module at start
    from engine.report import plots

    if not data.trials:
        raise InsufficientDataError("a report needs at least one analysed trial")
    for t in data.trials:
        if not isinstance(t.result, dict) or "steps" not in t.result:
            raise InputError(f"trial {t.name!r}: result is not a gait JSON object with 'steps'")
    table = spatiotemporal_table(data.trials, data.normative)
    figures: list[tuple[str, str, str]] = []  # (caption, text alternative, data URI)
    placements = [(t.name, t.placements) for t in data.trials if t.placements]
    # One panel per trial: a single figure of 10+ trials is taller than an A4 page and
    # the PDF cut off its last trials, so the panels go into figures of a page each.
    for k in range(0, len(placements), PLACEMENT_TRIALS_PER_FIGURE):
        chunk = placements[k:k + PLACEMENT_TRIALS_PER_FIGURE]
        caption = ("Foot placements seen from above (along the walkway in m, across it in cm: "
                   "the across axis is stretched so that step width can be read)")
        if len(placements) > PLACEMENT_TRIALS_PER_FIGURE:
            caption += (f", trials {k + 1}–{k + len(chunk)} of {len(placements)}"
                        if len(chunk) > 1 else f", trial {k + 1} of {len(placements)}")
        figures.append((caption, plots.foot_placements_alt(chunk),
                        _png_uri(plots.plot_foot_placements(chunk))))
    for t in data.trials:
        if t.times is not None and t.ankle_heights:
            events = t.result.get("events", []) or []
            figures.append((f"Ankle trajectories — {t.name}",
                            plots.ankle_heights_alt(t.name, t.times, t.ankle_heights, events),
                            _png_uri(plots.plot_ankle_heights(t.times, t.ankle_heights,
                                                              events))))
            break  # one example trial keeps the report short
    all_steps = [s for t in data.trials for s in t.result.get("steps", []) or []]
    if all_steps:
        sizes = [len(t.result.get("steps", []) or []) for t in data.trials]
        figures.append(("Parameters per step (lines break between trials)" if len(sizes) > 1
                        else "Parameters per step", plots.steps_alt(all_steps),
                        _png_uri(plots.plot_steps(all_steps, sizes))))
    # Sources numbered in the order the table cites them; each band shows its number.
    used_norms: list[str] = []
    populations: dict[str, list[str]] = {}
    for r in table:
        if r.normative is None:
            continue
        src = r.normative.source
        if src not in used_norms:
            used_norms.append(src)
        pops = populations.setdefault(src, [])
        if r.normative.population and r.normative.population not in pops:
            pops.append(r.normative.population)
        r.normative_ref = used_norms.index(src) + 1
    return {
        "data": data,
        "table": table,
        "figures": figures,
        "agreement_figures": [(c, _agreement_alt(c, data.agreement), _png_uri(p))
                              for c, p in data.agreement_figures],
        "agreement_few": any(a.n < MIN_AGREEMENT_PAIRS for a in data.agreement),
        "min_pairs": MIN_AGREEMENT_PAIRS,
        "notes": quality_notes(data, table),
        "norm_sources": [(s, "; ".join(populations.get(s, []))) for s in used_norms],
        "n_steps": len(all_steps),
        "trial_steps": [(t.name, t.source, len(t.result.get("steps", []) or []))
                        for t in data.trials],
        "trial_paces": trial_paces(data.trials),
        "session_pace": pace(data.trials),
        **_progress_context(data),
        # the day as the report writes days ("28 Nov 2026", progress.day_text); UTC said:
        # the server has no reader's time zone
        "generated": (lambda t: f"{day_text(t.date().isoformat())} {t:%H:%M} UTC")(
            _dt.datetime.now(_dt.UTC)),
        "version": __version__,
    }


def _agreement_alt(caption: str, rows: list[AgreementRow]) -> str:
    """Text alternative of an agreement figure: its row of the agreement table (the one
    whose parameter the caption names, both sides when it says so), else the caption."""
    from engine.report import plots

    cap = caption.lower()
    subject = cap.split(":", 1)[-1].split("(")[0].strip()  # "Bland–Altman: step length"
    named = ([r for r in rows if r.parameter.lower() in cap]
             or [r for r in rows if subject and subject in r.parameter.lower()])
    if "both sides" in cap:
        named = [r for r in named if "L+R" in r.level] or named
    if not named:
        return f"{caption}: Bland–Altman plot, differences against means."
    r = named[0]
    return plots.bland_altman_alt(caption, r.n, r.bias, r.rpc, r.unit)


def latest_changes(prog: Progress) -> list[tuple[ProgressParameter, list[Change]]]:
    """Per parameter, the latest session against the first and against the previous one
    (the previous only from three sessions on: with two it is the first).

    A report over many sessions listed every session against the first and the previous,
    ~20 rows a session; what a clinician asks is where the subject is now against the
    baseline and the last visit. The whole series stays in the sessions table and the
    trend plots.

    Args:
        prog: The session progress.

    Returns:
        Per followed parameter its latest changes (against the first, then the previous).
    """
    last = len(prog.sessions) - 1
    out = []
    for p in prog.parameters:
        changes = [c for ref in dict.fromkeys((0, last - 1))
                   if (c := prog.change(p.key, last, ref)) is not None]
        out.append((p, changes))
    return out


def _progress_context(data: ReportData) -> dict[str, Any]:
    """The "Change over sessions" section: the progress and its trend figure (nothing for
    a report of one session)."""
    if len(data.sessions) < 2:
        return {"progress": None, "progress_figure": None}
    from engine.report import plots
    from engine.report.progress import session_progress

    prog: Progress = session_progress(data.sessions, data.normative, data.mdc)
    panels = []
    for p in prog.parameters:
        vals = prog.values[p.key]
        band = prog.normative.get(p.key)
        panels.append({
            "title": p.label, "unit": p.unit,
            "mean": [v.mean * p.scale if v else math.nan for v in vals],
            "sd": [v.sd * p.scale if v else math.nan for v in vals],
            "band": (band.low * p.scale, band.high * p.scale) if band else None,
            "decimals": p.decimals})
    dates: list[_dt.date | None] = []
    for s in prog.sessions:
        try:
            dates.append(_dt.date.fromisoformat(s.date))
        except ValueError:
            dates.append(None)
    names = [s.name for s in prog.sessions]
    png = plots.plot_trends(panels, names, dates)
    steps = [sum(len(t.result.get("steps", []) or []) for t in s.trials) for s in prog.sessions]
    return {"progress": prog, "progress_figure": _png_uri(png), "progress_steps": steps,
            "progress_alt": plots.trends_alt(panels, names),
            "progress_latest": latest_changes(prog),
            "progress_labelled": len(plots.trend_label_indices(len(names))) < len(names)}


def _env() -> Environment:
    from jinja2 import Environment, FileSystemLoader, select_autoescape

    env = Environment(loader=FileSystemLoader(TEMPLATE_DIR),
                      autoescape=select_autoescape(["html", "j2"]))

    def fmt(v: float | None, d: int = 2) -> str:
        if v is None or (isinstance(v, float) and not math.isfinite(v)):
            return "–"
        text = f"{v:.{d}f}"
        # a value that rounds to zero has no sign ("-0.000" read as a negative bias)
        return text[1:] if text.startswith("-") and float(text) == 0 else text

    env.filters["fmt"] = fmt
    env.filters["day"] = day_text
    return env


def render_html(data: ReportData, *, standalone: bool = True) -> str:
    """The report as HTML.

    Args:
        data: Everything the report shows.
        standalone: A whole page (``<html>``/``<head>``); False: a fragment for the console.

    Returns:
        The HTML text.
    """
    ctx = build_context(data)
    ctx["standalone"] = standalone
    return _env().get_template("report.html.j2").render(**ctx)


def render_pdf(data: ReportData) -> bytes:
    """The same report as a tagged PDF/UA-1 document (A4, via WeasyPrint).

    Args:
        data: Everything the report shows.

    Returns:
        The PDF bytes.

    Raises:
        RuntimeError: WeasyPrint produced an empty document.
    """
    from weasyprint import HTML  # heavy import, only when a PDF is asked for
    from weasyprint.urls import URLFetcher

    # PDF/UA-1: a tagged PDF (structure tree in reading order, headings, tables with
    # their header cells, figures with their alt text), with its language and title, so
    # that a screen reader can read the downloaded report as well as the console's.
    # The report embeds its plots as data: URIs; nothing else is fetched, so no text that
    # reached the page could make the server read a local file or call an address.
    fetcher = URLFetcher(allowed_protocols={"data"})
    pdf = HTML(string=render_html(data, standalone=True), url_fetcher=fetcher).write_pdf(
        pdf_variant="pdf/ua-1")
    if not pdf:
        raise RuntimeError("WeasyPrint produced an empty PDF")
    return bytes(pdf)


def save_report(data: ReportData, path: str | Path) -> Path:
    """Write the report to ``path`` (.html or .pdf, chosen by suffix).

    Args:
        data: Everything the report shows.
        path: Destination ``.html`` or ``.pdf`` (overwritten).

    Returns:
        ``path`` as a Path.

    Raises:
        InputError: another suffix.
    """
    path = Path(path)
    if path.suffix.lower() == ".pdf":
        path.write_bytes(render_pdf(data))
    elif path.suffix.lower() in (".html", ".htm"):
        path.write_text(render_html(data), encoding="utf-8")
    else:
        raise InputError(f"report path must end in .html or .pdf, got {path.name!r}")
    return path
