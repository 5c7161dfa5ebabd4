"""Agreement between a measurement method and a reference (seed paper 000, Tables 1–3).

Statistics: Pearson's r with its p-value; Bland–Altman bias (mean of measured −
reference), reproducibility coefficient RPC = 1.96·SD of the differences, CV = SD of
the differences in % of the mean measurement; ICC(A,1) — McGraw & Wong's intraclass
correlation for absolute agreement, single measures, two-way model (identical for the
random and mixed models), i.e. Shrout & Fleiss ICC(2,1) — and the Bland–Altman plot.

Levels (paper, "Quantitative comparison"): (1) single steps/strides per side, matched
in time; (2) subject averages per side; (3) subject averages pooled over both sides.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import stats

from engine.errors import InputError, InsufficientDataError
from engine.wording import count

FloatArray = NDArray[np.float64]


class _Timed(Protocol):
    # read-only, so that frozen dataclasses (engine.gait.Step) type-check as steps
    @property
    def side(self) -> str: ...

    @property
    def time_s(self) -> float: ...


@dataclass(frozen=True)
class Agreement:
    """Summary and agreement statistics of one parameter at one level (a table row)."""

    n: int
    mean_measured: float
    sd_measured: float
    mean_reference: float
    sd_reference: float
    r: float
    p: float
    bias: float
    rpc: float
    cv_pct: float
    icc_a1: float

    @property
    def limits_of_agreement(self) -> tuple[float, float]:
        """Bland–Altman 95 % limits: bias ± RPC."""
        return self.bias - self.rpc, self.bias + self.rpc

    def to_dict(self) -> dict[str, float | int]:
        """JSON-ready form.

        Returns:
            The fields as a flat dict (units as in the field names).
        """
        return asdict(self)


def _pair(measured: ArrayLike, reference: ArrayLike) -> tuple[FloatArray, FloatArray]:
    a = np.asarray(measured, dtype=float).ravel()
    b = np.asarray(reference, dtype=float).ravel()
    if a.shape != b.shape:
        raise InputError(f"measured ({a.size}) and reference ({b.size}) must pair up")
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 3:
        raise InsufficientDataError(f"agreement needs at least 3 paired values, got {ok.sum()}")
    return a[ok], b[ok]


def pearson(measured: ArrayLike, reference: ArrayLike) -> tuple[float, float]:
    """Pearson's r and its two-sided p-value (NaN when a variable is constant).

    Args:
        measured: ``(n,)`` values of the system under test.
        reference: ``(n,)`` paired reference values.

    Returns:
        ``(r, p)``.
    """
    a, b = _pair(measured, reference)
    if np.ptp(a) == 0 or np.ptp(b) == 0:
        return float("nan"), float("nan")
    res = stats.pearsonr(a, b)
    return float(res[0]), float(res[1])


def icc_a1(ratings: ArrayLike) -> float:
    """ICC(A,1) of an ``(n_targets, k_raters)`` matrix (McGraw & Wong 1996, case 2A/3A).

    ``(MSR − MSE) / (MSR + (k−1)·MSE + k·(MSC − MSE)/n)`` from the two-way ANOVA
    without replication.

    Args:
        ratings: ``(n_targets, k_raters)`` values; rows with NaN are left out.

    Returns:
        ICC(A,1) (NaN when the ANOVA's denominator is 0, e.g. all values equal).

    Raises:
        InputError: not a matrix with at least two raters.
        InsufficientDataError: fewer than two complete targets.
    """
    Y = np.asarray(ratings, dtype=float)
    if Y.ndim != 2 or Y.shape[1] < 2:
        raise InputError("ICC needs an (n_targets, k ≥ 2 raters) matrix")
    Y = Y[np.isfinite(Y).all(axis=1)]
    n, k = Y.shape
    if n < 2:
        raise InsufficientDataError(f"ICC needs at least 2 complete targets, got {n}")
    gm = Y.mean()
    rm = Y.mean(axis=1)
    cm = Y.mean(axis=0)
    msr = k * np.sum((rm - gm) ** 2) / (n - 1)
    msc = n * np.sum((cm - gm) ** 2) / (k - 1)
    sse = np.sum((Y - rm[:, None] - cm[None, :] + gm) ** 2)
    mse = sse / ((n - 1) * (k - 1))
    den = msr + (k - 1) * mse + k * (msc - mse) / n
    return float((msr - mse) / den) if den != 0 else float("nan")


def agreement(measured: ArrayLike, reference: ArrayLike) -> Agreement:
    """All statistics of one table row for paired values.

    Args:
        measured: ``(n,)`` values of the system under test (SI units).
        reference: ``(n,)`` paired reference values, same unit.

    Returns:
        n, both means and SDs, Pearson's r and p, bias, RPC, CV % and ICC(A,1)
        (:class:`Agreement`).
    """
    a, b = _pair(measured, reference)
    d = a - b
    sd_d = float(d.std(ddof=1))
    r, p = pearson(a, b)
    mean_all = float(np.mean((a + b) / 2))
    return Agreement(
        n=len(a), mean_measured=float(a.mean()), sd_measured=float(a.std(ddof=1)),
        mean_reference=float(b.mean()), sd_reference=float(b.std(ddof=1)), r=r, p=p,
        bias=float(d.mean()), rpc=1.96 * sd_d,
        cv_pct=100.0 * sd_d / abs(mean_all) if mean_all != 0 else float("nan"),
        icc_a1=icc_a1(np.column_stack([a, b])),
    )


def match_steps(measured: Sequence[_Timed], reference: Sequence[_Timed],
                max_dt_s: float = 0.25) -> list[tuple[Any, Any]]:
    """Pair measured with reference steps (or strides, events) of the same side.

    Pairs are formed greedily in order of increasing time difference, each step used at
    most once, never further apart than ``max_dt_s`` (less than half a step time, so a
    step can never pair with its neighbour).

    Args:
        measured: Steps, strides or events with ``side`` and ``time_s`` (s) attributes.
        reference: The reference system's, on the same time axis.
        max_dt_s: Largest time difference of a pair, s.

    Returns:
        ``(measured, reference)`` pairs sorted by reference time.
    """
    cand = []
    for i, m in enumerate(measured):
        for j, r in enumerate(reference):
            dt = abs(m.time_s - r.time_s)
            if m.side == r.side and dt <= max_dt_s:
                cand.append((dt, i, j))
    cand.sort()
    used_m: set[int] = set()
    used_r: set[int] = set()
    pairs = []
    for _, i, j in cand:
        if i in used_m or j in used_r:
            continue
        used_m.add(i)
        used_r.add(j)
        pairs.append((measured[i], reference[j]))
    pairs.sort(key=lambda p: p[1].time_s)
    return pairs


def match_events(measured: Sequence[Any], reference: Sequence[Any], max_dt_s: float = 0.1
                 ) -> list[tuple[Any, Any]]:
    """Pair measured with reference gait events of the same side and kind.

    For event timing against annotated events (e.g. Vicon Nexus foot strikes and foot
    offs carried in a C3D's ``EVENT`` group, :attr:`engine.mocap.FeetTrajectories.events`)
    on the same time axis: objects with ``side``, ``kind`` and ``time_s`` such as
    :class:`engine.gait.GaitEvent` and :class:`engine.io.markers.MarkerEvent`. Pairing is
    that of :func:`match_steps`, per kind (``"foot_strike"``, ``"foot_off"``,
    ``"placement"``); events of another kind or without a side are left out.

    Args:
        measured: detected events.
        reference: reference events.
        max_dt_s: the largest time difference paired (s); the default, 0.1 s, is well
            under the ≈ 0.6 s between a foot's strike and its off.

    Returns:
        ``(measured, reference)`` pairs sorted by reference time; the timing error of a
        pair is ``measured.time_s - reference.time_s``.
    """
    pairs: list[tuple[Any, Any]] = []
    for kind in sorted({str(e.kind) for e in measured}):
        m = [e for e in measured if e.kind == kind and e.side in ("L", "R")]
        r = [e for e in reference if e.kind == kind and e.side in ("L", "R")]
        pairs += match_steps(m, r, max_dt_s)
    pairs.sort(key=lambda p: p[1].time_s)
    return pairs


def _value(step: Any, attr: str) -> float:
    """A step's value as a float: NaN where it has none (None in gait JSON)."""
    v = getattr(step, attr)
    return float("nan") if v is None else float(v)


def agreement_levels(
    trials: Mapping[str, Sequence[tuple[Sequence[Any], Sequence[Any]]]],
    attr: str,
    max_dt_s: float = 0.25,
) -> dict[str, Agreement]:
    """The paper's three levels for one step/stride parameter.

    Args:
        trials: subject id → list of ``(measured_steps, reference_steps)`` per trial
            (objects with ``side``, ``time_s`` and the attribute ``attr``, e.g.
            :class:`engine.gait.Step`).
        attr: the parameter, e.g. ``"length_m"``, ``"width_m"``, ``"duration_s"``.
        max_dt_s: step matching tolerance (:func:`match_steps`).

    Returns:
        ``{"L", "R"}`` single matched steps per side; ``{"AV L", "AV R"}`` subject
        averages per side; ``"AV AVG"`` subject averages over both sides. Levels with
        too few values are omitted.
    """
    out: dict[str, Agreement] = {}
    for key, (a, b) in _level_values(trials, attr, max_dt_s).items():
        if len(a) >= 3:
            out[key] = agreement(a, b)
    return out


def _level_values(trials: Mapping[str, Sequence[tuple[Sequence[Any], Sequence[Any]]]],
                  attr: str, max_dt_s: float) -> dict[str, tuple[list[float], list[float]]]:
    """The paired values of :func:`agreement_levels`' levels (``"L"``, ``"R"``, ``"AV
    L"``, ``"AV R"``, ``"AV AVG"``: measured, reference), each trial's steps matched once."""
    single: dict[str, tuple[list[float], list[float]]] = {"L": ([], []), "R": ([], [])}
    av: dict[str, tuple[list[float], list[float]]] = {k: ([], []) for k in ("L", "R", "AVG")}
    for trs in trials.values():
        subj_m: dict[str, list[float]] = {"L": [], "R": []}
        subj_r: dict[str, list[float]] = {"L": [], "R": []}
        for meas, ref in trs:
            for m, r in match_steps(meas, ref, max_dt_s):
                a, b = _value(m, attr), _value(r, attr)
                if np.isfinite(a) and np.isfinite(b):  # a step without the value: no pair
                    single[m.side][0].append(a)
                    single[m.side][1].append(b)
            # Subject averages use every step of each system (as the paper's AV rows).
            for s in meas:
                subj_m[s.side].append(_value(s, attr))
            for s in ref:
                subj_r[s.side].append(_value(s, attr))
        # a step without the value (NaN, None in gait JSON) is left out of its average
        subj_m = {k: [v for v in vs if np.isfinite(v)] for k, vs in subj_m.items()}
        subj_r = {k: [v for v in vs if np.isfinite(v)] for k, vs in subj_r.items()}
        for side in ("L", "R"):
            if subj_m[side] and subj_r[side]:
                av[side][0].append(float(np.mean(subj_m[side])))
                av[side][1].append(float(np.mean(subj_r[side])))
        allm, allr = subj_m["L"] + subj_m["R"], subj_r["L"] + subj_r["R"]
        if allm and allr:
            av["AVG"][0].append(float(np.mean(allm)))
            av["AVG"][1].append(float(np.mean(allr)))
    return {**single, **{f"AV {k}": v for k, v in av.items()}}


def bland_altman_png(measured: ArrayLike, reference: ArrayLike, title: str = "",
                     unit: str = "", scale: float = 1.0, dpi: int = 100) -> bytes:
    """Bland–Altman plot (difference vs mean, bias and 95 % limits) as PNG bytes.

    Args:
        measured: measured values.
        reference: reference values, paired with ``measured``.
        title: plot title.
        unit: axis unit label (after ``scale``), e.g. ``"cm"``.
        scale: factor applied to values for display (e.g. 100 for m → cm).
        dpi: resolution.

    Returns:
        The figure as PNG bytes.
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    a, b = _pair(measured, reference)
    a, b = a * scale, b * scale
    ag = agreement(a, b)
    lo, hi = ag.limits_of_agreement
    fig = Figure(figsize=(5, 3.6), dpi=dpi)
    ax = fig.add_subplot(1, 1, 1)
    ax.scatter((a + b) / 2, a - b, s=12, alpha=0.7, color="tab:blue")
    ax.axhline(ag.bias, color="k", lw=1.2, label=f"bias {ag.bias:.2f}")
    for v in (lo, hi):
        ax.axhline(v, color="tab:red", lw=1, ls="--")
    ax.text(1.0, hi, f" +1.96 SD {hi:.2f}", transform=ax.get_yaxis_transform(),
            va="bottom", ha="right", fontsize=8)
    ax.text(1.0, lo, f" −1.96 SD {lo:.2f}", transform=ax.get_yaxis_transform(),
            va="top", ha="right", fontsize=8)
    u = f" ({unit})" if unit else ""
    ax.set_xlabel(f"mean of methods{u}")
    ax.set_ylabel(f"measured − reference{u}")
    ax.set_title(title or "Bland–Altman")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


@dataclass(frozen=True)
class StudyTrial:
    """One walk of a validation study: the system's and the reference's gait results of
    the same walk, on one time axis.

    Attributes:
        measured_steps: the system's steps (objects with ``side``, ``time_s``,
            ``length_m``, ``width_m``, ``duration_s``, e.g. :class:`engine.gait.Step`).
        reference_steps: the reference system's steps.
        measured_strides: the system's strides (``side``, ``time_s``, ``length_m``).
        reference_strides: the reference system's strides.
        measured_speed_m_s: the system's walking speed of the walk (m/s; NaN: none).
        reference_speed_m_s: the reference's walking speed of the walk (m/s; NaN: none).
        name: the walk's name in messages (a file or trial label).
    """

    measured_steps: Sequence[Any]
    reference_steps: Sequence[Any]
    measured_strides: Sequence[Any] = ()
    reference_strides: Sequence[Any] = ()
    measured_speed_m_s: float = float("nan")
    reference_speed_m_s: float = float("nan")
    name: str = ""


@dataclass(frozen=True)
class StudyRow:
    """One row of a validation study's tables (seed 000, Tables 1–3).

    Attributes:
        table: ``1`` for the view-independent parameters (walking speed, step time),
            ``2`` for the spatial ones (stride length, step length, step width).
        parameter: ``"walking speed"``, ``"step time"``, ``"stride length"``,
            ``"step length"`` or ``"step width"``.
        level: ``"L"``/``"R"`` (single steps or strides of one side, matched in time),
            ``"AV L"``/``"AV R"`` (subject averages of one side), ``"AV AVG"`` (subject
            averages over both sides) or ``"AV"`` (walking speed: subject averages).
        unit: the unit the paper's tables use: ``"cm/s"``, ``"s"`` or ``"cm"``.
        agreement: the row's statistics in SI units (m, s, m/s).
    """

    table: int
    parameter: str
    level: str
    unit: str
    agreement: Agreement

    @property
    def scale(self) -> float:
        """Factor from the SI statistics to :attr:`unit` (100 for cm and cm/s)."""
        return 1.0 if self.unit == "s" else 100.0

    @property
    def label(self) -> str:
        """The row's name as the paper writes it, e.g. ``"AV step width R (cm)"``."""
        if self.level == "AV":
            return f"AV {self.parameter} ({self.unit})"
        if self.level.startswith("AV"):
            return f"AV {self.parameter} {self.level[3:]} ({self.unit})"
        return f"{self.parameter[0].upper()}{self.parameter[1:]} {self.level} ({self.unit})"

    def shown(self) -> Agreement:
        """The statistics in :attr:`unit` (means, SDs, bias and RPC scaled; r, p, CV and
        ICC unchanged).

        Returns:
            A scaled copy of :attr:`agreement`.
        """
        a, k = self.agreement, self.scale
        return Agreement(a.n, a.mean_measured * k, a.sd_measured * k, a.mean_reference * k,
                         a.sd_reference * k, a.r, a.p, a.bias * k, a.rpc * k, a.cv_pct,
                         a.icc_a1)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form, in :attr:`unit`.

        Returns:
            ``{"table", "parameter", "level", "label", "unit", **statistics}``.
        """
        return {"table": self.table, "parameter": self.parameter, "level": self.level,
                "label": self.label, "unit": self.unit, **self.shown().to_dict()}


#: (parameter, attribute, steps or strides, table, unit), in the paper's order
_STUDY_PARAMETERS = (("step time", "duration_s", "steps", 1, "s"),
                     ("stride length", "length_m", "strides", 2, "cm"),
                     ("step length", "length_m", "steps", 2, "cm"),
                     ("step width", "width_m", "steps", 2, "cm"))

#: The columns of :meth:`AgreementStudy.csv`.
STUDY_CSV_COLUMNS = ("table", "parameter", "level", "unit", "n", "mean_measured",
                     "sd_measured", "mean_reference", "sd_reference", "r", "p", "bias",
                     "rpc", "cv_pct", "icc_a1")


class AgreementStudy:
    """A validation study against a reference system at the paper's three levels (seed
    000, "Quantitative comparison", Tables 1–3): single steps and strides per side
    matched in time, subject averages per side, subject averages over both sides; and
    the subjects' average walking speed.

    Subject averages use every step of each system (the paper's AV rows), single steps
    only those matched within ``max_dt_s`` (:func:`match_steps`). A row with fewer than
    three values (e.g. subject averages of a study with two subjects) is left out.

    Args:
        max_dt_s: step and stride matching tolerance, s.

    Attributes:
        rows_: the tables' rows (:class:`StudyRow`), in the paper's order.
        pairs_: parameter → ``(measured, reference)`` arrays of the matched single steps
            (or strides) of both sides, SI units: the Bland–Altman plots' points.
        n_subjects_: subjects with at least one trial.
        n_trials_: trials.
        unmatched_: name of each trial none of whose steps matched the reference in time
            (the two files do not start together, or are not the same walk).
    """

    def __init__(self, max_dt_s: float = 0.25) -> None:
        self.max_dt_s = max_dt_s

    def fit(self, trials: Mapping[str, Sequence[StudyTrial]]) -> AgreementStudy:
        """Compute the study's rows.

        Args:
            trials: subject code → that subject's trials.

        Returns:
            ``self``, with the ``*_`` attributes set.

        Raises:
            InputError: ``max_dt_s`` not positive.
            InsufficientDataError: no row can be computed (fewer than three matched
                steps in all, fewer than three subjects' walking speeds).
        """
        if not self.max_dt_s > 0:
            raise InputError(f"max_dt_s must be positive, got {self.max_dt_s}")
        subjects = {k: list(v) for k, v in trials.items() if len(v)}
        rows: list[StudyRow] = []
        pairs: dict[str, tuple[FloatArray, FloatArray]] = {}
        speeds: tuple[list[float], list[float]] = ([], [])
        for trs in subjects.values():
            m = [t.measured_speed_m_s for t in trs if np.isfinite(t.measured_speed_m_s)]
            r = [t.reference_speed_m_s for t in trs if np.isfinite(t.reference_speed_m_s)]
            if m and r:
                speeds[0].append(float(np.mean(m)))
                speeds[1].append(float(np.mean(r)))
        if len(speeds[0]) >= 3:
            rows.append(StudyRow(1, "walking speed", "AV", "cm/s", agreement(*speeds)))
        for parameter, attr, kind, table, unit in _STUDY_PARAMETERS:
            data = {k: [(getattr(t, f"measured_{kind}"), getattr(t, f"reference_{kind}"))
                        for t in trs] for k, trs in subjects.items()}
            values = _level_values(data, attr, self.max_dt_s)
            rows += [StudyRow(table, parameter, level, unit, agreement(*values[level]))
                     for level in ("L", "R", "AV L", "AV R", "AV AVG")
                     if len(values[level][0]) >= 3]
            # the Bland–Altman points: the matched single steps of both sides
            if values["L"][0] or values["R"][0]:
                pairs[parameter] = (np.array(values["L"][0] + values["R"][0]),
                                    np.array(values["L"][1] + values["R"][1]))
        if not rows:
            n = sum(len(t.measured_steps) for trs in subjects.values() for t in trs)
            raise InsufficientDataError(
                f"no agreement can be computed from {count(len(subjects), 'subject')} and "
                f"{count(sum(map(len, subjects.values())), 'trial')} ({n} measured steps): "
                "at least three steps must match the reference in time (within "
                f"{self.max_dt_s:g} s), or three subjects have a walking speed")
        self.rows_ = rows
        self.pairs_ = pairs
        self.n_subjects_ = len(subjects)
        self.n_trials_ = sum(len(v) for v in subjects.values())
        self.unmatched_ = [t.name for trs in subjects.values() for t in trs
                           if t.measured_steps and t.reference_steps
                           and not match_steps(t.measured_steps, t.reference_steps,
                                               self.max_dt_s)]
        return self

    def csv(self) -> str:
        """The rows as CSV (:data:`STUDY_CSV_COLUMNS`, values in each row's unit).

        Returns:
            CSV text with a header line.
        """
        import csv

        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(STUDY_CSV_COLUMNS)
        for row in self.rows_:
            d = row.to_dict()
            w.writerow([d[c] if isinstance(d[c], str | int) else f"{d[c]:.6g}"
                        for c in STUDY_CSV_COLUMNS])
        return buf.getvalue()
