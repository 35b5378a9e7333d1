"""Motion, time offset and dwells of two pose/coupling streams: the pure array functions behind
``openemt collect`` (and any step that finds where a tracked object stood still).

Two streams arrive with their own clocks: the tracker's demodulated couplings ``C(t)`` and the
reference's poses ``B(t')`` (a robot flange or an optical marker, docs/reference-calibration.md).
The functions here

- measure motion in each stream (:func:`coupling_motion`: the relative rate of change of the
  couplings, which needs no calibration; :func:`pose_motion`: translation and rotation speed);
- estimate the time offset ``t' = t + offset`` between the streams by cross-correlating the two
  motion profiles (:func:`estimate_time_offset`);
- find the dwells where both streams are static, average the couplings and the reference pose
  over each, and drop the dwells where either moved (:func:`find_dwells`,
  :func:`collect_dwells`);
- summarise how well the collected poses cover the tracker's working volume and orientations
  (:func:`coverage`).

Thresholds are module constants (documented in docs/reference-calibration.md#collecting) and
keyword arguments.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from .._errors import InputError
from ..geometry import pose_from_rt, rotation_diversity

__all__ = [
    "BASELINE_S",
    "COUPLING_RATE_STATIC",
    "GRID_S",
    "LEVER_M",
    "MARGIN_S",
    "MIN_DWELL_S",
    "DwellSet",
    "OffsetEstimate",
    "ROTATION_SPEED_STATIC",
    "SPEED_STATIC",
    "collect_dwells",
    "average_dwell",
    "coupling_motion",
    "coverage",
    "estimate_time_offset",
    "find_dwells",
    "log_profile",
    "mean_pose",
    "pose_motion",
    "time_offset_scan",
]

#: A tracker sample is static when its couplings change by less than this fraction of their
#: norm per second (1/s), measured over ``BASELINE_S``.
COUPLING_RATE_STATIC = 0.02
#: A reference sample is static when it moves slower than this (m/s) ...
SPEED_STATIC = 2e-3
#: ... and turns slower than this (rad/s).
ROTATION_SPEED_STATIC = np.deg2rad(1.0)
#: Motion is measured as the difference of 0.1 s box averages 0.1 s apart.
BASELINE_S = 0.1
#: Lever (m) that turns a rotation speed into a speed for the motion profile of the reference.
LEVER_M = 0.1
#: Floor of :func:`log_profile`, a fraction of the 99th percentile of the motion.
PROFILE_FLOOR = 0.01
#: Grid step (s) of the cross-correlation of the two motion profiles.
GRID_S = 0.002
#: A dwell is trimmed by this much at both ends (the settling of the robot and the frame
#: length of the demodulator) ...
MARGIN_S = 0.1
#: ... and kept when at least this long after trimming.
MIN_DWELL_S = 0.3
#: Within a kept dwell, the means of its first and second halves may differ by at most this
#: fraction of the couplings' norm (tracker), and by these (reference): a slow drift below
#: the static speeds is caught, while the per-sample noise averages out.
COUPLING_DRIFT = 1e-3
TRANS_DRIFT_M = 0.2e-3
ROT_DRIFT_RAD = np.deg2rad(0.1)


def _uniform(times, values, step, grid_start=None):
    """Linear interpolation of ``values`` (N, ...) onto a uniform grid from times[0] (or on the
    grid ``grid_start + k * step`` within the times, so that pieces of a stream line up)."""
    t = np.asarray(times, dtype=np.float64)
    if grid_start is None:
        n = int(np.floor((t[-1] - t[0]) / step)) + 1
        g = t[0] + step * np.arange(n)
    else:
        k0 = int(np.ceil((t[0] - grid_start) / step - 1e-9))
        k1 = int(np.floor((t[-1] - grid_start) / step + 1e-9))
        g = grid_start + step * np.arange(k0, max(k1 + 1, k0))
        n = len(g)
    flat = np.asarray(values, dtype=np.float64).reshape(len(t), -1)
    out = np.empty((n, flat.shape[1]))
    for k in range(flat.shape[1]):
        out[:, k] = np.interp(g, t, flat[:, k])
    return g, out


def _box(x, w):
    """Centred moving average of ``x`` (n, m) over ``w`` samples (edges: shorter windows)."""
    if w <= 1:
        return x
    c = np.cumsum(np.vstack([np.zeros((1, x.shape[1])), x]), axis=0)
    n = len(x)
    i = np.arange(n)
    lo = np.clip(i - w // 2, 0, n)
    hi = np.clip(i - w // 2 + w, 0, n)
    return (c[hi] - c[lo]) / (hi - lo)[:, None]


def _diff(x, k):
    """``x[i + k] - x[i - k]`` with the ends held (n, m)."""
    n = len(x)
    i = np.arange(n)
    return x[np.clip(i + k, 0, n - 1)] - x[np.clip(i - k, 0, n - 1)]


def _check_times(times, name):
    t = np.asarray(times, dtype=np.float64)
    if t.ndim != 1 or len(t) < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise InputError(f"expected `{name}` as at least two finite, increasing time stamps, "
                         f"got shape {t.shape}")
    return t


def coupling_motion(times, couplings, *, step: float = GRID_S, baseline: float = BASELINE_S,
                    grid_start: float | None = None):
    """Motion of the tracker's sensor from its couplings alone: ``||dC/dt|| / ||C||`` (1/s).

    The couplings are put on a uniform grid of ``step`` seconds (from the first time, or
    ``grid_start + k * step``), averaged over ``baseline`` and differenced over ``baseline``;
    no calibration is needed. Returns ``(grid_times, rate)``. A value depends on the samples
    within ``baseline`` of its time only, so a stream can be profiled piece by piece.
    """
    t = _check_times(times, "times")
    C = np.asarray(couplings)
    if C.ndim < 2 or len(C) != len(t):
        raise InputError(f"expected couplings (N, ...) with N = {len(t)} time stamps, got shape "
                         f"{C.shape}")
    g, x = _uniform(t, np.real(C).reshape(len(t), -1), step, grid_start)
    k = max(1, int(round(baseline / step)))
    xs = _box(x, k)
    d = np.linalg.norm(_diff(xs, (k + 1) // 2), axis=1)
    span = step * 2 * ((k + 1) // 2)
    return g, d / span / np.maximum(np.linalg.norm(xs, axis=1), np.finfo(float).tiny)


def pose_motion(times, poses, *, step: float = GRID_S, baseline: float = BASELINE_S,
                grid_start: float | None = None):
    """Translation speed (m/s) and rotation speed (rad/s) of a pose stream on a uniform grid
    (as :func:`coupling_motion`).

    Returns ``(grid_times, speed, rotation_speed)``.
    """
    t = _check_times(times, "times")
    P = np.asarray(poses, dtype=np.float64)
    if P.shape != (len(t), 4, 4):
        raise InputError(f"expected poses ({len(t)}, 4, 4), got shape {P.shape}")
    g, x = _uniform(t, np.concatenate([P[:, :3, 3], P[:, :3, :3].reshape(len(t), 9)], axis=1),
                    step, grid_start)
    k = max(1, int(round(baseline / step)))
    xs = _box(x, k)
    h = (k + 1) // 2
    span = step * 2 * h
    speed = np.linalg.norm(_diff(xs[:, :3], h), axis=1) / span
    n = len(xs)
    i = np.arange(n)
    Ra = xs[np.clip(i - h, 0, n - 1), 3:].reshape(n, 3, 3)
    Rb = xs[np.clip(i + h, 0, n - 1), 3:].reshape(n, 3, 3)
    # averaged matrices are near-rotations; the angle of Ra^T Rb from its trace
    tr = np.einsum("nij,nij->n", Ra, Rb)
    norms = np.einsum("nij,nij->n", Ra, Ra) * np.einsum("nij,nij->n", Rb, Rb)
    tr = tr * 3 / np.sqrt(np.maximum(norms, np.finfo(float).tiny))
    angle = np.arccos(np.clip((tr - 1) / 2, -1.0, 1.0))
    return g, speed, angle / span


def _standardise(x):
    s = x.std()
    return (x - x.mean()) / (s if s > 0 else 1.0)


class OffsetEstimate(NamedTuple):
    """:func:`time_offset_scan`'s answer.

    Attributes
    ----------
    offset : float
        Seconds to add to a time of stream a to get the time of stream b.
    correlation : float
        Pearson correlation of the two profiles over their overlap at that offset, in [-1, 1].
    runner_up : float
        The best correlation at offsets at least ``separation`` seconds from it (-1 when there
        is none): a correlation that stands out from every other alignment makes the offset
        trustworthy, one that another alignment nearly matches does not.
    overlap_s : float
        Seconds of overlap at that offset.
    """

    offset: float
    correlation: float
    runner_up: float
    overlap_s: float

    @property
    def confidence(self) -> float:
        """``(correlation - runner_up) / (1 - runner_up)`` in [0, 1]: 0 when another alignment
        is as good, 1 when the match is perfect and unique."""
        return float(np.clip((self.correlation - self.runner_up)
                             / max(1.0 - self.runner_up, 1e-12), 0.0, 1.0))


def _pearson(x, y) -> float:
    x, y = x - x.mean(), y - y.mean()          # (sums, not BLAS dots: no thread start-up)
    d = np.sqrt(np.sum(x * x) * np.sum(y * y))
    return float(np.clip(np.sum(x * y) / d, -1.0, 1.0)) if d > 0 else -1.0


def time_offset_scan(t_a, motion_a, t_b, motion_b, *, min_overlap: float = 0.5,
                     max_offset: float | None = None, center: float = 0.0,
                     separation: float = 0.5) -> OffsetEstimate:
    """The offset ``d`` with ``b(t + d) ~ a(t)`` by cross-correlation of two motion profiles.

    Parameters
    ----------
    t_a, motion_a, t_b, motion_b : arrays
        Two motion profiles, each on its own uniform grid of the same step (as returned by
        :func:`coupling_motion` and :func:`pose_motion`); the clocks may differ by any amount.
    min_overlap : float
        Only lags where the profiles overlap by this fraction of the shorter one count.
    max_offset : float, optional
        Only offsets within ``center`` +- ``max_offset`` seconds count.
    separation : float
        Offsets at least this far from the best one give :attr:`OffsetEstimate.runner_up`.

    The correlation at each lag is Pearson's over the overlap, from sums computed by FFT;
    lags whose overlap has (numerically) no variance are left out, and the best lag's
    correlation is recomputed directly, so it lies in [-1, 1].
    """
    from scipy.signal import correlate

    ta, tb = np.asarray(t_a, dtype=np.float64), np.asarray(t_b, dtype=np.float64)
    a, b = _standardise(np.asarray(motion_a, float)), _standardise(np.asarray(motion_b, float))
    if len(a) < 4 or len(b) < 4:
        raise InputError(f"expected motion profiles of at least 4 samples, got {len(a)} and "
                         f"{len(b)}")
    step = ta[1] - ta[0]
    ones_a, ones_b = np.ones(len(a)), np.ones(len(b))

    def corr(x, y):
        return correlate(x, y, mode="full", method="fft")

    n = np.rint(corr(ones_b, ones_a))
    s_ab, s_a, s_b = corr(b, a), corr(ones_b, a), corr(b, ones_a)
    s_aa, s_bb = corr(ones_b, a * a), corr(b * b, ones_a)
    lags = np.arange(-(len(a) - 1), len(b))
    ok = n >= max(4, min_overlap * min(len(a), len(b)))
    offsets = tb[0] - ta[0] + lags * step
    if max_offset is not None:
        ok &= np.abs(offsets - center) <= max_offset
    if not ok.any():
        raise InputError("expected the two streams to overlap in time, got no lag with enough "
                         "overlap")
    m = np.maximum(n, 1)
    va = np.maximum(s_aa - s_a ** 2 / m, 0)
    vb = np.maximum(s_bb - s_b ** 2 / m, 0)
    # the sums carry FFT round-off of about 1e-12 of the totals: an overlap whose variance is
    # not well above that has no correlation to speak of
    floor = 1e-6 * np.maximum(m, 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = (s_ab - s_a * s_b / m) / np.sqrt(va * vb)
    r = np.where(ok & (va > floor) & (vb > floor), np.clip(r, -1.0, 1.0), -np.inf)
    k = int(np.argmax(r))
    if not np.isfinite(r[k]):
        return OffsetEstimate(float(offsets[k]), -1.0, -1.0, float(n[k] * step))

    def exact(j):
        lag = int(lags[j])
        i0, i1 = max(0, -lag), min(len(a), len(b) - lag)
        return _pearson(a[i0:i1], b[i0 + lag:i1 + lag])

    rk = exact(k)
    frac = 0.0
    if 0 < k < len(r) - 1 and np.isfinite(r[k - 1]) and np.isfinite(r[k + 1]):
        lo, hi = exact(k - 1), exact(k + 1)
        den = lo - 2 * rk + hi
        if den < 0:
            frac = float(np.clip(0.5 * (lo - hi) / den, -0.5, 0.5))
    far = np.abs(lags - lags[k]) * step >= separation
    rr = r[far & np.isfinite(r)]
    runner = float(rr.max()) if rr.size else -1.0
    return OffsetEstimate(float(offsets[k] + frac * step), rk, runner, float(n[k] * step))


def estimate_time_offset(t_a, motion_a, t_b, motion_b, *, min_overlap: float = 0.5,
                         max_offset: float | None = None) -> tuple[float, float]:
    """``(offset, correlation)`` of :func:`time_offset_scan`: the offset ``d`` with
    ``b(t + d) ~ a(t)`` (s, finer than the grid by parabolic interpolation) and the Pearson
    correlation at it, in [-1, 1] (below about 0.5 the offset is doubtful)."""
    e = time_offset_scan(t_a, motion_a, t_b, motion_b, min_overlap=min_overlap,
                         max_offset=max_offset)
    return e.offset, e.correlation


def log_profile(motion, floor: float = PROFILE_FLOOR):
    """``log(max(motion, floor * q99))``: a motion profile for :func:`estimate_time_offset`.

    The couplings' rate of change and the reference's speed are different functions of the
    same progress along each move; their ratio varies within a move, which biases a
    correlation of the raw profiles by a few ms. The logarithm turns that ratio into an
    additive term small beside the steep rise from the floor (here ``floor`` times the 99th
    percentile) when a move starts and ends, which both streams share.
    """
    x = np.asarray(motion, dtype=np.float64)
    q = np.quantile(x, 0.99) if len(x) else 0.0
    return np.log(np.maximum(x, max(floor * q, np.finfo(float).tiny)))


def find_dwells(times, static, *, margin: float = MARGIN_S, min_duration: float = MIN_DWELL_S):
    """Intervals ``(start, end)`` (s) where ``static`` holds, trimmed by ``margin`` at both
    ends and at least ``min_duration`` long after trimming; an interval that touches the end of
    the data is left out (it may go on)."""
    t = np.asarray(times, dtype=np.float64)
    s = np.asarray(static, dtype=bool)
    if len(t) != len(s):
        raise InputError(f"expected one static flag per time, got {len(s)} for {len(t)}")
    if not len(s):
        return np.empty((0, 2))
    edges = np.diff(np.concatenate([[0], s.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    keep = ends < len(s) - 1
    a, b = t[starts[keep]] + margin, t[ends[keep]] - margin
    ok = b - a >= min_duration
    return np.column_stack([a[ok], b[ok]])


def _drift(x):
    """Norm of the difference of the means of the second and first halves of ``x`` (N, ...)."""
    h = len(x) // 2
    return float(np.linalg.norm(x[h:].mean(axis=0) - x[:h].mean(axis=0)))


def mean_pose(poses) -> np.ndarray:
    """The mean of poses (N, 4, 4): mean translation, chordal L2 mean rotation."""
    P = np.asarray(poses, dtype=np.float64)
    R = Rotation.from_matrix(P[:, :3, :3]).mean().as_matrix()
    return pose_from_rt(R, P[:, :3, 3].mean(axis=0))


def average_dwell(t_tracker, couplings, t_reference, reference_poses, a, b, time_offset):
    """Both streams averaged over the dwell ``[a, b]`` (tracker clock, s): ``(couplings,
    reference pose, tracker samples, reference samples)``, or None when either stream has
    fewer than 3 samples there or drifts within it (the means of its halves differ by more
    than ``COUPLING_DRIFT`` of the couplings' norm, ``TRANS_DRIFT_M`` or ``ROT_DRIFT_RAD``).
    The time stamps must be sorted."""
    tt, tr = t_tracker, t_reference
    i0, i1 = np.searchsorted(tt, a, "left"), np.searchsorted(tt, b, "right")
    j0 = np.searchsorted(tr, a + time_offset, "left")
    j1 = np.searchsorted(tr, b + time_offset, "right")
    if i1 - i0 < 3 or j1 - j0 < 3:
        return None
    Ci = np.asarray(couplings[i0:i1])
    Bj = np.asarray(reference_poses[j0:j1], dtype=np.float64)
    Cm = Ci.mean(axis=0)
    if _drift(Ci) > COUPLING_DRIFT * np.linalg.norm(Cm):
        return None
    h = len(Bj) // 2
    B1, B2 = mean_pose(Bj[:h]), mean_pose(Bj[h:])
    if np.linalg.norm(B1[:3, 3] - B2[:3, 3]) > TRANS_DRIFT_M or \
            Rotation.from_matrix(B1[:3, :3].T @ B2[:3, :3]).magnitude() > ROT_DRIFT_RAD:
        return None
    return Cm, mean_pose(Bj), int(i1 - i0), int(j1 - j0)


@dataclass(frozen=True, eq=False)
class DwellSet:
    """The dwells collected from two streams.

    Attributes
    ----------
    couplings : ndarray (K, n_source, n_sensor)
        Couplings averaged over each kept dwell.
    reference_poses : ndarray (K, 4, 4)
        Reference pose averaged over the same interval of the reference's clock (m).
    intervals : ndarray (K, 2)
        Each kept dwell in the tracker's clock (s).
    n_tracker_samples, n_reference_samples : ndarray (K,)
        Samples averaged per dwell.
    time_offset : float
        Reference clock minus tracker clock (s), from :func:`estimate_time_offset`.
    offset_correlation : float
    tracker_dwells, reference_dwells : int
        Dwells found in each stream alone.
    dropped : dict
        Dwells of the tracker not kept: the reference moved within them or within the kept
        part failed a drift test (``moved``; a tracker that moved within a reference dwell
        shows as fewer ``tracker_dwells``), or the reference has no poses there
        (``no_reference``).
    """

    couplings: np.ndarray
    reference_poses: np.ndarray
    intervals: np.ndarray
    n_tracker_samples: np.ndarray
    n_reference_samples: np.ndarray
    time_offset: float
    offset_correlation: float
    tracker_dwells: int
    reference_dwells: int
    dropped: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.intervals)

    def stats(self) -> dict:
        d = self.intervals[:, 1] - self.intervals[:, 0] if len(self) else np.zeros(0)
        return {"found": len(self), "tracker_dwells": int(self.tracker_dwells),
                "reference_dwells": int(self.reference_dwells),
                "dropped_moved": int(self.dropped.get("moved", 0)),
                "dropped_no_reference": int(self.dropped.get("no_reference", 0)),
                "duration_s_mean": float(d.mean()) if len(d) else None,
                "tracker_samples_mean": (float(self.n_tracker_samples.mean()) if len(self)
                                         else None),
                "reference_samples_mean": (float(self.n_reference_samples.mean()) if len(self)
                                           else None),
                "thresholds": thresholds()}


def thresholds() -> dict:
    """The static and drift thresholds, for the dataset's metadata."""
    return {"coupling_rate_per_s": COUPLING_RATE_STATIC, "speed_m_per_s": SPEED_STATIC,
            "rotation_speed_rad_per_s": float(ROTATION_SPEED_STATIC),
            "baseline_s": BASELINE_S, "margin_s": MARGIN_S, "min_dwell_s": MIN_DWELL_S,
            "coupling_drift": COUPLING_DRIFT, "trans_drift_m": TRANS_DRIFT_M,
            "rot_drift_rad": float(ROT_DRIFT_RAD)}


def collect_dwells(t_tracker, couplings, t_reference, reference_poses, *,
                   time_offset: float | None = None, max_offset: float | None = None) -> DwellSet:
    """Synchronise two streams and average both over the dwells where both are static.

    Parameters
    ----------
    t_tracker : array (N,)
        Tracker clock (s) of each coupling sample.
    couplings : array (N, n_source, n_sensor)
    t_reference : array (M,)
        Reference clock (s) of each reference pose.
    reference_poses : array (M, 4, 4)
        Reference poses (m).
    time_offset : float, optional
        Known offset (reference clock minus tracker clock); estimated when None.
    max_offset : float, optional
        Bound of the offset search (s).
    """
    tt = _check_times(t_tracker, "t_tracker")
    tr = _check_times(t_reference, "t_reference")
    C = np.asarray(couplings)
    B = np.asarray(reference_poses, dtype=np.float64)
    ga, rate = coupling_motion(tt, C)
    gb, v, w = pose_motion(tr, B)
    corr = float("nan")
    if time_offset is None:
        time_offset, corr = estimate_time_offset(ga, log_profile(rate), gb,
                                                 log_profile(v + LEVER_M * w),
                                                 max_offset=max_offset)
    static_a = rate < COUPLING_RATE_STATIC
    static_b = (v < SPEED_STATIC) & (w < ROTATION_SPEED_STATIC)
    n_a = len(find_dwells(ga, static_a))
    n_b = len(find_dwells(gb, static_b))
    # the reference's static flag on the tracker's grid; no reference there = not static
    gbt = ga + time_offset
    inside = (gbt >= gb[0]) & (gbt <= gb[-1])
    sb = np.interp(gbt, gb, static_b.astype(float)) > 0.999
    tracker_iv = find_dwells(ga, static_a)
    both = find_dwells(ga, static_a & sb & inside)
    out_C, out_B, keep, n_ca, n_ba = [], [], [], [], []
    moved = 0
    for a, b in both:                   # (a dwell failing a drift test counts below)
        got = average_dwell(tt, C, tr, B, a, b, time_offset)
        if got is None:
            continue
        out_C.append(got[0])
        out_B.append(got[1])
        keep.append((a, b))
        n_ca.append(got[2])
        n_ba.append(got[3])
    # every dwell of the tracker is kept, or dropped because the reference moved in it (or
    # within the kept part), or because the reference has no poses there
    kept = np.array(keep, dtype=np.float64).reshape(len(keep), 2)
    no_ref = 0
    for a, b in tracker_iv:
        if np.any((kept[:, 0] < b) & (kept[:, 1] > a)):
            continue
        if a + time_offset < tr[0] or b + time_offset > tr[-1]:
            no_ref += 1
        else:
            moved += 1
    shape = C.shape[1:]
    return DwellSet(couplings=np.array(out_C).reshape(len(out_C), *shape),
                    reference_poses=np.array(out_B).reshape(len(out_B), 4, 4),
                    intervals=np.array(keep, dtype=np.float64).reshape(len(keep), 2),
                    n_tracker_samples=np.array(n_ca, dtype=np.int64),
                    n_reference_samples=np.array(n_ba, dtype=np.int64),
                    time_offset=float(time_offset), offset_correlation=corr,
                    tracker_dwells=n_a, reference_dwells=n_b,
                    dropped={"moved": moved, "no_reference": no_ref})


def coverage(positions, rotations_or_poses, box, *, cells: int = 4) -> dict:
    """How well collected poses cover a working volume and orientations.

    Parameters
    ----------
    positions : array (K, 3)
        Sensor positions in the tracker's frame (m).
    rotations_or_poses : array (K, 4, 4) or (K, 3, 3)
        The reference's poses (the hand-eye fit's rotations).
    box : array (2, 3)
        Lower and upper corner of the working volume (m).
    cells : int
        The box is split into ``cells`` ** 3 equal cells.

    Returns
    -------
    dict
        ``volume_coverage_pct`` (cells holding at least one position, in %), ``outside``
        (positions outside the box), ``orientation_spread_deg`` (RMS angle from the mean
        rotation), ``rotation_diversity_ok`` and ``rotation_second_axis_deg``
        (:func:`openemt.geometry.rotation_diversity`: the hand-eye fit needs rotations about two
        axes).
    """
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    lo, hi = np.asarray(box, dtype=np.float64)
    out = {"n_poses": len(p), "volume_coverage_pct": 0.0, "outside": 0,
           "orientation_spread_deg": None, "rotation_diversity_ok": False,
           "rotation_second_axis_deg": None}
    if not len(p):
        return out
    u = (p - lo) / (hi - lo)
    good = np.all(np.isfinite(u), axis=1)
    inside = good & np.all((u >= 0) & (u <= 1), axis=1)
    idx = np.minimum((u[inside] * cells).astype(int), cells - 1)
    filled = len({tuple(i) for i in idx})
    out["volume_coverage_pct"] = 100.0 * filled / cells ** 3
    out["outside"] = int((~inside).sum())
    M = np.asarray(rotations_or_poses, dtype=np.float64)
    rot = Rotation.from_matrix(M[:, :3, :3])
    ang = (rot * rot.mean().inv()).magnitude()
    out["orientation_spread_deg"] = float(np.degrees(np.sqrt(np.mean(ang ** 2))))
    if len(M) >= 2:
        d = rotation_diversity(M)
        out["rotation_diversity_ok"] = bool(d.ok)
        out["rotation_second_axis_deg"] = float(d.second_deg)
    return out
