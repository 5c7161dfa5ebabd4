"""Multi-sensor skeleton integration: time correction, resampling, fusion, filtering.

Pipeline (seed paper 000, "Integrating the information gathered by different Kinect
sensors", plus our estimator):

1. Each node's timestamps are mapped to the reference clock with its clock model
   ``t_local = offset + (1 + drift_ppm·1e-6)·t_ref`` (the :class:`engine.sim.clock.SimClock`
   convention), and its joints to the world frame with ``T_world_sensor``.
2. Every sensor is resampled to a common 30 Hz grid by linear interpolation of its
   TRACKED samples; INFERRED and NOT_TRACKED joints are missing values (the paper's
   Methods: "Untracked or inferred joint positions were considered as missing values";
   ``kept_states`` can also keep INFERRED ones, its Discussion's other reading, for the
   bench). Interpolation never bridges a gap longer than ``max_gap_s`` (0.2 s); shorter
   gaps are bridged and reported.
3. Per joint and sample the sensors are combined:

   * ``"mean"`` — the paper's equal-weight mean of the tracked estimates;
   * ``"weighted"`` — ours: an inverse-variance weighted mean. Each sensor's estimate
     of a limb joint gets the weight ``1 / (d² · (1 + (F − 1)·far)²)``: its noise grows
     linearly with the distance d, and by the factor F (:data:`FAR_SIDE_NOISE_FACTOR`)
     when the sensor sees the joint's body half from the other side of the body, with
     ``far = clip(−2 cos θ, 0, 1)`` and θ the angle between the joint→sensor line of
     sight and the outward normal of that body side (from the fused hip and shoulder
     axes): 0 for a sensor on the joint's side or straight ahead/behind, 1 once it is
     ≥ 30° to the other side of the body's sagittal plane. So left joints are mostly
     taken from sensors on the subject's left, while the far views still average noise
     down, in every coordinate: a far view's fit is worse along the walkway too (seed
     000, Table 2: one-sided, the far foot's steps are biased and scattered in length as
     well as width), and equal weights there cost step-length agreement; midline joints
     are weighted by distance only. Each sensor's limb joints
     are first moved back along its line of sight by the surface bias of a depth fit
     (``SURFACE_BIAS_M``: a sensor sees, and fits to, the near half of a limb), and a
     sensor whose ankles' left/right order is inverted, and whose ankles fit the other
     sensors' better swapped, has its lower legs' labels swapped back (a tracker's leg
     swap). Each sensor is
     further weighted by a Tukey biweight of its residual from the current estimate
     (iteratively reweighted from the per-coordinate median, so a sensor that swaps or
     misplaces a joint is rejected).
4. Fused gaps up to ``max_gap_s`` are interpolated (reported), then each trajectory is
   low-pass filtered with a zero-phase 4th-order Butterworth (``filtfilt``) at 6 Hz by
   default: walking kinematics have their power below ~6 Hz (Winter, *Biomechanics and
   Motor Control of Human Movement*, 4th ed., §3.4: 6 Hz for marker data of walking),
   while Kinect joint jitter is broadband; zero phase keeps event times unbiased.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from engine import nanstats
from engine.errors import InputError, InsufficientDataError
from engine.geometry import transform_points
from engine.skeleton import JointSet, SkeletonSeries, TrackingState
from engine.wording import named

FloatArray = NDArray[np.float64]
Estimator = Literal["mean", "weighted"]

#: Joint-noise SD of a limb seen from the body half turned away from the sensor,
#: relative to one seen from its own side or side-on. The turned-away half is fitted to
#: what shows past the body and is less accurate (Wang et al. 2015, IEEE ICHI: the far
#: half's errors grow at 30°/60° view angles; seed 000 Discussion: the far leg's
#: estimates are unreliable). A round prior, not fitted: ``bench/gait_study.py`` moves
#: by < 0.005 in ICC between 2 and 2.5.
FAR_SIDE_NOISE_FACTOR = 2.0
#: Distance (m) at which the distance weight is 1.
REF_DISTANCE_M = 2.5
#: Tukey biweight tuning constant (95 % efficiency for Gaussian residuals).
TUKEY_C = 4.685
#: Lower bound of the robust residual scale (m): below this, disagreements are noise.
MIN_SCALE_M = 0.02
#: Lateral inversion of a sensor's ankles (m) taken as a left/right label swap when
#: another sensor sees them the right way round by as much (a few SD of the lateral
#: joint noise, well under a step width of ≈ 10 cm).
SWAP_MARGIN_M = 0.03
#: How far a sensor's estimate of a limb joint lies towards that sensor (m). A depth
#: sensor sees only the half of the limb's surface facing it, and the skeleton is fitted
#: to that surface: seed 000 (Fig. 5B and its supplement) shows the ankle estimates of
#: two opposite sensors a few cm apart, each closer to the surface it sees, i.e. ≈ 1.5 cm
#: each way, about half the ankle's radius (malleolar width ≈ 7 cm). The weighted
#: estimator moves each sensor's limb joints back along its line of sight by this much.
SURFACE_BIAS_M = 0.015


@dataclass
class SensorStream:
    """One sensor's skeleton recording and its calibration.

    Attributes:
        series: skeleton in the sensor frame, on the node's local clock.
        T_world_sensor: 4×4 pose of the sensor in the world frame.
        clock_offset_s: node clock reading at reference time 0.
        clock_drift_ppm: node clock rate error (positive = node clock runs fast).
        sensor_id: name used in reports.
    """

    series: SkeletonSeries
    T_world_sensor: FloatArray
    clock_offset_s: float = 0.0
    clock_drift_ppm: float = 0.0
    sensor_id: str = ""


@dataclass(frozen=True)
class GapFill:
    """A gap in a joint's trajectory that was (or was not) bridged."""

    source: str  # sensor id, or "fused"
    joint: str
    t_start: float
    t_end: float


@dataclass
class FusionReport:
    """Data quality of an integration.

    Attributes:
        estimator: ``"mean"`` or ``"weighted"``.
        rate_hz: output rate.
        cutoff_hz: low-pass cut-off (None = no filter).
        tracked_pct: per joint, % of output samples seen (not gap-bridged) by ≥ 1 sensor.
        filled_pct: per joint, % of output samples that exist only by interpolation
            across a gap ≤ max_gap_s (in a sensor's stream or the fused trajectory).
        gaps_filled: bridged gaps (≤ max_gap_s), per sensor and fused.
        gaps_unfilled: gaps left missing (> max_gap_s) in the fused trajectory.
        sensors_contributing: per sensor, % of fused joint samples it contributed to.
        sensors_per_sample: mean number of sensors per fused joint sample.
        clock_offsets_s: the offsets applied.
    """

    estimator: str
    rate_hz: float
    cutoff_hz: float | None
    tracked_pct: dict[str, float] = field(default_factory=dict)
    filled_pct: dict[str, float] = field(default_factory=dict)
    gaps_filled: list[GapFill] = field(default_factory=list)
    gaps_unfilled: list[GapFill] = field(default_factory=list)
    sensors_contributing: dict[str, float] = field(default_factory=dict)
    sensors_per_sample: float = 0.0
    clock_offsets_s: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form.

        Returns:
            The fields as plain values (gaps as dicts).
        """
        return asdict(self)


def correct_timestamps(times: FloatArray, offset_s: float, drift_ppm: float = 0.0) -> FloatArray:
    """Node-clock times → reference times (inverse of ``offset + (1+drift)·t``).

    Args:
        times: ``(T,)`` times on the node's clock, s.
        offset_s: The node clock's offset, s.
        drift_ppm: Its drift, parts per million.

    Returns:
        ``(T,)`` times on the reference clock, s.
    """
    return (np.asarray(times, dtype=float) - offset_s) / (1.0 + drift_ppm * 1e-6)


def resample_stream(stream: SensorStream, grid: FloatArray, max_gap_s: float = 0.2,
                    kept_states: Collection[int] = (TrackingState.TRACKED,)
                    ) -> tuple[FloatArray, NDArray[np.bool_], list[GapFill]]:
    """One sensor's TRACKED joints (or those in ``kept_states``) in the world frame on
    ``grid``.

    Vectorised over joints: for every grid time the last valid sample at or before it
    and the first valid sample after it are found from running maxima/minima of the
    valid sample indices, and the pair is interpolated when it spans ≤ ``max_gap_s``.

    Args:
        stream: The sensor's skeletons, calibration and clock model.
        grid: ``(G,)`` output times on the reference clock, s.
        max_gap_s: Longest gap bridged by interpolation, s.
        kept_states: Tracking states whose samples are used; the others are missing
            values (default: TRACKED only).

    Returns:
        ``(G, J, 3)`` positions (NaN where the sensor has no estimate within
        ``max_gap_s``), the ``(G, J)`` mask of samples that bridge a gap (no real sample
        within 1.5 frame periods) and the gaps bridged.
    """
    s = stream.series
    t = correct_timestamps(s.times, stream.clock_offset_s, stream.clock_drift_ppm)
    P = transform_points(np.asarray(stream.T_world_sensor, dtype=float), s.positions)
    keep = np.array(sorted(int(k) for k in kept_states), dtype=s.states.dtype)
    valid = np.isin(s.states, keep) & np.isfinite(P).all(axis=-1)  # (T, J)
    T, J = valid.shape
    G = len(grid)
    out = np.full((G, J, 3), np.nan)
    if T == 0:
        return out, np.zeros((G, J), dtype=bool), []
    ar = np.arange(T)[:, None]
    last = np.maximum.accumulate(np.where(valid, ar, -1), axis=0)  # (T, J)
    nxt = np.minimum.accumulate(np.where(valid, ar, T)[::-1], axis=0)[::-1]
    k = np.searchsorted(t, grid, side="right") - 1  # sample at or before each grid time
    kc = np.clip(k, 0, T - 1)
    ia = np.where((k >= 0)[:, None], last[kc], -1)  # (G, J)
    kn = np.clip(k + 1, 0, T - 1)
    ib = np.where((k + 1 < T)[:, None], nxt[kn], T)
    has_a = ia >= 0
    has_b = ib < T
    iac = np.clip(ia, 0, T - 1)
    ibc = np.clip(ib, 0, T - 1)
    ta, tb = t[iac], t[ibc]
    g2 = grid[:, None]
    exact = has_a & np.isclose(ta, g2, rtol=0.0, atol=1e-9)
    span_ok = has_a & has_b & ((tb - ta) <= max_gap_s + 1e-9)
    ok = exact | span_ok
    u = np.where(span_ok, (g2 - ta) / np.where(tb > ta, tb - ta, 1.0), 0.0)
    jj = np.broadcast_to(np.arange(J), (G, J))
    pa, pb = P[iac, jj], P[ibc, jj]
    est = pa + u[..., None] * np.where(span_ok[..., None], pb - pa, 0.0)
    out[ok] = est[ok]

    # Gaps between consecutive valid samples longer than 1.5 frame periods.
    nominal = float(np.median(np.diff(t))) if T > 1 else 1.0 / 30.0
    bridged = span_ok & ~exact & ((tb - ta) > 1.5 * nominal)
    prev = np.vstack([np.full((1, J), -1), last[:-1]])
    gi, gj = np.nonzero(valid & (prev >= 0))
    dt = t[gi] - t[prev[gi, gj]]
    sel = (dt > 1.5 * nominal) & (dt <= max_gap_s + 1e-9)
    names = s.joint_set.joints
    filled = [GapFill(stream.sensor_id, names[j], float(t[prev[i, j]]), float(t[i]))
              for i, j in zip(gi[sel], gj[sel], strict=True)
              if t[i] >= grid[0] and t[prev[i, j]] <= grid[-1]]
    return out, bridged, filled


def _nanmedian0(x: FloatArray) -> FloatArray:
    """``np.nanmedian(x, axis=0)`` for a short first axis, without its Python overhead.

    NaN sorts last, so the median of the ``n`` finite values sits at ``(n−1)//2`` and
    ``n//2``; all-NaN slices give NaN.
    """
    xs = np.sort(x, axis=0)
    n = np.isfinite(x).sum(axis=0)
    lo = np.take_along_axis(xs, np.maximum((n - 1) // 2, 0)[None], axis=0)[0]
    hi = np.take_along_axis(xs, np.maximum(n // 2, 0)[None], axis=0)[0]
    hi = np.where(n % 2 == 1, lo, hi)
    return np.where(n > 0, 0.5 * (lo + hi), np.nan)


def _joint_sides(js: JointSet) -> FloatArray:
    """+1 for left-side joints, −1 for right-side, 0 for midline joints."""
    out = np.zeros(len(js.joints))
    for i, name in enumerate(js.joints):
        n = name.lower()
        out[i] = 1.0 if "left" in n else -1.0 if "right" in n else 0.0
    return out


def _lateral_axis(P: FloatArray, js: JointSet, rate: float) -> FloatArray:
    """``(G, 3)`` horizontal unit vector pointing to the subject's left (NaN if unknown)."""
    acc = np.zeros((P.shape[0], 3))
    for a, b in (("hip_left", "hip_right"), ("shoulder_left", "shoulder_right")):
        if a in js.roles and b in js.roles:
            d = P[:, js.role_index(a)] - P[:, js.role_index(b)]
            acc += np.nan_to_num(d)
    acc[:, 2] = 0.0
    n = np.linalg.norm(acc, axis=1)
    ok = n > 1e-6
    lat = np.full_like(acc, np.nan)
    lat[ok] = acc[ok] / n[ok, None]
    if ok.sum() >= 2 and not ok.all():
        g = np.arange(len(lat))
        for k in range(2):
            lat[~ok, k] = np.interp(g[~ok], g[ok], lat[ok, k])
        lat[~ok, 2] = 0.0
    if ok.any():
        # scipy where it is used: the server imports this module at start (storage)
        from scipy.ndimage import uniform_filter1d

        # Smooth over ~0.3 s: the trunk's orientation changes slowly.
        lat = uniform_filter1d(lat, max(1, round(0.3 * rate)), axis=0, mode="nearest")
        lat /= np.maximum(np.linalg.norm(lat, axis=1, keepdims=True), 1e-9)
    return lat


def _unswap_legs(E: FloatArray, have: NDArray[np.bool_], js: JointSet, lat: FloatArray
                 ) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Undo a sensor's brief left/right lower-leg label swap (``(S, G, J, 3)`` in/out).

    A tracker swaps the legs' labels when they cross in its view (Kinect v2 gait studies
    report such outliers). The left ankle is then on the right of the right ankle. Feet
    pass each other side by side, a step width apart, so a sensor whose ankles' lateral
    order is inverted by more than :data:`SWAP_MARGIN_M` is a candidate, and its
    knee/ankle/foot labels are swapped back when its ankles, swapped, lie closer on the
    floor to the other sensors' ankles than as they are. The references are the
    per-sample medians of each ankle over the sensors not inverted, including one that
    sees a single ankle (the far one hidden): with two sensors a vote cannot tell which
    is wrong, and the far ankle is often missing exactly when the legs cross. A
    cross-over step seen by every sensor has no reference and is left alone; a lateral
    order inverted by noise while the feet are a step apart along the walk (a far-side
    view's lateral error) fits better as it is, and swapping it would move both feet by a
    step length.
    """
    pairs = [(js.role_index(f"{p}_left"), js.role_index(f"{p}_right"))
             for p in ("knee", "ankle", "foot") if f"{p}_left" in js.roles
             and f"{p}_right" in js.roles]
    if not pairs or not np.isfinite(lat).any() or E.shape[0] < 2:
        return E, have
    iL, iR = js.role_index("ankle_left"), js.role_index("ankle_right")
    d = np.einsum("sgk,gk->sg", E[:, :, iL] - E[:, :, iR], np.nan_to_num(lat))
    d = np.where(have[:, :, iL] & have[:, :, iR] & np.isfinite(lat[None, :, 0]), d, np.nan)
    inverted: NDArray[np.bool_] = np.asarray(d < -SWAP_MARGIN_M, dtype=bool)  # (S, G)
    if not inverted.any():
        return E, have
    refs = []
    for j in (iL, iR):
        seen = (have[:, :, j] & ~inverted)[..., None]
        refs.append(_nanmedian0(np.where(seen, E[:, :, j, :2], np.nan)))  # (G, 2)
    refL, refR = refs
    eL, eR = E[:, :, iL, :2], E[:, :, iR, :2]

    def dist(a: FloatArray, b: FloatArray) -> FloatArray:
        return np.nan_to_num(np.linalg.norm(a - b[None], axis=-1), nan=0.0)

    keep_cost = dist(eL, refL) + dist(eR, refR)
    swap_cost = dist(eL, refR) + dist(eR, refL)
    has_ref = np.isfinite(refL[:, 0]) | np.isfinite(refR[:, 0])
    swap = inverted & has_ref[None] & (swap_cost < keep_cost)
    if not swap.any():
        return E, have
    E = E.copy()
    have = have.copy()
    si, gi = np.nonzero(swap)
    for a, b in pairs:
        E[si, gi, a], E[si, gi, b] = E[si, gi, b].copy(), E[si, gi, a].copy()
        have[si, gi, a], have[si, gi, b] = have[si, gi, b].copy(), have[si, gi, a].copy()
    return E, have


def _fuse_weighted(E: FloatArray, centres: FloatArray, js: JointSet, rate: float,
                   n_iter: int = 4, surface_bias_m: float = SURFACE_BIAS_M
                   ) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Weighted robust fusion of ``(S, G, J, 3)`` estimates → ``(G, J, 3)``, used mask."""
    have = np.asarray(np.isfinite(E).all(axis=-1), dtype=bool)  # (S, G, J)
    init = _nanmedian0(E)  # robust start: the per-coordinate median
    lat = _lateral_axis(init, js, rate)  # (G, 3)
    E, have = _unswap_legs(E, have, js, lat)
    init = _nanmedian0(E)
    sides = _joint_sides(js)  # (J,)
    to_sensor = centres[:, None, None, :] - E  # (S, G, J, 3)
    dist = np.linalg.norm(to_sensor, axis=-1)
    los = to_sensor / np.maximum(dist, 1e-9)[..., None]
    # Limb joints are fitted to the limb's visible surface: move each estimate back along
    # the horizontal line of sight by surface_bias_m (limbs are near-vertical, so the
    # visible surface is displaced horizontally).
    los_h = los.copy()
    los_h[..., 2] = 0.0
    los_h /= np.maximum(np.linalg.norm(los_h, axis=-1, keepdims=True), 1e-9)
    limb = (sides != 0)[None, None, :, None]
    E = np.where(limb, E - surface_bias_m * los_h, E)
    normal = sides[None, :, None] * lat[:, None, :]  # (G, J, 3) outward side normal
    cos = np.einsum("sgjk,gjk->sgj", los, np.nan_to_num(normal))
    # Inverse variance: noise SD ∝ distance, × FAR_SIDE_NOISE_FACTOR from the far side.
    far = np.clip(-2.0 * np.nan_to_num(cos), 0.0, 1.0)
    far = np.where((sides[None, None, :] != 0) & np.isfinite(lat[None, :, :1]), far, 0.0)
    w_view = 1.0 / (1.0 + (FAR_SIDE_NOISE_FACTOR - 1.0) * far) ** 2
    w_dist = np.where(have, (REF_DISTANCE_M / np.maximum(dist, 0.3)) ** 2, 0.0)
    w_prior = w_dist * w_view
    Ez = np.where(have[..., None], E, 0.0)

    def combine(rho: FloatArray) -> FloatArray:
        w = w_prior * rho
        sw = w.sum(axis=0)
        return np.einsum("sgj,sgjk->gjk", w, Ez) / np.where(sw > 0, sw, np.nan)[..., None]

    rho = np.ones_like(w_dist)
    est = init
    for _ in range(n_iter):
        # Residuals from the current (initially: median) estimate, robust scale, Tukey
        # biweights, then the weighted means with the new weights.
        r = np.linalg.norm(E - est[None], axis=-1)  # (S, G, J), NaN where missing
        scale = np.maximum(1.4826 * np.nan_to_num(_nanmedian0(r)), MIN_SCALE_M)
        z = r / (TUKEY_C * scale)[None]
        rho_new = np.where(have & (z < 1.0), (1.0 - np.nan_to_num(z) ** 2) ** 2, 0.0)
        # If every sensor would be rejected, keep the previous weights.
        rho = np.where(((w_prior * rho_new).sum(axis=0) > 0)[None], rho_new, rho)
        est = combine(rho)
    used = have & (w_dist * rho > 0)
    return est, used


def _fill_fused(grid: FloatArray, X: FloatArray, max_gap_s: float, names: tuple[str, ...]
                ) -> tuple[FloatArray, NDArray[np.bool_], list[GapFill], list[GapFill]]:
    """Interpolate fused gaps ≤ max_gap_s; report filled and unfilled gaps."""
    out = X.copy()
    filled_mask = np.zeros(X.shape[:2], dtype=bool)
    filled: list[GapFill] = []
    unfilled: list[GapFill] = []
    for j in range(X.shape[1]):
        ok = np.isfinite(X[:, j]).all(axis=1)
        idx = np.flatnonzero(ok)
        if len(idx) < 2:
            continue
        for g in np.flatnonzero(np.diff(idx) > 1):
            a, b = idx[g], idx[g + 1]
            ta, tb = grid[a], grid[b]
            if tb - ta <= max_gap_s + 1e-9:
                for k in range(3):
                    out[a + 1:b, j, k] = np.interp(grid[a + 1:b], [ta, tb],
                                                   [X[a, j, k], X[b, j, k]])
                filled_mask[a + 1:b, j] = True
                filled.append(GapFill("fused", names[j], float(ta), float(tb)))
            else:
                unfilled.append(GapFill("fused", names[j], float(ta), float(tb)))
    return out, filled_mask, filled, unfilled


def lowpass(X: FloatArray, rate: float, cutoff_hz: float, order: int = 4) -> FloatArray:
    """Zero-phase Butterworth low-pass along axis 0, per finite segment.

    Segments too short for ``filtfilt``'s padding are left unfiltered.

    Args:
        X: ``(T, ...)`` samples, time first (NaN splits segments).
        rate: Sampling rate, Hz.
        cutoff_hz: Cut-off frequency, Hz.
        order: Butterworth order (doubled by the forward-backward pass).

    Returns:
        The filtered samples, same shape (NaN kept).

    Raises:
        InputError: the cut-off is not between 0 and Nyquist.
    """
    if not 0 < cutoff_hz < rate / 2:
        raise InputError(f"cut-off {cutoff_hz} Hz must be between 0 and Nyquist ({rate / 2} Hz)")
    from scipy.signal import butter, filtfilt

    b, a = butter(order, cutoff_hz / (rate / 2))
    pad = 3 * max(len(a), len(b))
    out = X.copy()
    flat = out.reshape(len(X), -1)
    fin = np.isfinite(flat)
    full = fin.all(axis=0)
    if full.any() and len(X) > pad:
        flat[:, full] = filtfilt(b, a, flat[:, full], axis=0)  # one call for gap-free columns
    for c in np.flatnonzero(~full):
        idx = np.flatnonzero(fin[:, c])
        if len(idx) == 0:
            continue
        for r in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
            if len(r) > pad:
                flat[r, c] = filtfilt(b, a, flat[r, c])
    return out


def integrate_skeletons(
    streams: list[SensorStream],
    estimator: Estimator = "weighted",
    rate_hz: float = 30.0,
    max_gap_s: float = 0.2,
    cutoff_hz: float | None = 6.0,
    sensors: Collection[str] | None = None,
    surface_bias_m: float = SURFACE_BIAS_M,
    kept_states: Collection[int] = (TrackingState.TRACKED,),
) -> tuple[SkeletonSeries, FusionReport]:
    """Fuse several sensors' skeletons of one subject into one world-frame skeleton.

    Args:
        streams: one :class:`SensorStream` per sensor (same joint set).
        estimator: ``"mean"`` (paper) or ``"weighted"`` (ours; see module docstring).
        rate_hz: output sampling rate (the paper: 30 Hz).
        max_gap_s: longest gap bridged by interpolation.
        cutoff_hz: low-pass cut-off; None disables filtering.
        sensors: ids of the sensors to use (e.g. only those on the subject's left, for
            the paper's one-sided analysis of the same recording); None uses all.
        surface_bias_m: ``"weighted"`` only: how far each sensor's limb joints lie
            towards it (:data:`SURFACE_BIAS_M`); 0 for sensors known to be unbiased.
        kept_states: tracking states of a sensor's joints that are used (default
            TRACKED only: INFERRED and NOT_TRACKED are missing values, the paper's
            Methods); ``(TRACKED, INFERRED)`` keeps the SDK's guesses of occluded joints
            and drops only NOT_TRACKED ones (the paper's Discussion, another reading).

    Returns:
        The fused skeleton (world frame, reference clock; TRACKED where sensors gave an
        estimate, INFERRED where a short gap was interpolated, NOT_TRACKED elsewhere) and
        the quality report.

    Raises:
        InputError: no streams, mixed joint sets, unknown estimator, bad transform or
            unknown sensor ids.
        InsufficientDataError: the streams do not overlap a single output sample.
    """
    if not streams:
        raise InputError("no sensor streams to integrate")
    # Name unnamed streams (without touching the caller's objects).
    streams = [s if s.sensor_id else replace(s, sensor_id=f"sensor{k + 1}")
               for k, s in enumerate(streams)]
    if sensors is not None:
        unknown = sorted(set(sensors) - {s.sensor_id for s in streams})
        if unknown:
            raise InputError(f"{named('unknown sensor id', unknown)}; streams are "
                             + ", ".join(s.sensor_id for s in streams))
        streams = [s for s in streams if s.sensor_id in set(sensors)]
        if not streams:
            raise InputError("no sensors selected")
    if estimator not in ("mean", "weighted"):
        raise InputError(f"estimator must be 'mean' or 'weighted', got {estimator!r}")
    kept = sorted({int(k) for k in kept_states})
    if TrackingState.TRACKED not in kept or not set(kept) <= {TrackingState.TRACKED,
                                                              TrackingState.INFERRED}:
        raise InputError("kept_states must be TRACKED, optionally with INFERRED; got "
                         + ", ".join(str(k) for k in kept))
    js = streams[0].series.joint_set
    for k, s in enumerate(streams):
        if s.series.joint_set.name != js.name:
            raise InputError(f"stream {s.sensor_id or k} uses joint set "
                             f"{s.series.joint_set.name}, expected {js.name}")
        T = np.asarray(s.T_world_sensor, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise InputError(f"stream {s.sensor_id or k}: T_world_sensor must be a finite 4×4")
    ids = [s.sensor_id for s in streams]
    spans = [correct_timestamps(s.series.times[[0, -1]], s.clock_offset_s, s.clock_drift_ppm)
             for s in streams if len(s.series) >= 2]
    if not spans:
        raise InsufficientDataError("every sensor stream has fewer than two frames")
    t0 = min(float(a[0]) for a in spans)
    t1 = max(float(a[1]) for a in spans)
    grid = np.arange(np.ceil(t0 * rate_hz - 1e-9), np.floor(t1 * rate_hz + 1e-9) + 1) / rate_hz
    if len(grid) < 2:
        raise InsufficientDataError("the recording is shorter than two output samples")

    E = np.empty((len(streams), len(grid), len(js.joints), 3))
    report = FusionReport(estimator, rate_hz, cutoff_hz,
                          clock_offsets_s={i: float(s.clock_offset_s)
                                           for s, i in zip(streams, ids, strict=True)})
    real = np.zeros(E.shape[:3], dtype=bool)
    for k, s in enumerate(streams):
        E[k], bridged, f = resample_stream(s, grid, max_gap_s, kept)
        real[k] = np.isfinite(E[k]).all(axis=-1) & ~bridged
        report.gaps_filled += f
    have = np.asarray(np.isfinite(E).all(axis=-1), dtype=bool)
    if estimator == "mean":
        X = nanstats.nanmean(E, axis=0)  # NaN where no sensor has the joint
        used = have
    else:
        centres = np.array([np.asarray(s.T_world_sensor, dtype=float)[:3, 3] for s in streams])
        X, used = _fuse_weighted(E, centres, js, rate_hz, surface_bias_m=surface_bias_m)
    any_est = np.isfinite(X).all(axis=-1)
    any_real = np.asarray(real.any(axis=0), dtype=bool)
    X, filled_mask, ff, fu = _fill_fused(grid, X, max_gap_s, js.joints)
    report.gaps_filled += ff
    report.gaps_unfilled += fu
    if cutoff_hz is not None:
        X = lowpass(X, rate_hz, cutoff_hz)
    states = np.full(any_est.shape, TrackingState.NOT_TRACKED, dtype=np.uint8)
    # INFERRED: the estimate exists only thanks to interpolation across a gap.
    states[filled_mask | any_est] = TrackingState.INFERRED
    states[any_real] = TrackingState.TRACKED
    G = len(grid)
    report.tracked_pct = {n: float(100.0 * any_real[:, j].mean())
                          for j, n in enumerate(js.joints)}
    interp = (filled_mask | any_est) & ~any_real
    report.filled_pct = {n: float(100.0 * interp[:, j].mean()) for j, n in enumerate(js.joints)}
    n_fused = max(int(any_est.sum()), 1)
    report.sensors_contributing = {i: float(100.0 * used[k].sum() / n_fused)
                                   for k, i in enumerate(ids)}
    report.sensors_per_sample = float(used.sum() / n_fused)
    meta = {"frame": "world", "estimator": estimator, "sensors": ids, "rate_hz": rate_hz,
            "cutoff_hz": cutoff_hz, "samples": G}
    if kept != [TrackingState.TRACKED]:
        meta["kept_states"] = [TrackingState(k).name for k in kept]
    return SkeletonSeries(grid, X, states, js, meta), report
