"""The planar (Anser-style) part of ``openemt bench speed``: the 5-DOF finite-coil solver.

Data: the built-in ``anser`` board (8 square spiral coils, 8 mm sensor coil; docs/planar.md),
unit gains (couplings in tesla for 1 A, ~1e-8..1e-5), a smooth sensor path sampled at 1 kHz
60-160 mm above the board (about 0.2 m/s and 1 rad/s), white noise at the given SNR.

- ``planar_lm_tracking``: the board solver of :func:`openemt.solve.prepare` (prepared once,
  :func:`openemt.solve.solve_planar`), warm-started from the
  previous sample, one numba thread, process CPU time, best of the repeats after a warm-up;
- baseline: ``scipy.optimize.least_squares`` per pose ('trf', 2-point finite differences;
  the approach of the Anser software, Jaeger et al. 2017) on the same model in its reference
  implementation (the board's traces as magpylib polylines, the project's finite-coil truth),
  position + axis angles (theta, phi), started from the previous true pose, tolerances 1e-12;
  ``planar_vs_scipy_ratio`` compares with it. ``planar_vs_scipy_compiled_model_ratio`` gives
  the ratio to the same scipy loop calling the compiled segment kernel instead (the part of
  the speed-up that comes from the solver rather than from the kernel).
- ``board_6dof_*``: the ``anser-6dof`` board read by a two-coil 6-DOF sensor, tracked by the
  solver of :func:`openemt.solve.prepare` (the compiled LM kernels on the board's packed form,
  :func:`board_6dof_speed`); ``board_6dof_vs_5dof_tracking_ratio`` compares it with
  ``planar_lm_tracking`` in the same run, ``board_6dof_interface_lm_*`` gives the
  interface-level LM on the same couplings (the solver it replaced) and how far the answers of
  the two are apart. What bounds the rate, measured in the same run
  (:func:`board_6dof_ceiling`): one evaluation of the sensor by the segment kernel with and
  without derivatives (``board_6dof_evaluation_us``), the rate if a pose cost only the two
  evaluations a tracked pose needs at least (``board_6dof_ceiling_poses_per_s``), and the rate
  if those two evaluations did nothing but read the segments and take the square roots and the
  division of the exact formula (``board_6dof_floor_*``, two roots per segment as the kernel,
  or one if each vertex's distance were shared by its two segments).
- ``planar_live_*``: the live pipeline of ``openemt track`` with a board calibration
  (:func:`planar_live_speed`; docs/planar.md#tracking-live): the shipped ``anser`` tracker's raw
  samples simulated beforehand, then demodulated and solved chunk by chunk (640 samples = 10
  poses) as fast as possible; ``planar_live_realtime_factor`` is signal seconds per wall-clock
  second (``_cpu``: per CPU second), the latencies run from the demodulated couplings of a chunk
  to the end of its processing.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._compile_notice import serial_threads
from ..field._segments import _VECTOR
from ._timing import best_time

__all__ = ["board_6dof_ceiling", "board_6dof_speed", "planar_live_speed", "planar_speed",
           "planar_trajectory"]


def planar_trajectory(n, rate_hz=1000.0):
    """Positions (n, 3) and unit axes (n, 3) of a smooth path over the board."""
    t = np.arange(n)[:, None] / rate_hz
    pos = np.array([0.0, 0.0, 0.11]) + np.array([0.06, 0.06, 0.05]) * np.sin(
        2 * np.pi * np.array([0.5, 0.7, 0.9]) * t + [0.0, 1.0, 2.0])
    ang = 0.5 * np.sin(2 * np.pi * np.array([0.3, 0.23]) * t + [0.5, 1.5])
    th, ph = np.pi - 0.6 + ang[:, 0], ang[:, 1] * 3
    axes = np.column_stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
    return pos, axes


def planar_speed(samples=20000, baseline_samples=30, repeats=3, snr_db=80.0, seed=0) -> dict:
    """Poses per second of the planar tracking solver and its ratio to per-pose scipy."""
    from scipy.optimize import least_squares

    from ..board import BoardModel
    from ..solve import Status, prepare

    n, nb = int(samples), int(baseline_samples)
    with serial_threads():
        model = BoardModel.from_board("anser")
        P, U = planar_trajectory(n)
        C = model.coupling_points(P, U)
        rng = np.random.default_rng(seed)
        sigma = np.sqrt(np.mean(C ** 2, axis=1)) * 10 ** (-snr_db / 20)
        C = C + sigma[:, None] * rng.normal(size=C.shape)
        solver = prepare(model, initial="track")            # the factory's board solver
        solver(C[:20])                                      # warm-up: load the kernels
        dt, _, res = best_time(lambda: solver(C), repeats)

        import magpylib

        S, off = model.segments, model.segment_offsets
        lines = [magpylib.current.Polyline(current=1.0, vertices=np.vstack(
            [S[off[i]:off[i + 1], 0], S[off[i + 1] - 1, 1]])) for i in range(model.n_coils)]
        half = model.sensor_length / (2 * np.sqrt(3.0))

        def axis(x):
            return np.array([np.sin(x[3]) * np.cos(x[4]), np.sin(x[3]) * np.sin(x[4]),
                             np.cos(x[3])])

        def coupling_ref(x):
            u = axis(x)
            B = magpylib.getB(lines, np.array([x[:3] - half * u, x[:3] + half * u]))
            return model.gains * (B.mean(axis=1) @ u)

        def coupling_compiled(x):
            return model.coupling_points(x[None, :3], axis(x)[None])[0]

        def baseline(fun):
            out = np.empty((nb, 3))
            for k in range(nb):
                j = max(k - 1, 0)
                x0 = np.r_[P[j], np.arccos(np.clip(U[j, 2], -1, 1)), np.arctan2(U[j, 1], U[j, 0])]
                scale = 1.0 / np.linalg.norm(C[k])
                out[k] = least_squares(lambda x, k=k, s=scale: (fun(x) - C[k]) * s, x0,
                                       xtol=1e-12, ftol=1e-12, gtol=1e-12).x[:3]
            return out

        model_diff = float(np.abs(coupling_ref(np.r_[P[0], 2.5, 0.3])
                                  - coupling_compiled(np.r_[P[0], 2.5, 0.3])).max()
                           / np.abs(C[0]).max())
        dt_b, _, base = best_time(lambda: baseline(coupling_ref), 1)
        dt_c, _, base_c = best_time(lambda: baseline(coupling_compiled), 1)
    live = planar_live_speed(seconds=min(3.0, n / 1500.0), seed=seed)
    six = board_6dof_speed(samples=min(n, 5000), repeats=repeats, snr_db=snr_db, seed=seed)
    rate = n / dt
    rate_b = nb / dt_b
    rate_c = nb / dt_c
    ok = res.status == Status.CONVERGED
    err = np.linalg.norm(res.poses[ok, :3, 3] - P[ok], axis=1)
    diff = float(max(np.abs(res.poses[:nb, :3, 3] - base).max(),
                     np.abs(res.poses[:nb, :3, 3] - base_c).max()))
    return {
        "planar_samples": n, "planar_board": "anser", "planar_snr_db": snr_db,
        "planar_lm_tracking_poses_per_s": rate,
        "planar_lm_tracking_mean_iterations": float(res.iterations.mean()),
        "planar_lm_tracking_status_counts": res.status_counts(),
        "planar_lm_tracking_position_rms_error_m": float(np.sqrt(np.mean(err ** 2))),
        "planar_scipy_per_pose_poses_per_s": rate_b,
        "planar_vs_scipy_ratio": rate / rate_b,
        "planar_scipy_compiled_model_poses_per_s": rate_c,
        "planar_vs_scipy_compiled_model_ratio": rate / rate_c,
        "planar_reference_model_relative_diff": model_diff,
        "planar_max_position_diff_m": diff,
        **live, **six,
        "board_6dof_vs_5dof_tracking_ratio": six["board_6dof_lm_tracking_poses_per_s"] / rate,
        "planar_targets": {"planar_live_realtime_factor >= 1":
                           live["planar_live_realtime_factor"] >= 1,
                           "planar_lm_tracking_poses_per_s >= 10000": rate >= 1e4,
                           "planar_vs_scipy_ratio >= 200": rate / rate_b >= 200,
                           "planar_max_position_diff_m <= 1e-6": diff <= 1e-6},
    }


def board_6dof_speed(samples=5000, repeats=3, snr_db=80.0, seed=0) -> dict:
    """``board_6dof_*``: the built-in ``anser-6dof`` board (the Anser coils read by a sensor of
    two coils 60 degrees apart, unit gains) tracked along :func:`planar_trajectory` with a roll
    of +-60 degrees about the sensor axis, white noise at ``snr_db``, by the solver of
    :func:`openemt.solve.prepare` for the model (the compiled LM kernels), warm-started
    tracking, one numba thread, process CPU time, best of the repeats after a warm-up; and the
    interface-level LM (the registry's ``'model'`` entry) once on the same
    couplings: its rate, and the largest position and rotation differences of the samples
    both solvers call converged (and whether all statuses agree)."""
    from ..board import BoardModel
    from ..evaluate import error_summary, pose_error_magnitudes
    from ..geometry import pose_from_vector
    from ..simulate import add_noise, noise_sigma
    from ..solve import SOLVER_FAMILIES, SolveOptions, Status, pose_from_axis, prepare

    n = int(samples)
    with serial_threads():
        model = BoardModel.from_board("anser-6dof")
        pos, axes = planar_trajectory(n)
        roll = np.deg2rad(60.0) * np.sin(2 * np.pi * 0.4 * np.arange(n) / 1000.0)
        P, _ = pose_from_axis(pos, axes)
        P = P @ pose_from_vector(np.column_stack([np.zeros((n, 5)), roll]))
        C = model.coupling(P)
        C = add_noise(C, noise_sigma(C, snr_db=snr_db), np.random.default_rng(seed))
        solver = prepare(model, initial="track")
        solver(C[:20])                                      # warm-up: load the kernels
        dt, _, res = best_time(lambda: solver(C), repeats)
        # the interface-level LM: the registry's entry for models without a solver of their own
        interface = SOLVER_FAMILIES["model"](model, "lm", SolveOptions(initial="track"))[0]
        dt_i, _, res_i = best_time(lambda: interface(C), 1)
    both = (res.status == int(Status.CONVERGED)) & (res_i.status == int(Status.CONVERGED))
    dpos, drot = pose_error_magnitudes(res.poses[both], res_i.poses[both])
    ok = res.valid
    t, r = pose_error_magnitudes(res.poses[ok], P[ok])
    e = error_summary(t, r)
    return {"board_6dof_samples": n, "board_6dof_board": "anser-6dof",
            "board_6dof_solver": res.solver,
            "board_6dof_lm_tracking_poses_per_s": n / dt,
            "board_6dof_lm_tracking_mean_iterations": float(res.iterations.mean()),
            "board_6dof_lm_tracking_status_counts": res.status_counts(),
            "board_6dof_interface_lm_poses_per_s": n / dt_i,
            "board_6dof_interface_lm_status_counts": res_i.status_counts(),
            "board_6dof_vs_interface_lm_ratio": dt_i / dt,
            "board_6dof_vs_interface_lm_same_statuses": bool(np.array_equal(res.status,
                                                                            res_i.status)),
            "board_6dof_vs_interface_lm_max_position_diff_m": float(dpos.max(initial=0.0)),
            "board_6dof_vs_interface_lm_max_rotation_diff_deg": float(np.degrees(
                drot.max(initial=0.0))),
            "board_6dof_position_rms_error_mm": e["trans_rms_mm"],
            "board_6dof_rotation_rms_error_deg": e["rot_rms_deg"],
            **board_6dof_ceiling(model, P, repeats=repeats)}


@njit(cache=True, fastmath=_VECTOR)
def _roots_and_division(S, off, points, shared):
    """For each point, the sum over every coil's segments of ``1 / (|A| |B|)`` (two square
    roots and one division a segment, as the segment kernel), or with ``shared`` of
    ``1 / |A|`` over the segments' starts (one root and one division a segment, as if each
    vertex's distance served both its segments): the part of the exact segment formula no
    rewriting of its other operations removes, in the kernel's loop form (branch-free,
    the sums in vector lanes under the same ``fastmath`` flags)."""
    out = np.empty(points.shape[0])
    for p in range(points.shape[0]):
        rx, ry, rz = points[p, 0], points[p, 1], points[p, 2]
        acc = 0.0
        for i in range(off.shape[0] - 1):
            o = 0.0
            if shared:
                for s in range(off[i], off[i + 1]):
                    ax = S[s, 0, 0] - rx
                    ay = S[s, 0, 1] - ry
                    az = S[s, 0, 2] - rz
                    na = np.sqrt(ax * ax + ay * ay + az * az)
                    o += 1.0 / na if na > 0.0 else 0.0
            else:
                for s in range(off[i], off[i + 1]):
                    ax = S[s, 0, 0] - rx
                    ay = S[s, 0, 1] - ry
                    az = S[s, 0, 2] - rz
                    bx = S[s, 1, 0] - rx
                    by = S[s, 1, 1] - ry
                    bz = S[s, 1, 2] - rz
                    P = np.sqrt(ax * ax + ay * ay + az * az) * np.sqrt(bx * bx + by * by
                                                                       + bz * bz)
                    o += 1.0 / P if P > 0.0 else 0.0
            acc += o
        out[p] = acc
    return out


def board_6dof_ceiling(model, P, repeats=3) -> dict:
    """What bounds the 6-DOF board solver's rate on this machine, at the poses ``P`` of
    ``model`` (a :class:`~openemt.board.BoardModel`): the process CPU time of one evaluation
    of the sensor (its coils at every quadrature node, every segment) by the segment kernel the
    solvers run, with the derivatives a step needs and without (the residual the validity rule
    judges at the pose returned); the rate if each pose cost just one of each
    (``board_6dof_ceiling_poses_per_s``); and the same two evaluations reduced to reading the
    segments and taking the square roots and the division of the exact formula
    (:func:`_roots_and_division`, ``board_6dof_floor_*``). One numba thread, best of
    ``repeats``."""
    from ..field._segments import sensor_rule

    S, off, _ = model.packed()
    p, _, u = model._sensor_coils(P)                  # each sensor coil's centre and axis
    pts = p.reshape(-1, 3)
    axes = u.reshape(-1, 3)
    nodes, _ = sensor_rule(model.sensor_length)
    n = len(P)
    n_se = pts.shape[0] // n
    per_eval = n_se * len(nodes) * S.shape[0]        # segment-points of one evaluation
    # every quadrature node's point: what the kernel evaluates
    q = (pts[:, None, :] + nodes[None, :, None] * axes[:, None, :]).reshape(-1, 3)
    with serial_threads():
        times = {}
        for grad in (True, False):
            model.coupling_points(pts[:2], axes[:2], gradient=grad)
            times[grad] = best_time(lambda grad=grad: model.coupling_points(
                pts, axes, gradient=grad), repeats)[0] / n
        floor = {}
        for shared in (False, True):
            _roots_and_division(S, off, q[:2], shared)
            floor[shared] = best_time(lambda shared=shared: _roots_and_division(
                S, off, q, shared), repeats)[0] / (len(q) * S.shape[0])
    two = times[True] + times[False]
    return {
        "board_6dof_segment_points_per_evaluation": int(per_eval),
        "board_6dof_evaluation_us": {"with_derivatives": 1e6 * times[True],
                                     "without_derivatives": 1e6 * times[False]},
        "board_6dof_ceiling_poses_per_s": 1.0 / two,
        "board_6dof_floor_ns_per_segment_point": {"two_roots_one_division": 1e9 * floor[False],
                                                  "one_root_one_division": 1e9 * floor[True]},
        "board_6dof_floor_poses_per_s": {
            "two_roots_one_division": 1.0 / (2 * per_eval * floor[False]),
            "one_root_one_division": 1.0 / (2 * per_eval * floor[True])},
    }


def planar_live_speed(seconds: float = 3.0, seed: int = 0) -> dict:
    """Realtime factor and latency of the live pipeline with the shipped board tracker."""
    import os

    from ..live import (
        Backend,
        TrackingPipeline,
        example_tracker,
        read_tracker,
        tracker_backend,
        tracker_sensors,
    )

    spec = read_tracker(example_tracker("anser"))
    sim = tracker_backend(spec, "sim", realtime=False, duration=float(seconds), seed=seed)
    chunks = []
    while (x := sim.read()) is not None:
        chunks.append(x)

    class Recorded(Backend):
        layout = sim.layout

        def __init__(self):
            self._it = iter(chunks)

        def read(self):
            return next(self._it, None)

        def truth_poses(self, times):
            return sim.truth_poses(times)

    def run():
        pipe = TrackingPipeline(Recorded(), sensors=tracker_sensors(spec),
                                output_rate=spec.output_rate, window=spec.window)
        return pipe.run()

    run()                                               # warm-up: load the kernels
    cpu, wall, s = best_time(run, 1)
    return {"planar_live_signal_seconds": s.signal_seconds,
            "planar_live_realtime_factor": s.signal_seconds / wall,
            "planar_live_realtime_factor_cpu": s.signal_seconds / cpu,
            "planar_live_latency_ms_p50": s.latency_ms_p50,
            "planar_live_latency_ms_p99": s.latency_ms_p99,
            "planar_live_status_counts": s.status_counts,
            "planar_live_position_error_mm_rms": s.truth["position_error_mm_rms"],
            "planar_live_load_average": os.getloadavg()[0]}
