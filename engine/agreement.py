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
    single: dict[str, tuple[list[float], list[float]]] = {"L": ([], []), "R": ([], [])}
    av: dict[str, tuple[list[float], list[float]]] = {k: ([], []) for k in ("L", "R", "AVG")}
    for trs in trials.values():
        subj_m: dict[str, list[float]] = {"L": [], "R": []}
        subj_r: dict[str, list[float]] = {"L": [], "R": []}
        for meas, ref in trs:
            for m, r in match_steps(meas, ref, max_dt_s):
                single[m.side][0].append(float(getattr(m, attr)))
                single[m.side][1].append(float(getattr(r, attr)))
            # Subject averages use every step of each system (as the paper's AV rows).
            for s in meas:
                subj_m[s.side].append(float(getattr(s, attr)))
            for s in ref:
                subj_r[s.side].append(float(getattr(s, attr)))
        for side in ("L", "R"):
            if subj_m[side] and subj_r[side]:
                av[side][0].append(float(np.mean(subj_m[side])))
                av[side][1].append(float(np.mean(subj_r[side])))
        allm, allr = subj_m["L"] + subj_m["R"], subj_r["L"] + subj_r["R"]
        if allm and allr:
            av["AVG"][0].append(float(np.mean(allm)))
            av["AVG"][1].append(float(np.mean(allr)))
    out: dict[str, Agreement] = {}
    for key, (a, b) in [*single.items(), *((f"AV {k}", v) for k, v in av.items())]:
        if len(a) >= 3:
            out[key] = agreement(a, b)
    return out


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
