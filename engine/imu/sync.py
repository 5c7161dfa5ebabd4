"""Synchronisation of IMU streams and the depth skeleton by vertical jumps (seed 002 §3.1).

The subject performs a few (the paper: five) vertical jumps; every landing produces a large
acceleration spike on every body-worn IMU at the same instant, and a sharp upward
acceleration of the depth skeleton's torso. Between IMUs, spike times are detected per
stream, matched in order, and each stream's clock offset is the median difference to the
reference stream. The depth skeleton is too noisy for single spikes (with 1.5-2 cm joint
noise its twice-differentiated torso height has spurious peaks as high as the landings),
so against it the IMU's whole jump series is used as a template: the torso height
(several torso joints averaged) is differentiated twice by a Savitzky-Golay filter and
cross-correlated with the IMU's smoothed vertical acceleration (coarse offset), then the
waveforms are matched finely; the skeleton's landing times are finally searched only
near the aligned IMU landings. The per-jump residuals show how well the streams agree
after alignment.

Offsets are *added* to a stream's own time stamps to express them on the reference clock.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.signal import correlate, find_peaks, savgol_filter

from engine import nanstats
from engine.errors import InputError, InsufficientDataError
from engine.imu.io import ImuRecording
from engine.skeleton import SkeletonSeries
from engine.wording import count

FloatArray = NDArray[np.float64]
G = 9.80665


@dataclass
class SyncResult:
    """Outcome of :func:`synchronize`.

    Attributes:
        reference: name of the stream whose clock the others are aligned to.
        offsets: stream name -> seconds to add to its time stamps.
        spike_times: stream name -> ``(n_jumps,)`` detected landing times (own clock).
        residuals: stream name -> ``(n_jumps,)`` seconds left after alignment, per jump.
        warnings: problems worth showing to the operator.
    """

    reference: str
    offsets: dict[str, float]
    spike_times: dict[str, FloatArray]
    residuals: dict[str, FloatArray]
    warnings: list[str] = field(default_factory=list)

    def max_residual(self) -> float:
        """Largest absolute per-jump residual over all streams.

        Returns:
            The residual, s (0 without streams).
        """
        return float(max((np.max(np.abs(r)) for r in self.residuals.values()), default=0.0))


def _refine_peak(y: FloatArray, i: int) -> float:
    """Sub-sample peak position by a parabola through the three samples around ``i``."""
    if 0 < i < len(y) - 1:
        a, b, c = y[i - 1], y[i], y[i + 1]
        den = a - 2.0 * b + c
        if den < 0:
            return i + 0.5 * (a - c) / den
    return float(i)


def detect_spikes(
    times: ArrayLike,
    signal: ArrayLike,
    n_jumps: int = 5,
    min_interval: float = 0.4,
    max_span: float | None = None,
    min_height: float | None = None,
) -> FloatArray:
    """Times of the ``n_jumps`` landing spikes in an acceleration-like signal.

    Among all peaks at least ``min_interval`` apart, the ``n_jumps`` highest peaks within a
    time span of at most ``max_span`` are chosen, the span with the largest summed height
    winning (jumps come in one series; take-off pushes are lower than landing impacts, and
    isolated impacts elsewhere in the recording are ignored).

    Args:
        times: ``(T,)`` s, increasing.
        signal: ``(T,)`` e.g. acceleration norm (IMU) or torso vertical acceleration.
        n_jumps: number of jumps performed.
        min_interval: minimum time between two landings, s.
        max_span: longest allowed duration of the jump series, s (default ``2.5 s`` per
            jump).
        min_height: peaks below this are ignored (default: the signal's median plus half
            its range).

    Returns:
        ``(n_jumps,)`` spike times, s, increasing (sub-sample precision).

    Raises:
        InsufficientDataError: fewer than ``n_jumps`` spikes found.
    """
    t = np.asarray(times, dtype=float)
    y = np.asarray(signal, dtype=float)
    if t.shape != y.shape or t.ndim != 1:
        raise InputError(f"times and signal must be equal 1-D arrays, got {t.shape}, {y.shape}")
    ok = np.isfinite(y)
    if ok.sum() < 3:
        raise InsufficientDataError("signal has fewer than three finite samples")
    y = np.interp(t, t[ok], y[ok])
    dt = float(np.median(np.diff(t)))
    if min_height is None:
        med = float(np.median(y))
        min_height = med + 0.5 * (float(np.max(y)) - med)
    dist = max(1, round(min_interval / dt))
    peaks, props = find_peaks(y, height=min_height, distance=dist)
    if len(peaks) < n_jumps:
        raise InsufficientDataError(
            f"found {count(len(peaks), 'landing spike')}, need {n_jumps}; check that the "
            "recording contains the jump series and covers it completely")
    span = 2.5 * n_jumps if max_span is None else max_span
    heights = props["peak_heights"]
    tp = t[peaks]
    best: NDArray[np.intp] | None = None
    best_score = -np.inf
    for k in range(len(peaks)):
        # the n highest peaks of the window starting at this one (take-off pushes and
        # steps between the landings are lower and drop out)
        win = np.flatnonzero((tp >= tp[k]) & (tp <= tp[k] + span))
        if len(win) < n_jumps:
            continue
        top = win[np.argsort(heights[win])[::-1][:n_jumps]]
        score = float(np.sum(heights[top]))
        if score > best_score:
            best, best_score = np.sort(top), score
    if best is None:
        raise InsufficientDataError(
            f"no series of {n_jumps} landing spikes within {span:.1f} s")
    sel = peaks[best]
    return np.interp([_refine_peak(y, int(i)) for i in sel], np.arange(len(t)), t)


def imu_jump_spikes(rec: ImuRecording, n_jumps: int = 5, min_interval: float = 0.4,
                    min_flight: float = 0.2) -> FloatArray:
    """Landing-spike times (own clock) of one IMU.

    A jump is recognised by its flight: the acceleration norm (mounting- and
    orientation-independent) stays near zero — free fall — for at least ``min_flight``
    seconds, which walking, steps and heel strikes never do (their impacts on a shank
    sensor can be as high as a landing's). The landing is the highest norm within 0.2 s
    after each flight; the ``n_jumps`` consecutive flights of shortest total span are the
    series. Without enough flights (e.g. a clipped or heavily filtered recording) the
    ``n_jumps`` highest acceleration peaks are used (:func:`detect_spikes`).

    Args:
        rec: The recording (SI units).
        n_jumps: Jumps performed.
        min_interval: Shortest time between landings, s.
        min_flight: Shortest free fall counted as a jump's flight, s.

    Returns:
        ``(n_jumps,)`` landing times on the IMU's own clock, s.

    Raises:
        InsufficientDataError: fewer than ``n_jumps`` landings or peaks found.
    """
    ok = np.all(np.isfinite(rec.acc), axis=1)
    t = rec.time[ok]
    norm = np.linalg.norm(rec.acc[ok], axis=1)
    if len(t) > 3:
        dt = float(np.median(np.diff(t)))
        k = max(1, round(0.02 / dt))
        sm = np.convolve(norm, np.ones(k) / k, mode="same")
        free = np.r_[False, sm < 0.35 * G, False]
        edges = np.flatnonzero(np.diff(free.astype(np.int8)))
        starts, ends = edges[0::2], edges[1::2] - 1
        long = (t[ends] - t[starts]) >= min_flight
        lands = []
        for e in ends[long]:
            m = np.flatnonzero((t > t[e]) & (t <= t[e] + 0.2))
            if len(m):
                i = int(m[np.argmax(norm[m])])
                lands.append(float(np.interp(_refine_peak(norm, i), np.arange(len(t)), t)))
        la = np.array(lands)
        if len(la) >= n_jumps:
            if len(la) > n_jumps:
                spans = la[n_jumps - 1:] - la[:len(la) - n_jumps + 1]
                j = int(np.argmin(spans))
                la = la[j:j + n_jumps]
            if np.all(np.diff(la) >= min_interval):
                return la
    return detect_spikes(rec.time, np.linalg.norm(rec.acc, axis=1), n_jumps, min_interval,
                         min_height=1.5 * G)


#: Joints that move with the torso in a vertical jump; their heights are averaged (each
#: one's noise is independent enough that the mean is markedly smoother).
TORSO_ROLES = ("pelvis", "spine_mid", "spine_top", "neck", "hip_left", "hip_right",
               "shoulder_left", "shoulder_right")


def torso_height(
    skeleton: SkeletonSeries, up: ArrayLike = (0.0, 0.0, 1.0)
) -> tuple[FloatArray, FloatArray]:
    """Height of the torso (mean of the :data:`TORSO_ROLES` joints' heights, each taken
    relative to its own median so that a joint missing in some frames does not step the
    mean) on a uniform grid at the median frame rate.

    Args:
        skeleton: The depth skeleton (world frame, metres).
        up: The world's up direction.

    Returns:
        ``(times, height)`` (s, m).

    Raises:
        InsufficientDataError: fewer than 8 frames with a torso joint.
    """
    js = skeleton.joint_set
    u = np.asarray(up, dtype=float)
    u = u / np.linalg.norm(u)
    idx = sorted({js.role_index(r) for r in TORSO_ROLES if r in js.roles})
    h = skeleton.tracked_positions()[:, idx, :] @ u
    h = h - nanstats.nanmedian(h, axis=0)
    hm = nanstats.nanmean(h, axis=1)
    ok = np.isfinite(hm)
    if ok.sum() < 8:
        raise InsufficientDataError("the depth skeleton has fewer than 8 frames with a torso")
    t = skeleton.times
    dt = float(np.median(np.diff(t)))
    grid = np.arange(t[ok][0], t[ok][-1] + 0.5 * dt, dt)
    return grid, np.interp(grid, t[ok], hm[ok])


def torso_vertical_acceleration(
    skeleton: SkeletonSeries,
    up: ArrayLike = (0.0, 0.0, 1.0),
    window: float = 0.2,
) -> tuple[FloatArray, FloatArray]:
    """Vertical acceleration of the torso (:func:`torso_height`).

    The torso height is resampled to the median frame rate and differentiated twice with a
    Savitzky-Golay filter (cubic, ``window`` seconds), which smooths depth-sensor noise.

    Args:
        skeleton: The depth skeleton (world frame, metres).
        up: The world's up direction.
        window: Savitzky-Golay window, s.

    Returns:
        ``(times, acc)``: uniform time grid (s) and vertical acceleration (m/s²).

    Raises:
        InsufficientDataError: too few frames with a tracked torso.
    """
    grid, hz = torso_height(skeleton, up)
    dt = float(grid[1] - grid[0]) if len(grid) > 1 else 1.0
    win = max(5, round(window / dt) | 1)
    if win > len(grid):
        raise InsufficientDataError("skeleton recording is shorter than the smoothing window")
    acc = savgol_filter(hz, win, 3, deriv=2, delta=dt)
    return grid, acc


def synchronize(
    imus: Mapping[str, ImuRecording],
    skeleton: SkeletonSeries | None = None,
    n_jumps: int = 5,
    reference: str | None = None,
    up: ArrayLike = (0.0, 0.0, 1.0),
    refine: bool = True,
    min_match: float = 0.4,
) -> SyncResult:
    """Align IMU streams (and a depth skeleton) by the jump series.

    Args:
        imus: name -> recording.
        skeleton: the depth skeleton (its stream is named ``"skeleton"``), or ``None``.
        n_jumps: number of jumps performed.
        reference: stream whose clock is kept; default the skeleton if given, else the
            first IMU.
        up: the skeleton world frame's up direction.
        refine: with the skeleton as reference, refine each IMU's offset by matching the
            whole jump waveform (see :func:`_refine_against_skeleton`), far more precise
            than the 30 Hz spike times alone.
        min_match: smallest correlation coefficient between an IMU's jump series and the
            skeleton's torso acceleration (median over IMUs) accepted as found.

    Returns:
        The reference stream, per-stream offsets (s to add to its time stamps; apply them
        with :func:`shift_recording`), the detected landing times and residuals.

    Raises:
        InputError: no streams or an unknown reference.
        InsufficientDataError: the jump series is not found in some stream.
    """
    spikes: dict[str, FloatArray] = {}
    for name, rec in imus.items():
        try:
            spikes[name] = imu_jump_spikes(rec, n_jumps)
        except InsufficientDataError as e:
            raise InsufficientDataError(f"IMU {name!r}: {e}") from None
    if not spikes and skeleton is None:
        raise InputError("nothing to synchronise: give at least one IMU recording")
    if not spikes:
        raise InputError("the depth skeleton alone cannot be synchronised: give at least "
                         "one IMU recording")
    names = list(spikes)
    ref = reference or ("skeleton" if skeleton is not None else names[0])
    if ref not in spikes and not (ref == "skeleton" and skeleton is not None):
        have = sorted([*spikes, *(["skeleton"] if skeleton is not None else [])])
        raise InputError(f"unknown reference stream {ref!r}; have {have}")
    # IMU to IMU: the 256 Hz landing spikes agree to a sample
    pivot = ref if ref in spikes else names[0]
    rel = {n: float(np.median(spikes[pivot] - spikes[n])) for n in names}
    to_sk: dict[str, float] = {}  # IMU -> offset onto the skeleton clock
    missing = np.zeros(0, dtype=bool)
    if skeleton is not None:
        try:
            sk_acc = torso_vertical_acceleration(skeleton, up)
            sk_coarse = torso_vertical_acceleration(skeleton, up, window=0.4)
        except InsufficientDataError as e:
            raise InsufficientDataError(f"depth skeleton: {e}") from None
        # template matching of every IMU's whole jump series; their mutual offsets are
        # exact, so the median over IMUs is one robust estimate for the pivot
        matches = [_coarse_offset(imus[n], spikes[n], *sk_coarse) for n in names]
        r_match = float(np.median([r for _, r in matches]))
        if r_match < min_match:
            raise InsufficientDataError(
                f"depth skeleton: its torso motion does not show the IMUs' jump series "
                f"(best match r = {r_match:.2f}); record the depth skeleton from before the "
                "jumps, with the torso in view")
        pivot_sk = float(np.median([o - rel[n] for (o, _), n in zip(matches, names,
                                                                    strict=True)]))
        for n in names:
            to_sk[n] = pivot_sk + rel[n]
            if refine:
                to_sk[n] = _refine_against_skeleton(imus[n], sk_acc, to_sk[n],
                                                    spikes[n] + to_sk[n])
        # the skeleton's landings: the highest torso acceleration near the aligned IMU
        # landings (a global peak search would pick noise)
        on_sk = np.median(np.stack([spikes[n] + to_sk[n] for n in names]), axis=0)
        inside = (on_sk >= sk_acc[0][0]) & (on_sk <= sk_acc[0][-1])
        if inside.sum() < min(3, n_jumps):
            raise InsufficientDataError(
                f"depth skeleton: only {int(inside.sum())} of the {n_jumps} jumps fall inside "
                "its recording; record the depth skeleton from before the jumps")
        found = _peaks_near(*sk_acc, on_sk, 0.1)
        missing = ~np.isfinite(found)
        # a landing outside the depth recording: its time predicted from the IMUs (keeps
        # every series finite; the warning below says so)
        spikes["skeleton"] = np.where(missing, on_sk, found)
        to_sk["skeleton"] = 0.0
    offsets: dict[str, float] = {}
    if skeleton is not None:
        base = to_sk[ref]
        offsets = {n: to_sk[n] - base for n in spikes}
    else:
        offsets = {n: rel[n] - rel[ref] for n in names}
    residuals: dict[str, FloatArray] = {}
    warnings: list[str] = []
    for name, sp in spikes.items():
        residuals[name] = spikes[ref] + offsets[ref] - (sp + offsets[name])
        if np.max(np.abs(residuals[name])) > 0.1:
            warnings.append(f"{name}: jumps disagree by up to "
                            f"{np.max(np.abs(residuals[name])) * 1e3:.0f} ms after alignment; "
                            "check the clock drift or the detected spikes")
    if skeleton is not None and missing.any():
        warnings.append(f"depth skeleton: {count(int(missing.sum()), 'jump landing')} outside "
                        "the depth recording (times predicted from the IMUs)")
    return SyncResult(ref, offsets, spikes, residuals, warnings)


def _peaks_near(t: FloatArray, y: FloatArray, at: FloatArray, half: float) -> FloatArray:
    """Sub-sample time of the maximum of ``y`` within ``±half`` s of each time in ``at``
    (NaN where that window is not entirely inside ``t``)."""
    out = np.full(len(at), np.nan)
    idx = np.arange(len(t))
    for k, tk in enumerate(at):
        m = np.flatnonzero(np.abs(t - tk) <= half)
        if len(m) == 0 or tk - half < t[0] or tk + half > t[-1]:
            continue
        i = int(m[np.argmax(y[m])])
        out[k] = float(np.interp(_refine_peak(y, i), idx, t))
    return out


def _coarse_offset(rec: ImuRecording, spikes: FloatArray, t_sk: FloatArray,
                   a_sk: FloatArray) -> tuple[float, float]:
    """Offset of an IMU onto the skeleton clock by cross-correlating its whole jump series.

    The IMU's acceleration norm minus g (≈ vertical acceleration of an upright body), from
    1.5 s before its first landing to 1 s after the last, is averaged over each depth frame
    period and smoothed like the skeleton's torso acceleration ``a_sk`` (Savitzky-Golay),
    then slid over ``a_sk``: the lag of the largest correlation wins. Free fall (-g for
    ~0.45 s), push-off and landing of all the jumps contribute, so single noise peaks of
    the depth signal cannot win as they can for a spike detector.

    Returns:
        ``(offset, r)``: offset (s) and the correlation coefficient of the match (0 when
        less than 60 % of the template overlaps the skeleton signal).
    """
    dt = float(t_sk[1] - t_sk[0])
    ok = np.all(np.isfinite(rec.acc), axis=1)
    ti = rec.time[ok]
    lin = np.linalg.norm(rec.acc[ok], axis=1) - G
    grid = np.arange(spikes[0] - 1.5, spikes[-1] + 1.0, dt)
    cum = np.r_[0.0, np.cumsum(0.5 * (lin[1:] + lin[:-1]) * np.diff(ti))]
    box = (np.interp(grid + 0.5 * dt, ti, cum) - np.interp(grid - 0.5 * dt, ti, cum)) / dt
    win = max(5, round(0.4 / dt) | 1)
    y = savgol_filter(box, win, 3) if len(box) >= win else box
    y = y - np.mean(y)
    x = a_sk - np.mean(a_sk)
    c = correlate(x, y, mode="full", method="auto")
    k = int(np.argmax(c))
    kk = _refine_peak(c, k)
    m = kk - (len(y) - 1)
    # quality: correlation coefficient of the template with the skeleton signal it was
    # matched to (the template must lie inside the depth recording for most of its length)
    lag = k - (len(y) - 1)
    i0, i1 = max(0, lag), min(len(x), lag + len(y))
    r = 0.0
    if i1 - i0 >= 0.6 * len(y):
        xs, ys = x[i0:i1], y[i0 - lag:i1 - lag]
        xs, ys = xs - xs.mean(), ys - ys.mean()
        den = float(np.sqrt(np.sum(xs * xs) * np.sum(ys * ys)))
        r = float(np.sum(xs * ys) / den) if den > 0 else 0.0
    return float(t_sk[0] + m * dt - grid[0]), r


def _refine_against_skeleton(
    rec: ImuRecording,
    sk_acc: tuple[FloatArray, FloatArray],
    coarse: float,
    ref_spikes: FloatArray,
    search: float = 0.1,
    step: float = 0.0005,
) -> float:
    """Offset of an IMU to the skeleton clock by matching the whole jump series.

    The IMU's acceleration norm minus g (≈ vertical acceleration of an upright body) is
    integrated twice into a pseudo height, sampled at the skeleton's frame times for a
    candidate offset and passed through the same Savitzky-Golay second derivative as the
    torso height; the offset minimising the squared difference over the jump series wins.
    Integration constants and a constant accelerometer bias only add a line or parabola to
    the pseudo height, which the second derivative removes or reduces to a constant (the
    means are subtracted), so no drift correction is needed.
    """
    t_sk, a_sk = sk_acc
    dt_sk = float(np.median(np.diff(t_sk)))
    win = max(5, round(0.2 / dt_sk) | 1)
    lo, hi = float(ref_spikes[0]) - 1.0, float(ref_spikes[-1]) + 1.0
    m = (t_sk >= lo) & (t_sk <= hi)
    if m.sum() < 2 * win:
        return coarse
    ok = np.all(np.isfinite(rec.acc), axis=1)
    t_i = rec.time[ok]
    lin = np.linalg.norm(rec.acc[ok], axis=1) - G
    sel = (t_i >= lo - coarse - search - 1.0) & (t_i <= hi - coarse + search + 1.0)
    if sel.sum() < 10:
        return coarse
    t_i, lin = t_i[sel], lin[sel]
    dti = np.diff(t_i)
    vel = np.r_[0.0, np.cumsum(0.5 * (lin[1:] + lin[:-1]) * dti)]
    height = np.r_[0.0, np.cumsum(0.5 * (vel[1:] + vel[:-1]) * dti)]
    target = a_sk[m] - np.mean(a_sk[m])
    t_grid = t_sk[m]
    best, best_cost = coarse, np.inf
    # the derivative filter needs the neighbouring frames too: pad by its half window
    pad = win // 2
    idx = np.flatnonzero(m)
    i0, i1 = max(idx[0] - pad, 0), min(idx[-1] + pad + 1, len(t_sk))
    t_pad = t_sk[i0:i1]
    inner = slice(idx[0] - i0, idx[0] - i0 + len(t_grid))
    for off in np.arange(coarse - search, coarse + search + step / 2, step):
        h = np.interp(t_pad - off, t_i, height)
        acc = savgol_filter(h, win, 3, deriv=2, delta=dt_sk)[inner]
        cost = float(np.sum((acc - np.mean(acc) - target) ** 2))
        if cost < best_cost:
            best, best_cost = float(off), cost
    return best


def shift_recording(rec: ImuRecording, offset: float) -> ImuRecording:
    """A copy of ``rec`` with ``offset`` seconds added to its time stamps.

    Args:
        rec: The recording (SI units, time first axis).
        offset: Seconds to add (``SyncResult.offsets[name]``).

    Returns:
        A new recording sharing the sample arrays, ``meta["time_offset_s"] = offset``.
    """
    return ImuRecording(time=rec.time + offset, gyr=rec.gyr, acc=rec.acc, mag=rec.mag,
                        frequency=rec.frequency, name=rec.name, quat_ref=rec.quat_ref,
                        movement=rec.movement, meta={**rec.meta, "time_offset_s": offset},
                        warnings=list(rec.warnings))


def sync_signals(
    imus: Mapping[str, ImuRecording],
    skeleton: SkeletonSeries | None = None,
    result: SyncResult | None = None,
    up: ArrayLike = (0.0, 0.0, 1.0),
) -> dict[str, tuple[FloatArray, FloatArray]]:
    """The signals the jump detection looks at, for plotting the synchronisation.

    Args:
        imus: name -> recording.
        skeleton: depth skeleton (stream ``"skeleton"``) or ``None``.
        result: if given, times are shifted onto the reference clock.
        up: the skeleton world frame's up direction.

    Returns:
        stream name -> ``(times, signal)``: IMU acceleration norm and torso vertical
        acceleration (+ g, so both read ≈ 9.81 m/s² at rest), m/s².
    """
    out: dict[str, tuple[FloatArray, FloatArray]] = {}
    for name, rec in imus.items():
        off = result.offsets.get(name, 0.0) if result else 0.0
        out[name] = (rec.time + off, np.linalg.norm(rec.acc, axis=1))
    if skeleton is not None:
        t, a = torso_vertical_acceleration(skeleton, up)
        off = result.offsets.get("skeleton", 0.0) if result else 0.0
        out["skeleton"] = (t + off, a + G)
    return out
