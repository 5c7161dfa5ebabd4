"""Change of a subject's gait over sessions ("did my patient change?").

Pure functions over the per-trial gait results of a subject's sessions: per session the
key parameters as mean ± SD (defined as in the report's spatiotemporal table, see
:func:`engine.report.render.spatiotemporal_table`), the change of each later session
against the FIRST and the PREVIOUS one (absolute and %), and whether a change is beyond
measurement noise, judged two ways:

(a) beyond this subject's own trial-to-trial variability: Welch's t-test (unequal
    variances) on the two sessions' per-trial values, p < :data:`ALPHA`; it needs at least
    two trials in each session, otherwise "too few trials to tell". Trials of one session
    vary less than sessions on different days do, so (a) alone flags changes too readily
    over weeks; it answers "is this more than the spread of today's walks?".
(b) beyond a published minimal detectable change, MDC95 = 1.96 · √2 · SEM
    (:func:`mdc95_from_sem`), where a test–retest source for the parameter is given
    (:class:`~engine.report.normative.MdcValue`); "no published MDC" otherwise. The
    defaults (:data:`~engine.report.normative.DEFAULT_MDC_VALUES`) hold only what we
    could check against its paper (authors, year, journal, population and figure):
    comfortable walking speed, 0.18 m/s, measured in people with parkinsonism; the
    report prints that population beside the figure. A lab loads its own with
    :func:`load_mdc_values` (JSON, SI units).

A change is described by its direction only — faster/slower, longer/shorter,
wider/narrower — never as an improvement: whether faster is better depends on the
patient.

Units: every number here is SI (m, s, steps/min, % of the gait cycle, %) except
:attr:`ProgressParameter.scale`, which converts to the display unit; sessions are in
time order (first = earliest), as the caller gives them.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from engine.errors import InputError
from engine.report.normative import (
    DEFAULT_MDC_VALUES,
    DEFAULT_NORMATIVE_RANGES,
    MdcValue,
    NormativeRange,
    normative_lookup,
)
from engine.report.render import TableRow, TrialData, day_text, spatiotemporal_table

#: Significance level of the trial-to-trial test (a).
ALPHA = 0.05
#: Trials per session the t-test needs (a variance from one trial does not exist).
MIN_TRIALS_FOR_TEST = 2
TOO_FEW_TRIALS = "too few trials to tell"
NO_PUBLISHED_MDC = "no published MDC"


@dataclass(frozen=True)
class ProgressParameter:
    """A parameter followed over sessions.

    Attributes:
        key: SI key (``walking_speed_m_s``, ``step_length_L_m``, ...).
        label: name printed in the report.
        table_label: label of its row in the spatiotemporal table.
        side: "L", "R" or "" (both sides).
        unit: display unit.
        scale: SI → display unit.
        decimals: decimals shown.
        more: word for an increase ("faster", "longer", "wider", ...).
        less: word for a decrease.
        asymmetry: the value is the table row's asymmetry (not its mean).
        norm_key: key of its normative band (:mod:`engine.report.normative`), or "".
        relative: a change is also given in % of the earlier value (not for a value that
            is itself a %, whose change is in percentage points).
    """

    key: str
    label: str
    table_label: str
    side: str
    unit: str
    scale: float
    decimals: int
    more: str
    less: str
    asymmetry: bool = False
    norm_key: str = ""
    relative: bool = True


PROGRESS_PARAMETERS: tuple[ProgressParameter, ...] = (
    ProgressParameter("walking_speed_m_s", "Walking speed", "Walking speed", "", "m/s", 1.0,
                      2, "faster", "slower", norm_key="walking_speed_m_s"),
    ProgressParameter("cadence_steps_min", "Cadence", "Cadence", "", "steps/min", 1.0, 1,
                      "higher", "lower", norm_key="cadence_steps_min"),
    ProgressParameter("step_length_L_m", "Step length, left", "Step length", "L", "cm",
                      100.0, 1, "longer", "shorter", norm_key="step_length_m"),
    ProgressParameter("step_length_R_m", "Step length, right", "Step length", "R", "cm",
                      100.0, 1, "longer", "shorter", norm_key="step_length_m"),
    ProgressParameter("stride_length_m", "Stride length", "Stride length", "", "cm", 100.0,
                      1, "longer", "shorter", norm_key="stride_length_m"),
    ProgressParameter("step_width_m", "Step width", "Step width", "", "cm", 100.0, 1,
                      "wider", "narrower", norm_key="step_width_m"),
    ProgressParameter("step_time_s", "Step time", "Step time", "", "s", 1.0, 3, "longer",
                      "shorter", norm_key="step_time_s"),
    ProgressParameter("double_support_pct", "Double support", "Double support", "",
                      "% cycle", 1.0, 1, "longer", "shorter", norm_key="double_support_pct"),
    ProgressParameter("step_length_asymmetry_pct", "Step-length asymmetry", "Step length", "",
                      "% points", 1.0, 1, "more asymmetric", "less asymmetric",
                      asymmetry=True, relative=False),
)


def mdc95_from_sem(sem: float) -> float:
    """MDC95 = 1.96 · √2 · SEM.

    The smallest change between two measurements that exceeds their measurement error with
    95 % confidence (SEM from a test–retest study).

    Args:
        sem: Standard error of measurement, in the parameter's unit.

    Returns:
        The MDC95, same unit.
    """
    return 1.96 * math.sqrt(2.0) * float(sem)


def load_mdc_values(path: str | Path) -> list[MdcValue]:
    """Read a JSON list of MDC values (fields as in :class:`MdcValue`, SI units).

    Args:
        path: A JSON file (as :func:`save_mdc_values` writes).

    Returns:
        The values, in file order.

    Raises:
        InputError: the file is not a list of complete values for known parameters.
    """
    try:
        raw = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read MDC values from {path}: {exc}") from exc
    if not isinstance(raw, list):
        raise InputError("an MDC file must hold a JSON list of objects")
    known = {p.key for p in PROGRESS_PARAMETERS}
    out: list[MdcValue] = []
    for i, item in enumerate(raw):
        try:
            v = MdcValue(str(item["parameter"]), float(item["mdc"]),
                         str(item.get("population", "")), str(item["source"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"MDC value #{i + 1} is incomplete or invalid: {exc}") from exc
        if v.parameter not in known:
            raise InputError(f"MDC value #{i + 1}: unknown parameter {v.parameter!r}; use one "
                             f"of {', '.join(sorted(known))}")
        if not (math.isfinite(v.mdc) and v.mdc > 0) or not v.source.strip():
            raise InputError(f"MDC value #{i + 1} ({v.parameter}): needs mdc > 0 and a source")
        out.append(v)
    return out


def save_mdc_values(values: Sequence[MdcValue], path: str | Path) -> None:
    """Write MDC values as JSON (the format :func:`load_mdc_values` reads).

    Args:
        values: The values (SI units).
        path: Destination file (overwritten).
    """
    Path(path).write_text(json.dumps([asdict(v) for v in values], indent=2), encoding="utf-8")


@dataclass
class SessionTrials:
    """The trials of one session.

    Attributes:
        label: the session's label.
        date: ISO date (``YYYY-MM-DD``) or "".
        trials: its analysed walks.
        session_id: the database id, when there is one.
    """

    label: str
    date: str
    trials: list[TrialData]
    session_id: int | None = None

    @property
    def name(self) -> str:
        """Date and label as printed ("20 Nov 2026 baseline", :func:`day_text`)."""
        return " ".join(x for x in (day_text(self.date), self.label) if x) or "session"


@dataclass(frozen=True)
class WelchResult:
    """Welch's unequal-variances t-test of ``b`` against ``a`` (t > 0: b larger)."""

    t: float
    df: float
    p: float


def welch_t_test(a: Sequence[float] | np.ndarray,
                 b: Sequence[float] | np.ndarray) -> WelchResult | None:
    """Welch's t-test (two-sided) of the mean of ``b`` against the mean of ``a``.

    Same t, Welch–Satterthwaite df and p as ``scipy.stats.ttest_ind(b, a,
    equal_var=False)``; non-finite values are dropped. With no spread in either group
    (identical trials) p is 0 if the means differ and 1 if not (scipy gives NaN).

    Args:
        a: Values of the earlier session's trials.
        b: Values of the later session's trials.

    Returns:
        The test, or None when either group has fewer than :data:`MIN_TRIALS_FOR_TEST`
        values.
    """
    xa = np.asarray(a, dtype=float)
    xb = np.asarray(b, dtype=float)
    xa, xb = xa[np.isfinite(xa)], xb[np.isfinite(xb)]
    if len(xa) < MIN_TRIALS_FOR_TEST or len(xb) < MIN_TRIALS_FOR_TEST:
        return None
    va = float(np.var(xa, ddof=1)) / len(xa)
    vb = float(np.var(xb, ddof=1)) / len(xb)
    diff = float(np.mean(xb) - np.mean(xa))
    se2 = va + vb
    if se2 <= 0.0:
        return WelchResult(math.copysign(math.inf, diff) if diff else 0.0,
                           float(len(xa) + len(xb) - 2), 0.0 if diff else 1.0)
    t = diff / math.sqrt(se2)
    df = se2 ** 2 / (va ** 2 / (len(xa) - 1) + vb ** 2 / (len(xb) - 1))
    from scipy import stats  # here: the server imports this module at start

    p = float(2.0 * stats.t.sf(abs(t), df))
    return WelchResult(t, df, p)


@dataclass(frozen=True)
class SessionValue:
    """One parameter in one session (SI units).

    Attributes:
        n: values behind the mean (steps, strides or trials, as in the report's table).
        mean: session value (speed and cadence pooled over all steps).
        sd: SD as in the report's table (between steps, or between trials); NaN for one.
        trial_values: the parameter of each trial alone (for the t-test).
    """

    n: int
    mean: float
    sd: float
    trial_values: tuple[float, ...]


@dataclass(frozen=True)
class Change:
    """Change of one parameter from session ``ref`` to session ``to`` (SI units).

    Attributes:
        parameter: the parameter.
        ref: index of the session compared against (0 = first).
        to: index of the later session.
        delta: value at ``to`` − value at ``ref``.
        pct: 100 · delta / |value at ref| (NaN when that is 0, or for a percentage).
        welch: the trial-to-trial test, or None (too few trials).
        mdc: the published MDC95 used, or None.
    """

    parameter: ProgressParameter
    ref: int
    to: int
    delta: float
    pct: float
    welch: WelchResult | None
    mdc: MdcValue | None

    @property
    def direction(self) -> str:
        """The parameter's word for the change ("faster", "narrower", ...) or "unchanged"."""
        if not math.isfinite(self.delta) or self.delta == 0.0:
            return "unchanged"
        return self.parameter.more if self.delta > 0 else self.parameter.less

    @property
    def beyond_trial_noise(self) -> bool | None:
        """(a) Welch p < :data:`ALPHA`; None when a session has too few trials."""
        return None if self.welch is None else self.welch.p < ALPHA

    @property
    def beyond_mdc(self) -> bool | None:
        """(b) |delta| > MDC95; None without a published MDC."""
        return None if self.mdc is None else abs(self.delta) > self.mdc.mdc

    @property
    def beyond_noise(self) -> bool:
        """Beyond noise by every test that could be made (and at least one could)."""
        verdicts = [v for v in (self.beyond_trial_noise, self.beyond_mdc) if v is not None]
        return bool(verdicts) and all(verdicts)

    def describe(self) -> str:
        """e.g. "faster by 0.19 m/s (+15.2 %)".

        Returns:
            The change in words, in the parameter's display unit.
        """
        p = self.parameter
        amount = f"{abs(self.delta) * p.scale:.{p.decimals}f} {p.unit}"
        pct = f" ({self.pct:+.1f} %)" if math.isfinite(self.pct) else ""
        if self.direction == "unchanged":
            return "unchanged" + pct
        return f"{self.direction} by {amount}{pct}"

    def trial_verdict(self) -> str:
        """Verdict (a) in words, with the p-value.

        Returns:
            Whether the trials differ (Welch's test), or why it was not tested.
        """
        if self.welch is None:
            return TOO_FEW_TRIALS
        p = "p < 0.001" if self.welch.p < 0.001 else f"p = {self.welch.p:.3f}"
        if self.welch.p < ALPHA:
            return f"beyond trial-to-trial variability ({p})"
        return f"within trial-to-trial variability ({p})"

    def mdc_verdict(self) -> str:
        """Verdict (b) in words, with the MDC95.

        Returns:
            Whether the change exceeds the published MDC95, or that none is published.
        """
        if self.mdc is None:
            return NO_PUBLISHED_MDC
        p = self.parameter
        m = f"{self.mdc.mdc * p.scale:.{p.decimals}f} {p.unit}"
        return f"exceeds MDC95 {m}" if self.beyond_mdc else f"below MDC95 {m}"


@dataclass
class Progress:
    """Sessions, their values and the changes between them.

    Attributes:
        sessions: the sessions, in time order.
        parameters: parameters with a value in at least one session.
        values: ``values[key][i]``: the parameter in session ``i`` (None without data).
        vs_first: changes of every later session against the first.
        vs_previous: changes against the session before (from the third session on;
            for the second session it is the same as ``vs_first``).
        normative: normative band per parameter key (SI), when there is one.
        mdc_sources: the MDC sources cited, in order.
    """

    sessions: list[SessionTrials]
    parameters: list[ProgressParameter]
    values: dict[str, list[SessionValue | None]]
    vs_first: list[Change] = field(default_factory=list)
    vs_previous: list[Change] = field(default_factory=list)
    normative: dict[str, NormativeRange] = field(default_factory=dict)
    mdc_sources: list[MdcValue] = field(default_factory=list)

    def change(self, key: str, to: int, ref: int = 0) -> Change | None:
        """The change of parameter ``key`` from session ``ref`` to session ``to``.

        Args:
            key: Parameter key (e.g. ``"walking_speed_m_s"``).
            to: Index of the later session.
            ref: Index of the earlier session (0: the first; ``to - 1``: the previous).

        Returns:
            The change, or None when it was not computed (no data, or a pair other than
            against the first or the previous session).
        """
        for c in (*self.vs_first, *self.vs_previous):
            if c.parameter.key == key and c.to == to and c.ref == ref:
                return c
        return None


def _row_value(rows: list[TableRow], p: ProgressParameter) -> tuple[int, float, float]:
    for r in rows:
        if r.label != p.table_label:
            continue
        if p.asymmetry:
            if r.side == "" and r.asymmetry_pct is not None and math.isfinite(r.asymmetry_pct):
                return 1, float(r.asymmetry_pct), math.nan
        elif r.side == p.side:
            # the table is in display units
            return r.n, r.mean / p.scale, r.sd / p.scale
    return 0, math.nan, math.nan


def session_value(trials: Sequence[TrialData], p: ProgressParameter) -> SessionValue | None:
    """A parameter of one session, as the report's table defines it, and per trial.

    Args:
        trials: The session's analysed trials.
        p: The parameter.

    Returns:
        The session's value and each trial's value alone; None when no trial has it.
    """
    n, mean, sd = _row_value(spatiotemporal_table(list(trials), ()), p)
    if n == 0 or not math.isfinite(mean):
        return None
    per_trial: list[float] = []
    for t in trials:
        nt, mt, _ = _row_value(spatiotemporal_table([t], ()), p)
        if nt and math.isfinite(mt):
            per_trial.append(mt)
    if p.asymmetry:  # one value per session: its spread is between the trials' values
        n = len(per_trial)
        sd = float(np.std(per_trial, ddof=1)) if n > 1 else math.nan
    return SessionValue(n, mean, sd, tuple(per_trial))


def _change(p: ProgressParameter, ref: int, to: int, a: SessionValue, b: SessionValue,
            mdc: MdcValue | None) -> Change:
    delta = b.mean - a.mean
    pct = 100.0 * delta / abs(a.mean) if a.mean and p.relative else math.nan
    return Change(p, ref, to, delta, pct, welch_t_test(a.trial_values, b.trial_values), mdc)


def session_progress(
    sessions: Sequence[SessionTrials],
    normative: Sequence[NormativeRange] = DEFAULT_NORMATIVE_RANGES,
    mdc_values: Sequence[MdcValue] = DEFAULT_MDC_VALUES,
    parameters: Sequence[ProgressParameter] = PROGRESS_PARAMETERS,
) -> Progress:
    """Per-session values and the changes between sessions.

    Args:
        sessions: the subject's sessions in time order (first = baseline).
        normative: bands drawn in the trend plots.
        mdc_values: published MDC95 values (b); a parameter without one gets
            "no published MDC".
        parameters: what to follow.

    Returns:
        Per parameter its value in each session and the changes against the first and
        the previous session (difference, %, Welch's test of the trials, the MDC95
        used).

    Raises:
        InputError: fewer than two sessions, or a session without trials.
    """
    sess = list(sessions)
    if len(sess) < 2:
        raise InputError(f"change over sessions needs at least two sessions, got {len(sess)}")
    for s in sess:
        if not s.trials:
            raise InputError(f"session {s.name} has no analysed trial")
    mdcs = {m.parameter: m for m in mdc_values}
    norms = normative_lookup(tuple(normative))
    values: dict[str, list[SessionValue | None]] = {}
    used: list[ProgressParameter] = []
    for p in parameters:
        vals = [session_value(s.trials, p) for s in sess]
        if any(v is not None for v in vals):
            values[p.key] = vals
            used.append(p)
    out = Progress(sess, used, values,
                   normative={p.key: norms[p.norm_key] for p in used if p.norm_key in norms})
    for i in range(1, len(sess)):
        for p in used:
            a, b, prev = values[p.key][0], values[p.key][i], values[p.key][i - 1]
            if a is not None and b is not None:
                out.vs_first.append(_change(p, 0, i, a, b, mdcs.get(p.key)))
            if i >= 2 and prev is not None and b is not None:
                out.vs_previous.append(_change(p, i - 1, i, prev, b, mdcs.get(p.key)))
    for c in (*out.vs_first, *out.vs_previous):
        if c.mdc is not None and c.mdc not in out.mdc_sources:
            out.mdc_sources.append(c.mdc)
    return out
