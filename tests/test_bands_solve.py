"""The carrier bands in the solver: one band stage for ``solve`` and ``track`` (fast, slow,
fuse, eddy-free), streamed block by block as in one batch, and what it does near a conductive
object and in a clean workspace."""

from __future__ import annotations

import dataclasses
import shutil
from importlib import resources

import numpy as np
import pytest

from openemt._errors import InputError
from openemt.solve import BandStage, fuse_bands, resolve_bands

#: band 0 fast (ILEMT's), band 1 slow
BANDS = [[7500.0, 10500.0, 13500.0], [274.0, 334.0, 370.0]]
#: a short stainless tube as one loop (radius 50 mm, 5 mm wire radius), 50 mm beside the
#: simulated rig's sensor volume, facing it
RING = {"object": [{"kind": "ring", "material": "stainless_steel",
                    "position": [0.101, 0.244, 0.015], "rotation": [0.0, np.pi / 2, 0.0],
                    "radius": 0.05, "wire_radius": 0.005}]}


def _random_bands(n, rng, eddy=0.02):
    C0 = rng.standard_normal((n, 3, 3))
    B = np.repeat(C0[:, None], 2, axis=1).astype(complex)
    B += eddy * (rng.standard_normal(B.shape) + 1j * rng.standard_normal(B.shape))
    return B


def test_fusion_streamed_block_by_block_equals_the_batch():
    rng = np.random.default_rng(3)
    B = _random_bands(200, rng)
    stage = BandStage("fuse", BANDS, time_constant=0.05, rate=150.0)
    whole, _ = stage(B)
    # the batch function on the concatenated stream
    np.testing.assert_allclose(whole, fuse_bands(B[:, 0].real, B[:, 1].real,
                                                 time_constant=0.05, rate=150.0),
                               rtol=0, atol=1e-12)
    parts, state, a = [], None, 0
    for size in (1, 1, 3, 8, 9, 50, 2, 126):          # live reads and long blocks
        C, state = stage(B[a:a + size], state)
        parts.append(C)
        a += size
    assert a == len(B)
    np.testing.assert_allclose(np.concatenate(parts), whole, rtol=0, atol=1e-12)
    # a fresh stream starts again on its first difference
    np.testing.assert_allclose(stage(B[50:60])[0][0], B[50, 1].real, atol=1e-12)


@pytest.mark.parametrize("tc", [0.0, 0.05])
def test_fusion_of_extreme_values_streamed_equals_the_batch(tc):
    """Differences near the largest double (a 1e300 sample beside ordinary ones): the live
    path (short blocks, a sample with a non-finite band) and the filter path compute the same
    recursion, so a stream cut into blocks gives the batch result (with ``tc = 0`` the
    low-pass is the difference itself; its old form y + (d - y) lost it)."""
    rng = np.random.default_rng(5)
    fast = rng.standard_normal((30, 2, 2))
    slow = fast + 0.01 * rng.standard_normal(fast.shape)
    slow[4, 0, 0] = 1e300
    slow[9, 1, 1] = -1e300
    slow[20, 0, 1] = np.nan
    whole = fuse_bands(fast, slow, time_constant=tc, rate=150.0)
    parts, state = [], None
    for a, b in ((0, 5), (5, 11), (11, 30)):
        out, state = fuse_bands(fast[a:b], slow[a:b], time_constant=tc, rate=150.0,
                                state=state, return_state=True)
        parts.append(out)
    streamed = np.concatenate(parts)
    assert np.isfinite(whole).all() and np.isfinite(streamed).all()
    np.testing.assert_allclose(streamed, whole, rtol=1e-12, atol=0)
    if tc == 0.0:                       # no low-pass: the slow band where its sample is finite
        good = np.isfinite(slow).all(axis=(1, 2))
        np.testing.assert_allclose(whole[good], slow[good], rtol=1e-15, atol=0)


def test_band_stage_methods():
    rng = np.random.default_rng(4)
    B = _random_bands(20, rng)
    B[:10].imag = 0                                   # no quadrature: not corrected
    slow_first = [BANDS[1], BANDS[0]]                 # the bands in any order
    np.testing.assert_array_equal(BandStage("fast", slow_first)(B[:, ::-1])[0], B[:, 0].real)
    np.testing.assert_array_equal(BandStage("slow", BANDS)(B)[0], B[:, 1].real)
    np.testing.assert_array_equal(BandStage("slow", BANDS, signed=True)(B)[0], B[:, 1])
    ef = BandStage("eddy-free", BANDS)(B)[0]
    np.testing.assert_array_equal(ef[:10], B[:10, 0].real)
    assert not np.allclose(ef[10:], B[10:, 0].real)
    assert BandStage("fuse", BANDS, rate=1.0).quadrature_band == 1
    assert BandStage("eddy-free", BANDS).quadrature_band == 0
    with pytest.raises(InputError, match="band couplings"):
        BandStage("slow", BANDS)(B[:, :1])
    with pytest.raises(InputError, match="sample rate"):
        BandStage("fuse", BANDS)


def test_resolve_bands():
    assert resolve_bands("auto", 2, ordered=True, rate=150.0) == "fuse"
    assert resolve_bands("auto", 2, ordered=False, rate=None) is None
    assert resolve_bands("auto", 1, ordered=True, rate=150.0) is None
    assert resolve_bands("fast", 1, ordered=False) is None
    assert resolve_bands("eddy-free", 2, ordered=False) == "eddy-free"
    with pytest.raises(InputError, match=r"two or more carrier bands for slow \(--bands\)"):
        resolve_bands("slow", 1, ordered=True, rate=1.0)
    with pytest.raises(InputError, match="time order"):
        resolve_bands("fuse", 2, ordered=False, rate=1.0)
    with pytest.raises(InputError, match=r"band method \(--bands\) in auto"):
        resolve_bands("mean", 2, ordered=True)


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    """The simulated rig's stage pattern near the stainless ring and without it (two
    bands), each also as a recording at 50 samples/s, and the truth calibration."""
    from openemt.io import recording_meta, write_calibration, write_dataset
    from openemt.simulate import simulate, truth_calibration

    d = tmp_path_factory.mktemp("bands")
    kw = dict(source_fixtures="YoutZup", sensor_fixtures="YoutZup", stage_sigma=0,
              bands=BANDS)
    for name, metal in (("ring", RING), ("clean", None)):
        data = simulate("dipole-approx", "md", metal=metal, **kw)
        write_dataset(data, d / f"{name}.h5")
        rec = dataclasses.replace(data, meta={**data.meta,
                                              "recording": recording_meta(50.0, "test")})
        write_dataset(rec, d / f"{name}-rec.h5")
    write_calibration(truth_calibration("dipole-approx"), d / "cal.json")
    return d, data.poses


def _solve(rig, name, bands, **kw):
    from openemt.evaluate import pose_error_magnitudes
    from openemt.solve import SolveFileOptions, read_poses, solve_file

    d, truth = rig
    out = d / f"{name}-{bands}-{len(kw)}.h5"
    res = solve_file(SolveFileOptions(dataset=d / f"{name}.h5", calibration=d / "cal.json",
                                      output=out, bands=bands, max_relative_residual=0.5,
                                      **kw))
    poses = read_poses(out)
    assert poses.valid.all()
    t, _ = pose_error_magnitudes(poses.poses, truth)
    return res, poses, float(np.sqrt(np.mean(t ** 2)))


def test_solve_with_bands_near_a_conductive_ring(rig):
    res, _, fast = _solve(rig, "ring", "auto")        # not a recording: band 0 as it is
    assert res.bands is None and "bands" not in res.to_dict()
    for method in ("slow", "eddy-free"):
        res, _, err = _solve(rig, "ring", method)
        assert res.to_dict()["bands"] == method
        assert err < fast / 10, (method, err, fast)
    with pytest.raises(InputError, match="time order"):
        _solve(rig, "ring", "fuse")


def test_solve_with_bands_in_a_clean_workspace(rig):
    _, base, fast = _solve(rig, "clean", "fast")
    _, same, _ = _solve(rig, "clean", "eddy-free")    # no quadrature: nothing corrected
    np.testing.assert_array_equal(same.poses, base.poses)
    _, _, slow = _solve(rig, "clean", "slow")
    assert slow < fast + 1e-5, (slow, fast)           # the same poses within 10 um


def test_solve_fuses_a_recording_block_by_block(rig):
    from openemt.solve import BandReader

    res, _, _ = _solve(rig, "ring-rec", "auto")
    assert res.bands == "fuse"
    # every row solved on its own (no warm start across blocks): the poses follow the
    # fused couplings alone, whatever the blocks (to the LM's stopping tolerance)
    _, whole, _ = _solve(rig, "ring-rec", "fuse", initial="kim18")
    _, blocks, _ = _solve(rig, "ring-rec", "fuse", initial="kim18", chunk_rows=7)
    np.testing.assert_allclose(blocks.poses, whole.poses, rtol=0, atol=1e-8)
    d, _ = rig
    stage = BandStage("fuse", BANDS, rate=50.0, signed=True)
    one = BandReader(d / "ring-rec.h5", stage, 10_000)[0:142]
    seven = BandReader(d / "ring-rec.h5", stage, 7)
    np.testing.assert_allclose(np.concatenate([seven[a:a + 7] for a in range(0, 142, 7)]),
                               one, rtol=0, atol=1e-12)
    np.testing.assert_allclose(seven[10:30], one[10:30], rtol=0, atol=1e-12)  # off the grid


def _tracker(tmp_path, metal: str | None, bands: str | None = None):
    """The shipped simulated tracker driven at two bands (slow band 275 / 325 / 375 Hz, whole
    cycles of the 50 Hz output's frames, clear of the simulated mains harmonics)."""
    folder = resources.files("openemt.live") / "trackers"
    text = (folder / "simulated.toml").read_text()
    text = text.replace("frequencies = [7500.0, 10500.0, 13500.0]",
                        "frequencies = [[7500.0, 275.0], [10500.0, 325.0], [13500.0, 375.0]]")
    text = text.replace("output_rate = 1500.0", "output_rate = 50.0")
    if metal is not None:
        text = text.replace('preset = "concentric"', f'preset = "concentric"\nmetal = "{metal}"')
    if bands is not None:
        text += f'\n[solve]\nbands = "{bands}"\n'
    shutil.copy(folder / "concentric.json", tmp_path / "concentric.json")
    (tmp_path / "ring.toml").write_text(
        # a stainless ring (short tube) 90 mm beside the simulated sensor's path
        '[[object]]\nkind = "ring"\nmaterial = "stainless_steel"\n'
        'position = [0.2, 0.09, 0.0]\nrotation = [1.5707963, 0.0, 0.0]\n'
        'radius = 0.04\nwire_radius = 0.004\n')
    (tmp_path / "t.toml").write_text(text)
    return tmp_path / "t.toml"


def _track(path, bands=None):
    from openemt.live import TrackingSession, TrackOptions

    o = TrackOptions(tracker=path, duration=0.7, fast=True, igtl_port=0, bands=bands,
                     quiet=True)
    with TrackingSession.from_tracker(path, o) as session:
        return session.run().to_dict()


def test_track_sim_with_bands_near_a_conductive_ring(tmp_path):
    from openemt.live import read_tracker

    path = _tracker(tmp_path, "ring.toml", bands="eddy-free")
    assert read_tracker(path).solve_bands == "eddy-free"
    runs = {b: _track(path, b) for b in ("fast", "auto", "eddy-free")}
    assert runs["auto"]["bands"] == {"method": "fuse", "time_constant_s": 0.1,
                                     "frequencies_hz": [[7500.0, 10500.0, 13500.0],
                                                        [275.0, 325.0, 375.0]]}
    err = {b: r["truth"]["position_error_mm_rms"] for b, r in runs.items()}
    assert err["auto"] < err["fast"] / 3, err          # auto: fusion
    assert err["eddy-free"] < err["fast"] / 10, err
    clean = _tracker(tmp_path, None)
    got = {b: _track(clean, b)["truth"]["position_error_mm_rms"] for b in ("fast", "auto")}
    # without metal: the same poses within the slow band's noise (0.1 mm)
    assert got["auto"] < got["fast"] + 0.1, got


def test_tracker_file_solve_section(tmp_path):
    from openemt.live import read_tracker

    path = _tracker(tmp_path, None)
    assert read_tracker(path).solve_bands == "auto"
    text = path.read_text()
    path.write_text(text + '\n[solve]\nbands = "mean"\n')
    with pytest.raises(InputError, match="solve.bands"):
        read_tracker(path)
    one = (resources.files("openemt.live") / "trackers" / "simulated.toml").read_text()
    path.write_text(one + '\n[solve]\nbands = "fuse"\n')
    with pytest.raises(InputError, match="carriers of one band"):
        read_tracker(path)


def test_cole_cole_extrapolation_recovers_a_broadened_relaxation():
    """C_b = C0 + k (i w tau)^a / (1 + (i w tau)^a), k per entry, tau and a per sample (on
    the estimator's grid): C0 comes back; a = 1 is the single relaxation."""
    from openemt.solve import cole_cole_couplings

    rng = np.random.default_rng(5)
    n = 6
    C0 = rng.standard_normal((n, 3, 3))
    k = 0.3 * rng.standard_normal((n, 3, 3))
    tau = np.array([1e-5, 1e-4, 1e-3, 1e-4, 1e-2, 1e-3])[:, None, None]
    a = np.array([0.5, 0.6, 1.0, 0.8, 0.7, 0.35])[:, None, None]
    f = np.array(BANDS)
    B = np.stack([C0 + k * (1j * 2 * np.pi * f[b][None, :, None] * tau) ** a
                  / (1 + (1j * 2 * np.pi * f[b][None, :, None] * tau) ** a)
                  for b in range(2)], axis=1)
    out, t, alpha = cole_cole_couplings(B, f, return_params=True)
    np.testing.assert_allclose(out, C0, atol=1e-8)
    np.testing.assert_allclose(t, tau[:, 0, 0], rtol=1e-9)
    np.testing.assert_allclose(alpha, a[:, 0, 0], atol=1e-12)


def test_solve_cli_bands_errors(rig, tmp_path, capsys):
    """``openemt solve --bands``: a choice the dataset cannot serve is one error line, exit
    2, no output file; --json names the bands used."""
    import json

    from openemt.cli import main
    from openemt.io import write_dataset
    from openemt.simulate import simulate

    d, _ = rig
    one = tmp_path / "one.h5"
    write_dataset(simulate("dipole-approx", "md", source_fixtures="YoutZup",
                           sensor_fixtures="YoutZup", stage_sigma=0), one)
    out = tmp_path / "p.h5"
    for data, bands, what in ((one, "slow", "two or more carrier bands"),
                              (d / "ring.h5", "fuse", "time order")):
        assert main(["solve", str(data), "-c", str(d / "cal.json"), "-o", str(out),
                     "--bands", bands, "--quiet"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: ") and what in err[0], err
        assert not out.exists()
    assert main(["solve", str(d / "ring.h5"), "-c", str(d / "cal.json"), "-o", str(out),
                 "--bands", "eddy-free", "--max-relative-residual", "0.5", "--json",
                 "--quiet"]) == 0
    assert json.loads(capsys.readouterr().out)["bands"] == "eddy-free"


def test_live_fusion_state_per_sensor_equals_the_batch(tmp_path):
    """The pipeline fuses read by read (0 or 1 outputs per read here), its state kept per
    sensor: what the solver is given equals the batch fusion of the demodulated stream."""
    from openemt.live import (
        PipelineConfig,
        SensorSetup,
        TrackingPipeline,
        lm_solver,
        read_tracker,
        tracker_backend,
    )
    from openemt.signal import demodulate
    from openemt.simulate import get_preset

    spec = read_tracker(_tracker(tmp_path, "ring.toml"))
    model = get_preset("concentric").dipole
    inner = lm_solver(model)
    seen = []

    def solver(C, initial, **kw):
        seen.append(np.array(C))
        return inner(C, initial, **kw)

    backend = tracker_backend(spec, "sim", realtime=False, duration=0.5, chunk=1000)
    pipe = TrackingPipeline(backend, SensorSetup(name="s", solver=solver),
                            PipelineConfig(output_rate=spec.output_rate, bands="fuse"))
    while pipe.step() is not None:
        pass
    again = tracker_backend(spec, "sim", realtime=False, duration=0.5, chunk=1000)
    raw = []
    while (c := again.read()) is not None:
        raw.append(c)
    d = demodulate(np.concatenate(raw), spec.layout(), output_rate=spec.output_rate)
    batch, _ = BandStage("fuse", spec.layout().band_frequencies, rate=spec.output_rate)(d.bands)
    got = np.concatenate(seen)
    assert len(got) == len(batch) > 10
    np.testing.assert_allclose(got, batch, rtol=0, atol=1e-12 * np.abs(batch).max())


def test_a_bad_sample_does_not_end_the_fusion():
    """A sample whose band difference is not finite keeps the low-pass state: the samples
    after it fuse as if it had not come (the live stream goes on); it gets its fast band
    plus the last low-passed difference (NaN where its fast band is not finite)."""
    rng = np.random.default_rng(6)
    B = _random_bands(30, rng)
    bad = B.copy()
    bad[10, 1, 0, 0] = np.nan
    bad[20, 0, 2, 1] = np.inf
    stage = BandStage("fuse", BANDS, time_constant=0.05, rate=150.0)
    out, _ = stage(bad)
    ok = np.isfinite(out).all(axis=(1, 2))
    assert ok.sum() == 29 and not ok[20]
    skip = np.delete(B, [10, 20], axis=0)
    fused = stage(skip)[0]
    np.testing.assert_allclose(np.delete(out, [10, 20], axis=0), fused, atol=1e-12)
    np.testing.assert_allclose(out[10], B[10, 0].real + fused[9] - skip[9, 0].real,
                               atol=1e-12)


def test_track_refuses_the_sheet_band_method(tmp_path):
    """``sheet`` is a per-sample fit (tens of milliseconds a sample): ``solve``'s, on a
    dataset; a live stream is refused it in one line before it starts."""
    from openemt.cli import main
    from openemt.live import read_tracker

    path = _tracker(tmp_path, None)
    with pytest.raises(InputError, match="got sheet"):
        _track(path, "sheet")
    with pytest.raises(InputError, match="solve.bands"):
        read_tracker(_tracker(tmp_path, None, bands="sheet"))
    assert main(["track", str(path), "--bands", "sheet", "--duration", "0.1"]) == 2
