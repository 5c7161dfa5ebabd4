"""Report figures rendered with matplotlib (Agg) to PNG bytes."""

from __future__ import annotations

import functools
import io
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, ParamSpec, TypeVar

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib import font_manager
from matplotlib.figure import Figure

SIDE_COLOURS = {"L": "#1f77b4", "R": "#d62728"}
SIDE_NAMES = {"L": "left", "R": "right"}
#: Gait events marked on the ankle trajectories (``events[].kind`` of the gait JSON).
EVENT_NAMES = {"foot_strike": "foot strike (dashed)", "placement": "foot placement (dashed)"}
#: Tried after DejaVu Sans for the glyphs it lacks (CJK trial names in the panel titles);
#: the same fallbacks as the report template's CSS (``fonts-wqy-microhei`` is installed
#: by ``scripts/bootstrap.sh`` and the Dockerfile).
FALLBACK_FAMILIES = ("WenQuanYi Micro Hei", "Noto Sans CJK JP", "Noto Sans CJK SC")
#: lower-case file-name parts (without "-") of those fonts
_FALLBACK_FILES = ("wqymicrohei", "notosanscjk")

P = ParamSpec("P")
R = TypeVar("R")


@functools.cache
def font_families() -> list[str]:
    """``DejaVu Sans`` followed by the installed fallback families, for ``font.family``.

    Returns:
        The family names.
    """
    names = {f.name for f in font_manager.fontManager.ttflist}
    if not any(f in names for f in FALLBACK_FAMILIES):
        # matplotlib caches its font list across runs: a font installed after the cache
        # was written (apt-get after the first plot) is missing from it until added here
        for path in font_manager.findSystemFonts():
            if any(k in Path(path).name.lower().replace("-", "") for k in _FALLBACK_FILES):
                try:
                    font_manager.fontManager.addfont(path)
                except (OSError, RuntimeError, ValueError):
                    continue  # an unreadable font file: no fallback from it
        names = {f.name for f in font_manager.fontManager.ttflist}
    return ["DejaVu Sans", *(f for f in FALLBACK_FAMILIES if f in names)]


def _fallback_fonts(plot: Callable[P, R]) -> Callable[P, R]:
    """Draw ``plot``'s figure with :func:`font_families` (matplotlib ≥ 3.6 falls back
    glyph by glyph through the list), without changing the caller's rcParams."""

    @functools.wraps(plot)
    def wrapped(*args: P.args, **kwargs: P.kwargs) -> R:
        with plt.rc_context({"font.family": font_families()}):
            return plot(*args, **kwargs)

    return wrapped


def figure_png(fig: Figure, dpi: int = 130) -> bytes:
    """Serialise a figure to PNG and close it.

    Args:
        fig: The matplotlib figure.
        dpi: Resolution, dots per inch.

    Returns:
        The PNG bytes.
    """
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


@_fallback_fonts
def plot_foot_placements(trials: Sequence[tuple[str, Sequence[dict[str, Any]]]]) -> bytes:
    """Foot placements seen from above, one row of markers per trial.

    Args:
        trials: ``(name, placements)`` with placements ``{"side", "position": [x, y, z]}``
            in metres, already expressed along (x) and across (y) the walking direction.

    Returns:
        The figure as PNG bytes.
    """
    n = max(len(trials), 1)
    # One scale for all panels: with each panel autoscaled, a 1.4 m trial was drawn as
    # long as a 3.5 m one. Equal aspect would flatten ±10 cm over metres to a line, so
    # the across axis stays in cm, stretched, and the caption says so.
    fig, axes = plt.subplots(n, 1, figsize=(7.5, 1.3 + 1.1 * n), squeeze=False,
                             sharex=True, sharey=True)
    for ax, (name, placements) in zip(axes[:, 0], trials, strict=False):
        for side in ("L", "R"):
            pts = np.array([p["position"][:2] for p in placements if p["side"] == side])
            if len(pts):
                ax.scatter(pts[:, 0], pts[:, 1] * 100.0, s=28, marker="s",
                           color=SIDE_COLOURS[side], label=SIDE_NAMES[side])
        ax.set_ylabel("across (cm)")
        ax.tick_params(labelbottom=True)
        ax.set_title(name, fontsize=9, loc="left")
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("along the walkway (m)")
    axes[0, 0].legend(loc="lower left", bbox_to_anchor=(0.0, 1.15), fontsize=8, ncol=2,
                      frameon=False)
    fig.tight_layout()
    return figure_png(fig)


@_fallback_fonts
def plot_ankle_heights(
    times: np.ndarray, heights: dict[str, np.ndarray], events: Sequence[dict[str, Any]] = ()
) -> bytes:
    """Vertical ankle trajectories over time with gait events marked.

    Args:
        times: ``(T,)`` s.
        heights: Side (``"L"``/``"R"``) -> ``(T,)`` ankle height, m.
        events: Gait JSON events (``side``, ``kind``, ``time_s``).

    Returns:
        The figure as PNG bytes.
    """
    fig, ax = plt.subplots(figsize=(7.5, 2.6))
    for side, h in heights.items():
        ax.plot(times, np.asarray(h) * 100.0, color=SIDE_COLOURS.get(side, "k"), lw=1.2,
                label=f"{SIDE_NAMES.get(side, side)} ankle")
    # Heel-strike analyses give foot strikes, the crossing method foot placements; the
    # latter were not drawn, and neither kind was named in the legend.
    marked = [ev for ev in events if ev.get("kind") in EVENT_NAMES]
    for ev in marked:
        ax.axvline(ev["time_s"], color=SIDE_COLOURS.get(ev.get("side", ""), "k"), lw=0.6,
                   ls="--", alpha=0.6)
    for kind in dict.fromkeys(ev["kind"] for ev in marked):
        ax.plot([], [], color="#666", lw=0.8, ls="--", label=EVENT_NAMES[kind])
    ax.set_xlabel("time (s)")
    ax.set_ylabel("height (cm)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    return figure_png(fig)


@_fallback_fonts
def plot_steps(steps: Sequence[dict[str, Any]],
               trial_sizes: Sequence[int] | None = None) -> bytes:
    """Step length, width and time per step, left and right.

    Args:
        steps: gait JSON steps of all trials, trial after trial.
        trial_sizes: steps per trial (summing to ``len(steps)``); the line of each side
            breaks between trials, so that two walks are not drawn as one.

    Returns:
        The figure as PNG bytes.
    """
    sizes = list(trial_sizes) if trial_sizes else [len(steps)]
    trial_of = np.repeat(np.arange(len(sizes)), sizes)
    fig, axes = plt.subplots(1, 3, figsize=(7.5, 2.4))
    specs = (("length_m", "step length (cm)", 100.0), ("width_m", "step width (cm)", 100.0),
             ("duration_s", "step time (s)", 1.0))
    for ax, (key, label, scale) in zip(axes, specs, strict=True):
        for side in ("L", "R"):
            vals: list[float] = []
            prev = None
            for s, k in zip(steps, trial_of, strict=True):
                if s["side"] != side or s.get(key) is None:
                    continue
                if prev is not None and k != prev:
                    vals.append(np.nan)  # break the line between trials
                vals.append(s[key] * scale)
                prev = k
            x = np.cumsum(np.isfinite(vals)).astype(float)
            x[~np.isfinite(vals)] = np.nan
            ax.plot(x, vals, "o-", ms=3, lw=0.8, color=SIDE_COLOURS[side],
                    label=SIDE_NAMES[side])
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("step # per side" + (", trial after trial" if len(sizes) > 1 else ""),
                      fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    return figure_png(fig)


@_fallback_fonts
def plot_bland_altman(measured: np.ndarray, reference: np.ndarray, title: str,
                      unit: str) -> bytes:
    """Bland–Altman plot: difference vs mean with bias and ±1.96·SD limits.

    Args:
        measured: ``(n,)`` values of the system under test (displayed unit).
        reference: ``(n,)`` paired reference values.
        title: Figure title.
        unit: Axis unit.

    Returns:
        The figure as PNG bytes.
    """
    m = np.asarray(measured, dtype=float)
    r = np.asarray(reference, dtype=float)
    ok = np.isfinite(m) & np.isfinite(r)
    m, r = m[ok], r[ok]
    mean = (m + r) / 2.0
    diff = m - r
    bias = float(np.mean(diff)) if len(diff) else float("nan")
    sd = float(np.std(diff, ddof=1)) if len(diff) > 1 else float("nan")
    fig, ax = plt.subplots(figsize=(3.6, 2.8))
    ax.scatter(mean, diff, s=10, alpha=0.7, color="#444")
    ax.axhline(bias, color="#d62728", lw=1, label=f"bias {bias:+.2f}")
    if np.isfinite(sd):
        for k in (-1.96, 1.96):
            ax.axhline(bias + k * sd, color="#1f77b4", lw=0.8, ls="--")
    ax.set_xlabel(f"mean ({unit})", fontsize=8)
    ax.set_ylabel(f"difference ({unit})", fontsize=8)
    ax.set_title(title, fontsize=9)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return figure_png(fig)


#: Session names written under a trend plot at most (more overprint each other).
MAX_TREND_LABELS = 6


def trend_label_indices(n: int, most: int = MAX_TREND_LABELS) -> list[int]:
    """Indices of the sessions whose names label a trend plot's axis: all of ``n`` up to
    ``most``, else ``most`` evenly spaced ones including the first and the last.

    Args:
        n: Number of sessions.
        most: Most labels.

    Returns:
        Increasing session indices.
    """
    if n <= most:
        return list(range(n))
    return sorted(set(np.rint(np.linspace(0, n - 1, most)).astype(int).tolist()))


@_fallback_fonts
def plot_trends(panels: Sequence[dict[str, Any]], x_labels: Sequence[str],
                dates: Sequence[Any] | None = None) -> bytes:
    """Parameters against session date: mean ± SD per session, normative band shaded.

    Args:
        panels: one per parameter, ``{"title", "unit", "mean": (S,), "sd": (S,),
            "band": (low, high) or None}`` in display units (NaN where a session has no
            value or no SD).
        x_labels: the sessions' names, first to last (only
            :func:`trend_label_indices` of them are written under the axis).
        dates: the sessions' dates (``datetime.date``) to space them in time; None (or
            any missing) puts them at equal steps.

    Returns:
        The figure as PNG bytes.
    """
    n = max(len(panels), 1)
    cols = min(n, 3)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(7.5, 2.1 * rows + 0.4), squeeze=False)
    if dates is not None and all(d is not None for d in dates) and len(set(dates)) == len(dates):
        x: Any = list(dates)
    else:
        x = list(range(len(x_labels)))
    shown = trend_label_indices(len(x_labels))
    for ax, panel in zip(axes.ravel(), panels, strict=False):
        mean = np.asarray(panel["mean"], dtype=float)
        sd = np.asarray(panel["sd"], dtype=float)
        band = panel.get("band")
        if band is not None:
            ax.axhspan(band[0], band[1], color="#2ca02c", alpha=0.15, lw=0,
                       label="normative band")
        ax.errorbar(x, mean, yerr=np.where(np.isfinite(sd), sd, 0.0), fmt="o-", ms=4,
                    lw=1.0, capsize=3, color="#333")
        ax.set_title(f"{panel['title']} ({panel['unit']})", fontsize=8.5)
        # Every session is a point; past MAX_TREND_LABELS the names would overprint,
        # so only evenly spaced ones (always the first and the last) are written.
        ax.set_xticks([x[k] for k in shown])
        ax.set_xticklabels([x_labels[k] for k in shown], fontsize=6.5,
                           rotation=30 if len(shown) <= 4 else 60, ha="right",
                           rotation_mode="anchor" if len(shown) > 4 else "default")
        ax.tick_params(axis="y", labelsize=7)
        ax.grid(alpha=0.3)
        if band is not None:
            ax.legend(fontsize=6, loc="best", frameon=False)
    for ax in axes.ravel()[len(panels):]:
        ax.set_visible(False)
    fig.tight_layout()
    return figure_png(fig)


# ---------------------------------------------------------------- text alternatives
# What each figure shows, in words computed from the data it is drawn from: the report's
# <img alt> in the HTML and the /Alt of the figure in the tagged PDF (a screen reader
# reads it in place of the picture). A generic "plot of step length" tells nothing.


def _range_text(vals: Sequence[float] | np.ndarray, unit: str, decimals: int) -> str:
    v = np.asarray(vals, dtype=float)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return "no values"
    lo, hi = float(v.min()), float(v.max())
    if f"{lo:.{decimals}f}" == f"{hi:.{decimals}f}":
        return f"{lo:.{decimals}f} {unit}"
    return f"{lo:.{decimals}f} to {hi:.{decimals}f} {unit}"


def foot_placements_alt(trials: Sequence[tuple[str, Sequence[dict[str, Any]]]]) -> str:
    """Text alternative of :func:`plot_foot_placements` for the same ``trials``: per trial
    its left and right placements and the distance they span along the walkway.

    Args:
        trials: ``(name, steps)`` per trial (gait JSON steps).

    Returns:
        The text.
    """
    parts = []
    for name, placements in trials:
        n = {s: sum(1 for p in placements if p.get("side") == s) for s in ("L", "R")}
        xs = [float(p["position"][0]) for p in placements]
        along = max(xs) - min(xs) if xs else 0.0
        parts.append(f"{name}: {n['L']} left and {n['R']} right placements along "
                     f"{along:.1f} m")
    head = "Foot placements seen from above"
    if len(parts) > 1:
        head += f", {len(parts)} trials, one panel each"
    return f"{head}. " + "; ".join(parts) + "."


def ankle_heights_alt(name: str, times: np.ndarray, heights: dict[str, np.ndarray],
                      events: Sequence[dict[str, Any]] = ()) -> str:
    """Text alternative of :func:`plot_ankle_heights`: duration, each ankle's height range
    and the events marked.

    Args:
        name: The trial's name.
        times: ``(T,)`` s.
        heights: Side -> ``(T,)`` ankle height, m.
        events: Gait JSON events.

    Returns:
        The text.
    """
    t = np.asarray(times, dtype=float)
    t = t[np.isfinite(t)]
    dur = float(t.max() - t.min()) if len(t) else 0.0
    sides = [f"{SIDE_NAMES.get(s, s)} ankle {_range_text(np.asarray(h) * 100.0, 'cm', 0)}"
             for s, h in heights.items()]
    marked = [ev for ev in events if ev.get("kind") in EVENT_NAMES]
    text = (f"Ankle height over time in trial {name}, {dur:.1f} s: "
            + ", ".join(sides) + " above the floor")
    if marked:
        kinds = {ev["kind"] for ev in marked}
        what = " and ".join(EVENT_NAMES[k].split(" (")[0] + "s" for k in sorted(kinds))
        text += f"; {len(marked)} {what} marked"
    return text + "."


def steps_alt(steps: Sequence[dict[str, Any]]) -> str:
    """Text alternative of :func:`plot_steps`: per side the steps and the range of step
    length, width and time.

    Args:
        steps: Gait JSON steps.

    Returns:
        The text.
    """
    parts = []
    for side in ("L", "R"):
        mine = [s for s in steps if s.get("side") == side]
        if not mine:
            continue

        def vals(key: str, scale: float, of: list[dict[str, Any]] = mine) -> list[float]:
            return [s[key] * scale for s in of if s.get(key) is not None]

        parts.append(f"{len(mine)} {SIDE_NAMES[side]} steps, length "
                     f"{_range_text(vals('length_m', 100.0), 'cm', 0)}, width "
                     f"{_range_text(vals('width_m', 100.0), 'cm', 0)}, time "
                     f"{_range_text(vals('duration_s', 1.0), 's', 2)}")
    return ("Step length, width and time of every step, left and right: "
            + ("; ".join(parts) if parts else "no steps") + ".")


def bland_altman_alt(caption: str, n: int, bias: float, rpc: float, unit: str) -> str:
    """Text alternative of a Bland–Altman figure from its agreement figures.

    Args:
        caption: The figure's caption.
        n: Number of pairs.
        bias: Mean difference (displayed unit).
        rpc: Reproducibility coefficient (1.96·SD, displayed unit).
        unit: The unit.

    Returns:
        The text.
    """
    return (f"{caption}: differences of {n} paired values against their means; bias "
            f"{bias:+.2f} {unit}, 95 % limits of agreement bias ± {rpc:.2f} {unit}.")


def trends_alt(panels: Sequence[dict[str, Any]], x_labels: Sequence[str]) -> str:
    """Text alternative of :func:`plot_trends`: the sessions, and per parameter its first
    and last value and whether the last is inside the normative band.

    Args:
        panels: The trend plot's panels (``title``, ``unit``, per-session ``mean``, ``decimals``,
            the normative ``band``).
        x_labels: Session names.

    Returns:
        The text.
    """
    parts = []
    for p in panels:
        mean = np.asarray(p["mean"], dtype=float)
        ok = np.flatnonzero(np.isfinite(mean))
        if len(ok) == 0:
            continue
        first, last = float(mean[ok[0]]), float(mean[ok[-1]])
        d = int(p.get("decimals", 2))
        text = f"{p['title']} {first:.{d}f} to {last:.{d}f} {p['unit']}"
        band = p.get("band")
        if band is not None:
            text += (" (inside the normative band)" if band[0] <= last <= band[1]
                     else " (outside the normative band)")
        parts.append(text)
    span = (f"{x_labels[0]} to {x_labels[-1]}" if len(x_labels) > 1
            else (x_labels[0] if x_labels else ""))
    return (f"Parameters over {len(x_labels)} sessions, {span}, first to last: "
            + "; ".join(parts) + ".")
