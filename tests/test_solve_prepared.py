"""The prepared LM solver (arguments checked and packed once) gives the results of
``solve_lm`` bit for bit, and the live pipeline built on it tracks as the plain ``solve_lm``
callable does, failures included."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from openemt.bench._memory import Memory
from openemt.bench._track import _spec
from openemt.geometry import pose_from_vector
from openemt.live import TrackingPipeline, TrackLog
from openemt.live._session import tracker_backend, tracker_sensors
from openemt.simulate import get_preset, truth_calibration
from openemt.solve import Status, solve_lm
from openemt.solve._prepared import PreparedLM


def _chunks(model, n_chunks=4, n=10, seed=0):
    """Noisy couplings along a short path, in chunks of ``n`` samples; a middle chunk has
    non-finite and zero couplings in it."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_chunks * n) / 1500.0
    v = np.tile([0.2, 0.03, -0.02, 0.1, -0.2, 0.3], (t.size, 1))
    v[:, 1] += 0.01 * np.sin(2 * np.pi * 2.0 * t)
    v[:, 5] += 0.2 * t
    C = model.coupling(pose_from_vector(v))
    C = C + 1e-6 * np.abs(C).max() * rng.standard_normal(C.shape)
    bad = (n_chunks // 2) * n + 3
    C[bad, 1, 2] = np.nan
    C[bad + 1] = 0.0
    C[bad + 2, 0, 0] = np.inf
    return [np.ascontiguousarray(C[i * n:(i + 1) * n]) for i in range(n_chunks)], v


def _same(a, b):
    np.testing.assert_array_equal(a.status, b.status)
    for f in ("poses", "pose_vectors", "residual", "relative_residual", "iterations"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)


@pytest.mark.parametrize("preset", ["concentric", "dipole-approx"])
def test_warm_starts_chunk_by_chunk_equal_solve_lm(preset):
    model = truth_calibration(preset).model
    chunks, v = _chunks(model)
    solver = PreparedLM(model, hemisphere="+x")
    last = v[0] + np.array([1e-3, -1e-3, 2e-3, 0.01, 0.0, -0.01])
    failed = 0
    for C in chunks:
        init = np.tile(last, (C.shape[0], 1))
        got = solver(C, init)                    # the compiled kernel directly
        _same(got, solve_lm(C, model, hemisphere="+x", initial=init))
        _same(got, solver.solve(C, init))
        ok = got.status == Status.CONVERGED
        failed += int(np.count_nonzero(~ok))
        last = got.pose_vectors[np.flatnonzero(ok)[-1]]
    assert failed == 3          # the three bad samples, flagged INVALID_INPUT, not solved


@pytest.mark.parametrize("initial", ["kim18", "track", "multistart"])
def test_named_starts_of_a_reused_solver(initial):
    """A solver that has served other calls (its cached constants and whitening filled for
    another size) answers a named start as a fresh one does, and finds the simulated poses."""
    model = truth_calibration("dipole-approx").model
    chunks, v = _chunks(model, n_chunks=3, n=8)
    C = np.concatenate(chunks)
    solver = PreparedLM(model, hemisphere="+x")
    solver(np.ascontiguousarray(C[::-1][:5]), initial)
    got = solver(C, initial)
    _same(got, PreparedLM(model, hemisphere="+x")(C, initial))
    ok = got.status == Status.CONVERGED
    assert np.count_nonzero(got.status == Status.INVALID_INPUT) == 3 and ok.sum() == len(C) - 3
    np.testing.assert_allclose(got.pose_vectors[ok, :3], v[ok, :3], atol=1e-5)


def test_one_prepared_solver_reused_for_many_sizes_and_hemispheres():
    model = get_preset("concentric").dipole
    C = np.concatenate(_chunks(model, n_chunks=2, n=40)[0])
    solver = PreparedLM(model, hemisphere=None)
    for n in (1, 7, 80, 3):               # the cached per-call constants grow and shrink
        init = np.tile([0.2, 0.03, -0.02, 0.1, -0.2, 0.3], (n, 1))
        _same(solver(C[:n], init), solve_lm(C[:n], model, hemisphere=None, initial=init))
    per_sample = ["+x", "+y", "-z"]       # three strings: one hemisphere per sample
    init = np.tile([0.2, 0.03, -0.02, 0.1, -0.2, 0.3], (3, 1))
    got = PreparedLM(model, hemisphere=per_sample)(C[:3], init)
    _same(got, solve_lm(C[:3], model, hemisphere=per_sample, initial=init))


def _raw(k, seconds=0.12):
    spec = _spec("concentric", k)
    sim = tracker_backend(spec, "sim", realtime=False, duration=seconds, chunk=96000, seed=3)
    parts = []
    while (x := sim.read()) is not None:
        parts.append(x)
    raw = np.concatenate(parts)
    return spec, sim.layout, raw


@pytest.mark.parametrize("k", [1, 4])
def test_pipeline_output_unchanged(k):
    """The default (prepared) solver against ``solve_lm`` called afresh on every chunk, on
    raw samples with a dropout (NaN) on one sensor channel: same poses, statuses and
    residuals for every sensor, the loss and the re-acquisition included."""
    spec, layout, raw = _raw(k)
    raw = raw.copy()
    raw[3000:3400, 3 * (k - 1) + 1] = np.nan     # the last sensor loses a coil for a while
    logs = []
    for plain in (False, True):
        sensors = tracker_sensors(spec)
        if plain:
            def solver(C, initial, model=sensors[0].model):
                return solve_lm(C, model, hemisphere="+x", initial=initial)

            sensors = [replace(s, solver=solver) for s in sensors]
        log = TrackLog()
        TrackingPipeline(Memory(raw, layout, 640), sensors=sensors, log=log).run()
        logs.append(log)
    lost = 0
    for j in range(k):
        a, b = logs[0].arrays(j), logs[1].arrays(j)
        for key in ("poses", "pose_vectors", "status", "residual", "distortion"):
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
        lost += int(np.count_nonzero(a["status"] != Status.CONVERGED))
    assert lost > 0 and np.all(logs[0].arrays(k - 1)["status"][-20:] == Status.CONVERGED)
