"""The real-time chain: backend -> demodulation -> warm-started LM solve -> optional correction
-> OpenIGTLink, log, per-sample status and distortion flag.

The solver is injected: any callable ``solver(couplings (N, n_so, n_se) real, initial)``
returning an object with ``poses (N, 4, 4)``, ``pose_vectors (N, 6)``, ``status (N,)`` and
``residual (N,)`` (the :class:`openemt.solve.SolveResult` fields). ``initial`` is either
``(N, 6)`` pose vectors (warm start from the last valid pose) or the string ``"kim18"`` when no
valid pose is known yet. The default wraps :func:`openemt.solve.solve_lm`.
"""

from __future__ import annotations

import collections
import time
from dataclasses import dataclass, field

import numpy as np

from .._constants import OUTPUT_RATE_HZ
from .._errors import InputError
from ..signal import Demodulator
from ..solve import Status, solve_lm

__all__ = ["TrackLog", "TrackStep", "TrackSummary", "TrackingPipeline", "lm_solver"]

_CONVERGED = int(Status.CONVERGED)


def lm_solver(model, *, hemisphere="+x", **kwargs):
    """The default solver callable: :func:`openemt.solve.solve_lm` on ``model``.

    ``hemisphere`` only matters while (re)acquiring with the closed-form start; afterwards
    each sample starts from the previous valid pose.
    """
    # warm starts never use the closed form; handing solve_lm a ready concentric model skips
    # re-deriving it on every call (a fixed cost that dominates one-sample solves)
    conc = None
    if model.n_source == 3 and model.n_sensor == 3 and "concentric_model" not in kwargs:
        conc = model.replace(L_so=np.zeros((3, 3)), L_se=np.zeros((3, 3)))

    def solve(C, initial):
        if conc is not None and not isinstance(initial, str):
            return solve_lm(C, model, initial=initial, hemisphere=hemisphere,
                            concentric_model=conc, **kwargs)
        return solve_lm(C, model, initial=initial, hemisphere=hemisphere, **kwargs)

    return solve


def _serial(fn, *args):
    """Call ``fn`` with numba's parallel regions on this thread limited to one thread.

    A live chunk holds a handful of samples; waking a thread pool for them costs far more
    (milliseconds on a busy machine) than the solve itself (~0.1 ms per sample).
    """
    try:
        import numba
    except ImportError:  # pragma: no cover
        return fn(*args)
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        return fn(*args)
    finally:
        numba.set_num_threads(before)


@dataclass(frozen=True, eq=False)
class TrackStep:
    """Outputs of one processed chunk (N samples, possibly 0).

    Attributes
    ----------
    times : ndarray, shape (N,)
        Sample time (s from the first raw sample; frame centres).
    couplings : ndarray, shape (N, n_source, n_sensor), complex
        Demodulated couplings (real = coupling, imaginary = quadrature).
    poses : ndarray, shape (N, 4, 4)
        Sensor poses (m), corrected if a correction is configured.
    pose_vectors : ndarray, shape (N, 6)
        ``[x, y, z, rx, ry, rz]`` of ``poses``.
    status : ndarray, shape (N,), int8
        :class:`openemt.solve.Status` codes of the solve.
    residual : ndarray, shape (N,)
        Solver residual (ILEMT resnorm).
    distortion : ndarray, shape (N,)
        Quadrature ratio ``||Im C|| / ||C||``.
    distorted : ndarray, shape (N,), bool
        ``distortion > distortion_threshold``.
    t_ready : float
        ``time.perf_counter()`` when the demodulated couplings were available.
    """

    times: np.ndarray
    couplings: np.ndarray
    poses: np.ndarray
    pose_vectors: np.ndarray
    status: np.ndarray
    residual: np.ndarray
    distortion: np.ndarray
    distorted: np.ndarray
    t_ready: float = 0.0

    def __len__(self) -> int:
        return self.times.shape[0]


@dataclass(frozen=True)
class TrackSummary:
    """What a run did (JSON-ready via :meth:`to_dict`)."""

    n_samples: int
    signal_seconds: float
    wall_seconds: float
    status_counts: dict
    distorted_fraction: float
    latency_ms_p50: float | None
    latency_ms_p99: float | None
    igtl: dict | None = None
    truth: dict | None = None
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = {"n_samples": self.n_samples, "signal_seconds": self.signal_seconds,
             "wall_seconds": self.wall_seconds, "status_counts": self.status_counts,
             "distorted_fraction": self.distorted_fraction,
             "latency_ms_p50": self.latency_ms_p50, "latency_ms_p99": self.latency_ms_p99,
             "igtl": self.igtl, "truth": self.truth}
        d.update(self.extra)
        return d


class TrackLog:
    """Accumulates per-sample outputs; writes HDF5 (``.h5``/``.hdf5``) or CSV (``.csv``).

    HDF5 datasets: ``times`` (s), ``poses`` (N, 4, 4) m, ``pose_vectors`` (N, 6) m/rad,
    ``status`` int8, ``residual``, ``distortion``, ``distorted`` bool, ``couplings`` complex
    (N, n_source, n_sensor); attrs ``format = "openemt-track"``, ``version = 1``.
    CSV columns: ``time_s, x_m, y_m, z_m, rx_rad, ry_rad, rz_rad, status, residual,
    distortion, distorted``.
    """

    _KEYS = ("times", "poses", "pose_vectors", "status", "residual", "distortion",
             "distorted", "couplings")

    def __init__(self):
        self._parts = {k: [] for k in self._KEYS}

    def append(self, step: TrackStep) -> None:
        if len(step):
            for k in self._KEYS:
                self._parts[k].append(getattr(step, k))

    def arrays(self) -> dict:
        return {k: (np.concatenate(v) if v else np.empty(0)) for k, v in self._parts.items()}

    def write(self, path) -> None:
        from pathlib import Path

        from ..io import atomic_path

        path = Path(path)
        a = self.arrays()
        suffix = path.suffix.lower()
        if suffix in (".h5", ".hdf5"):
            import h5py

            with atomic_path(path, suffix=".h5") as tmp, h5py.File(tmp, "w") as f:
                f.attrs["format"] = "openemt-track"
                f.attrs["version"] = 1
                for k, v in a.items():
                    f.create_dataset(k, data=v)
        elif suffix == ".csv":
            n = len(a["times"])
            pv = a["pose_vectors"].reshape(n, 6)
            table = np.column_stack([a["times"], pv, a["status"], a["residual"],
                                     a["distortion"], a["distorted"].astype(int)])
            header = ("time_s,x_m,y_m,z_m,rx_rad,ry_rad,rz_rad,status,residual,distortion,"
                      "distorted")
            with atomic_path(path, suffix=".csv") as tmp:
                np.savetxt(tmp, table, delimiter=",", header=header, comments="",
                           fmt=["%.6f"] + ["%.9g"] * 6 + ["%d", "%.6g", "%.6g", "%d"])
        else:
            raise InputError(f"expected a log file ending in .h5, .hdf5 or .csv, got "
                             f"{str(path)!r}")


class TrackingPipeline:
    """Raw samples to poses, live.

    Parameters
    ----------
    backend : Backend
        Source of raw chunks (:mod:`openemt.live`).
    model : DipoleModel
        Model for the default solver (ignored when ``solver`` is given).
    solver : callable, optional
        See the module docstring; default :func:`lm_solver` (``model``, ``hemisphere``).
    hemisphere : str
        Hemisphere for (re)acquisition with the closed-form start.
    correction : ndarray, shape (4, 4), optional
        Linear position correction (docs/paper-procedure.md#applying-correction) applied to valid poses.
    output_rate, window, phase
        Demodulator settings (:class:`openemt.signal.Demodulator`).
    distortion_threshold : float
        Quadrature ratio above which a sample is flagged as distorted.
    igtl : IgtlServer, optional
        Receives every ``igtl_every``-th valid pose, and every ``status_every`` samples a
        STRING message on device ``<device_name>Status`` such as
        ``"CONVERGED distorted=0 quadrature=1.2e-05"`` (the latest sample), which Slicer shows
        as a text node.
    log : TrackLog, optional
    serial_small_batches : bool
        Solve chunks of fewer than 256 samples with numba's parallel regions limited to this
        thread (see ``openemt bench track``'s baseline for why).
    """

    def __init__(self, backend, model=None, *, solver=None, hemisphere="+x", correction=None,
                 output_rate: float = OUTPUT_RATE_HZ, window: str = "hann", phase=None,
                 distortion_threshold: float = 1e-3, igtl=None, log: TrackLog | None = None,
                 igtl_every: int = 1, status_every: int = 150,
                 serial_small_batches: bool = True):
        if solver is None:
            if model is None:
                raise InputError("expected a `model` or a `solver`, got neither")
            solver = lm_solver(model, hemisphere=hemisphere)
        self.backend = backend
        self.solver = solver
        self.demod = Demodulator(backend.layout, output_rate=output_rate, window=window,
                                 phase=phase)
        if correction is not None:
            L = np.asarray(correction, dtype=np.float64)
            if L.shape != (4, 4) or not np.all(np.isfinite(L)):
                raise InputError(f"expected a finite (4, 4) `correction`, got shape {L.shape}")
            correction = L
        self.correction = correction
        self.distortion_threshold = float(distortion_threshold)
        self.igtl = igtl
        self.log = log
        self.igtl_every = max(1, int(igtl_every))
        self.status_every = max(1, int(status_every))
        self.serial_small_batches = bool(serial_small_batches)
        self._last = None             # last valid pose vector
        self._n_out = 0
        self._status_counts: dict = {}
        self._n_distorted = 0
        self._latency = collections.deque(maxlen=200_000)   # bounded for endless runs
        self._err_n, self._err_ss, self._err_max = 0, 0.0, 0.0
        self._pending: list = []
        self._n_pending = 0
        self._truth_known = backend.truth_poses(np.zeros(1)) is not None

    def _solve(self, C):
        n = C.shape[0]
        initial = "kim18" if self._last is None else np.tile(self._last, (n, 1))
        if self.serial_small_batches and n < 256:
            res = _serial(self.solver, C, initial)
        else:
            res = self.solver(C, initial)
        poses = np.asarray(res.poses, dtype=np.float64)
        vecs = np.asarray(res.pose_vectors, dtype=np.float64)
        status = np.asarray(res.status).astype(np.int8)
        ok = status == _CONVERGED
        if np.any(ok):
            self._last = vecs[np.flatnonzero(ok)[-1]].copy()
        elif n:
            self._last = None         # lost: re-acquire with the closed form
        return poses, vecs, status, np.asarray(res.residual, dtype=np.float64)

    def _correct(self, poses, vecs, status):
        if self.correction is None:
            return poses, vecs
        from ..correct import apply_linear_correction
        from ..geometry import vector_from_pose

        ok = status == _CONVERGED
        if not np.any(ok):
            return poses, vecs
        poses = poses.copy()
        poses[ok, :3, 3] = apply_linear_correction(self.correction, poses[ok, :3, 3])
        return poses, vector_from_pose(poses)

    def step(self) -> TrackStep | None:
        """Read and process one backend chunk; None at the end of the data."""
        chunk = self.backend.read()
        if chunk is None:
            return None
        d = self.demod.process(chunk)
        t_ready = time.perf_counter()
        n = len(d)
        if n == 0:
            e = np.empty(0)
            return TrackStep(d.times, d.couplings, np.empty((0, 4, 4)), np.empty((0, 6)),
                             np.empty(0, np.int8), e, e, np.empty(0, bool), t_ready)
        poses, vecs, status, resid = self._solve(d.in_phase)
        poses, vecs = self._correct(poses, vecs, status)
        ratio = d.distortion_ratio()
        flag = ratio > self.distortion_threshold
        if self.igtl is not None:
            epoch = self.backend.t0_epoch
            pick = (status == _CONVERGED) & ((self._n_out + np.arange(n)) % self.igtl_every == 0)
            if np.any(pick):
                self.igtl.send_poses(poses[pick], epoch + d.times[pick], t_ready=t_ready)
            self._latency.extend([time.perf_counter() - t_ready] * n)
            if (self._n_out + n) // self.status_every > self._n_out // self.status_every:
                self._send_status(int(status[-1]), bool(flag[-1]), float(ratio[-1]),
                                  epoch + d.times[-1])
        else:
            self._latency.extend([time.perf_counter() - t_ready] * n)
        step = TrackStep(d.times, d.couplings, poses, vecs, status, resid, ratio, flag, t_ready)
        self._account(step)
        return step

    def _send_status(self, code, distorted, ratio, timestamp):
        import pyigtl

        try:
            name = Status(code).name
        except ValueError:  # pragma: no cover - a custom solver's own code
            name = str(code)
        device = (self.igtl.device_name + "Status")[:20]
        self.igtl.send_message(pyigtl.StringMessage(
            f"{name} distorted={int(distorted)} quadrature={ratio:.2e}", timestamp=timestamp,
            device_name=device))

    def _account(self, step: TrackStep):
        self._n_out += len(step)
        codes, counts = np.unique(step.status, return_counts=True)
        for c, k in zip(codes.tolist(), counts.tolist()):
            self._status_counts[c] = self._status_counts.get(c, 0) + k
        self._n_distorted += int(np.count_nonzero(step.distorted))
        if self.log is not None:
            self.log.append(step)
        ok = step.status == _CONVERGED
        if self._truth_known and np.any(ok):
            self._pending.append((step.times[ok], step.poses[ok, :3, 3]))
            self._n_pending += int(ok.sum())
            if self._n_pending >= 1500:       # compare with the truth in batches (cheaper)
                self._flush_truth()

    def _flush_truth(self):
        if not self._pending:
            return
        t = np.concatenate([p[0] for p in self._pending])
        xyz = np.concatenate([p[1] for p in self._pending])
        self._pending, self._n_pending = [], 0
        truth = self.backend.truth_poses(t)
        if truth is None:
            self._truth_known = False
            return
        err = np.linalg.norm(xyz - truth[:, :3, 3], axis=1)
        self._err_n += err.size
        self._err_ss += float(np.sum(err ** 2))
        self._err_max = max(self._err_max, float(err.max()))

    def run(self, duration: float | None = None, *, max_steps: int | None = None,
            stop=None) -> TrackSummary:
        """Process chunks until the data end, ``duration`` seconds of signal, ``max_steps``
        chunks, ``stop()`` returning True, or Ctrl-C (a clean stop, not an error)."""
        t_wall = time.perf_counter()
        steps = 0
        fs_out = self.demod.output_rate
        try:
            while True:
                if duration is not None and self._n_out >= duration * fs_out:
                    break
                if max_steps is not None and steps >= max_steps:
                    break
                if stop is not None and stop():
                    break
                if self.step() is None:
                    break
                steps += 1
        except KeyboardInterrupt:
            pass
        return self.summary(time.perf_counter() - t_wall)

    def summary(self, wall_seconds: float = float("nan")) -> TrackSummary:
        """Summary of everything processed so far."""
        names = {int(s): s.name for s in Status}
        counts = {names.get(c, str(c)): k for c, k in sorted(self._status_counts.items())}
        self._flush_truth()
        lat = np.asarray(self._latency) * 1e3
        truth = None
        if self._err_n:
            truth = {"position_error_mm_rms": 1e3 * float(np.sqrt(self._err_ss / self._err_n)),
                     "position_error_mm_max": 1e3 * self._err_max}
        igtl = None
        if self.igtl is not None:
            igtl = dict(self.igtl.stats(), port=self.igtl.port,
                        device_name=self.igtl.device_name)
            sl = self.igtl.latencies() * 1e3
            if sl.size:
                igtl["send_latency_ms_p50"] = float(np.percentile(sl, 50))
                igtl["send_latency_ms_p99"] = float(np.percentile(sl, 99))
        n = self._n_out
        return TrackSummary(
            n_samples=n, signal_seconds=n / self.demod.output_rate, wall_seconds=wall_seconds,
            status_counts=counts, distorted_fraction=(self._n_distorted / n) if n else 0.0,
            latency_ms_p50=float(np.percentile(lat, 50)) if lat.size else None,
            latency_ms_p99=float(np.percentile(lat, 99)) if lat.size else None,
            igtl=igtl, truth=truth)
