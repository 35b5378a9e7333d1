"""Tracker description files (valid and invalid), the sound-card backend through a stand-in
``sounddevice`` module, and ``openemt track --tracker`` / ``openemt devices``."""

from __future__ import annotations

import json
import shutil
import sys
import threading
import tomllib
import types

import numpy as np
import pytest
from _counts import converged_only

from openemt._errors import InputError
from openemt.live import (
    SimulatedBackend,
    TrackingPipeline,
    TrackLog,
    example_tracker,
    read_tracker,
)
from openemt.live._session import tracker_backend, tracker_sensors

GOOD = example_tracker("simulated-2").read_text()


@pytest.fixture
def tracker_dir(tmp_path):
    shutil.copy(example_tracker("simulated").parent / "concentric.json", tmp_path)
    return tmp_path


def _write(folder, text, name="t.toml"):
    p = folder / name
    p.write_text(text)
    return p


def test_shipped_tracker_files_are_valid():
    one = read_tracker(example_tracker("simulated"))
    two = read_tracker(example_tracker("simulated-2"))
    assert one.sensor_names == ("Sensor",) and one.sample_rate == 96000.0
    assert two.sensor_names == ("Probe", "Reference")
    assert [s.device_name for s in two.sensors] == ["ProbeToTracker", "ReferenceToTracker"]
    assert two.layout().sensor_channels == (0, 1, 2, 3, 4, 5)
    assert two.layout().reference_channels == (6, 7, 8)
    assert two.sensor_columns() == [(0, 1, 2), (3, 4, 5)]
    assert all(s.calibration.is_file() for s in two.sensors)     # resolved beside the file
    assert [c.model.n_sensor for c in two.calibrations()] == [3, 3]


def test_relative_calibration_path_and_values(tracker_dir):
    p = _write(tracker_dir, GOOD.replace("sample_rate = 96000.0", "sample_rate = 96000"))
    spec = read_tracker(p)
    assert spec.sample_rate == 96000.0 and spec.path == p
    assert spec.sensors[0].calibration == tracker_dir / "concentric.json"
    assert spec.sensors[1].simulation_offset == (0.03, 0.0, 0.05)


@pytest.mark.parametrize("edit, match", [
    # missing key
    (lambda s: s.replace("sample_rate = 96000.0\n", ""), r"`adc.sample_rate`.*missing"),
    (lambda s: s.replace('reference_channels = [6, 7, 8]\n', ""),
     r"`source.reference_channels`.*missing"),
    (lambda s: s.replace('name = "Probe"\n', ""), r"`sensors\[0\].name`.*missing"),
    # wrong type
    (lambda s: s.replace("channels = 9", 'channels = "nine"'),
     r"`adc.channels` to be an integer, got str 'nine'"),
    (lambda s: s.replace("channels = [0, 1, 2]", "channels = [0, 1.5, 2]"),
     r"`sensors\[0\].channels` to be a list of integers, got an item float 1.5"),
    (lambda s: s.replace('window = "hann"', "window = 3"), r"`demodulation.window`"),
    # channel used twice
    (lambda s: s.replace("channels = [3, 4, 5]", "channels = [3, 4, 2]"),
     r"each ADC channel used once, got channel 2 already used by sensor 'Probe'"),
    (lambda s: s.replace("channels = [3, 4, 5]", "channels = [3, 4, 6]"),
     r"channel 6 already used by source.reference_channels"),
    (lambda s: s.replace("channels = [3, 4, 5]", "channels = [3, 4, 9]"),
     r"channels in 0..8 \(adc.channels = 9\), got 9"),
    # unknown sensor key / unknown keys / duplicate names
    (lambda s: s.replace('name = "Reference"', 'name = "Probe"'),
     r"`sensors\[1\].name` to be a unique non-empty sensor name, got 'Probe'"),
    (lambda s: s.replace('device_name = "ReferenceToTracker"', 'devce_name = "X"'),
     r"unknown key `sensors\[1\].devce_name`"),
    (lambda s: s + "\n[sensor]\nname = 'X'\n", r"unknown key `sensor`"),
    (lambda s: s.replace('device_name = "ProbeToTracker"', 'device_name = "ReferenceToTracker"'),
     r"a device name no other sensor uses"),
    (lambda s: s.replace('device_name = "ProbeToTracker"',
                         'device_name = "ThisNameIsFarTooLongForIGTL"'),
     r"device name of 1-20 characters"),
    # calibration file missing
    (lambda s: s.replace('calibration = "concentric.json"\n\n[[sensors]]',
                         'calibration = "nowhere.json"\n\n[[sensors]]'),
     r"`sensors\[0\].calibration` to be an existing calibration file.*nowhere.json"),
    # sample rate <= 0
    (lambda s: s.replace("sample_rate = 96000.0", "sample_rate = 0.0"),
     r"`adc.sample_rate` to be a positive number \(Hz\), got 0.0"),
    (lambda s: s.replace("sample_rate = 96000.0", "sample_rate = -96000.0"),
     r"`adc.sample_rate` to be a positive number"),
    # carrier above Nyquist
    (lambda s: s.replace("13500.0]", "50000.0]"),
     r"`source.frequencies` to be carriers in \(0, 48000\) Hz.*got 50000.0"),
    # carrier plan the demodulator cannot use
    (lambda s: s.replace("13500.0]", "13600.0]"), r"demodulator accepts"),
    (lambda s: s.replace('kind = "none"', 'kind = "median"'), r"`filter.kind`"),
    # unknown sensor named in the per-sensor filter settings
    (lambda s: s + '\n[filter.sensors.Probe]\nkind = "kalman"\n[filter.sensors.Needle]\n'
                   'kind = "kalman"\n',
     (r"`filter.sensors.Needle` to be the name of a sensor in \['Probe', 'Reference'\], "
      r"got unknown sensor 'Needle'")),
    (lambda s: s + '\n[filter.sensors.Probe]\nprocess_noise = -1.0\n',
     r"`filter.sensors.Probe.process_noise` in \[1e-09, 10000\] m/s\^2/sqrt\(Hz\), got -1.0"),
    # finite but far beyond any tracker: the filter's covariances would overflow
    (lambda s: s.replace("[filter]", "[filter]\nprocess_noise = 1e308"),
     r"`filter.process_noise` in \[1e-09, 10000\].*got 1e\+308"),
    (lambda s: s.replace("[filter]", "[filter]\nmeasurement_noise = 1e-300"),
     r"`filter.measurement_noise` in \[1e-12, 1\] m, got 1e-300"),
    (lambda s: s.replace("[igtl]", "[igtl]\nrate = inf"), r"`igtl.rate`.*stream rate"),
    (lambda s: s.replace("seed = 0", "seed = 0\nnoise_rms = inf"),
     r"`simulation.noise_rms` to be a finite non-negative number, got inf"),
    (lambda s: s.replace("seed = 0", "seed = 0\nmains_amplitudes = [0.01, nan]"),
     r"`simulation.mains_amplitudes` to be finite numbers"),
    (lambda s: s.replace('window = "hann"', 'window = "hann"\ndistortion_threshold = inf'),
     r"`demodulation.distortion_threshold` to be a positive finite number, got inf"),
    (lambda s: s.replace("simulation_offset = [0.03, 0.0, 0.05]",
                         "simulation_offset = [0.03, 0.0, inf]"),
     r"`sensors\[1\]\.simulation_offset` to be 3 finite numbers"),
    (lambda s: s.replace("[igtl]", "[igtl]\nrate = 0"), r"`igtl.rate`.*stream rate"),
    (lambda s: s.replace("[igtl]", "[igtl]\nheader_version = 3"),
     r"`igtl.header_version`.*'auto', 1 or 2, got 3"),
    (lambda s: s + '\n[navigation]\nregistration = "nowhere.json"\n',
     r"`navigation.registration`.*missing"),
    # a sensor name too long for its default device <name>ToTracker
    (lambda s: s.replace('name = "Probe"\ndevice_name = "ProbeToTracker"',
                         'name = "AVeryLongProbe"'),
     r"`sensors\[0\]\.name`.*1-20 characters.*'AVeryLongProbeToTracker'"),
    (lambda s: s.replace('format = "openemt-tracker"', 'format = "other"'), r"`format`"),
    (lambda s: s.replace("[adc]", "[adc\n"), r"valid TOML"),
])
def test_invalid_tracker_files(tracker_dir, edit, match):
    p = _write(tracker_dir, edit(GOOD))
    with pytest.raises(ValueError, match=match) as info:
        read_tracker(p)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(str(p))      # one line naming the file


def test_missing_tracker_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="tracker description"):
        read_tracker(tmp_path / "nope.toml")


def test_calibration_with_wrong_coil_count(tracker_dir):
    p = _write(tracker_dir, GOOD.replace("channels = [3, 4, 5]", "channels = [3, 4]"))
    spec = read_tracker(p)
    with pytest.raises(ValueError, match="one channel per coil of its calibration"):
        spec.calibrations()


def test_per_sensor_filter_settings(tracker_dir):
    p = _write(tracker_dir, GOOD + '\n[filter.sensors.Reference]\nkind = "kalman"\n'
                                   'process_noise = 0.001\n')
    spec = read_tracker(p)
    probe, ref = tracker_sensors(spec)
    assert probe.filter.kind == "none"
    assert ref.filter.kind == "kalman" and ref.filter.process_noise == 0.001
    # command-line settings apply to every sensor
    probe, ref = tracker_sensors(spec.with_filter(kind="kalman", measurement_noise=5e-6))
    assert probe.filter.kind == ref.filter.kind == "kalman"
    assert probe.filter.measurement_noise == ref.filter.measurement_noise == 5e-6
    assert ref.filter.process_noise == 0.001


def test_filter_settings_from_file_and_overrides(tracker_dir):
    p = _write(tracker_dir, GOOD.replace('kind = "none"',
                                         'kind = "kalman"\nprocess_noise = 0.5'))
    spec = read_tracker(p)
    assert spec.filter.kind == "kalman" and spec.filter.process_noise == 0.5
    spec2 = spec.with_filter(kind=None, measurement_noise=1e-5)
    assert spec2.filter.kind == "kalman" and spec2.filter.measurement_noise == 1e-5
    with pytest.raises(ValueError, match="filter.process_noise"):
        spec.with_filter(process_noise=-1.0)


# ------------------------------------------------------------------ sound card stand-in

def _fake_sounddevice(raw_source, streams):
    """A stand-in ``sounddevice``: its InputStream delivers ``raw_source.read()`` blocks
    through the callback from its own thread, as PortAudio's audio thread would."""

    class InputStream:
        def __init__(self, samplerate, channels, dtype, blocksize, device, callback):
            self.samplerate, self.channels, self.device = samplerate, channels, device
            self.callback, self.blocksize = callback, blocksize
            self._stop = threading.Event()
            self._thread = threading.Thread(target=self._run, daemon=True)
            self.closed = False
            streams.append(self)

        def _run(self):
            while not self._stop.is_set():
                x = raw_source.read()
                if x is None:
                    break
                block = np.zeros((len(x), self.channels), np.float32)
                block[:, :x.shape[1]] = x
                self.callback(block, len(x), None, None)

        def start(self):
            self._thread.start()

        def stop(self):
            self._stop.set()
            self._thread.join(timeout=5.0)

        def close(self):
            self.closed = True

    devices = [{"name": "Built-in Output", "index": 0, "hostapi": 0, "max_input_channels": 0,
                "default_samplerate": 48000.0},
               {"name": "8-in USB interface", "index": 1, "hostapi": 0,
                "max_input_channels": 10, "default_samplerate": 96000.0}]
    return types.SimpleNamespace(InputStream=InputStream,
                                 query_devices=lambda: devices,
                                 query_hostapis=lambda: [{"name": "ALSA"}])


def test_sound_backend_tracks_two_sensors_from_the_tracker_file(monkeypatch):
    spec = read_tracker(example_tracker("simulated-2"))
    sim = tracker_backend(spec, "sim", realtime=False, duration=0.2, chunk=1024)
    streams = []
    monkeypatch.setitem(sys.modules, "sounddevice", _fake_sounddevice(sim, streams))
    backend = tracker_backend(spec, "sound", device=1)
    assert streams[0].channels == 9 and streams[0].samplerate == 96000.0
    assert streams[0].device == 1
    log = TrackLog()
    try:
        # the sound card's read timeout is not the end of the data: stop at 0.19 s
        s = TrackingPipeline(backend, sensors=tracker_sensors(spec), log=log).run(
            0.19, max_steps=60)
    finally:
        backend.close()
    assert streams[0].closed
    assert s.n_samples >= 250                   # 0.2 s at 1500/s, minus the first frame
    assert s.status_counts == converged_only(2 * s.n_samples)
    for k, name in enumerate(spec.sensor_names):
        a = log.arrays(name)
        truth = sim.truth_poses(a["times"])[:, k]
        err = np.linalg.norm(a["poses"][:, :3, 3] - truth[:, :3, 3], axis=1)
        assert np.sqrt(np.mean(err ** 2)) < 50e-6


def test_cli_track_sound_with_stand_in_device(cli, capsys, monkeypatch, tmp_path):
    spec = read_tracker(example_tracker("simulated"))
    sim = SimulatedBackend(duration=0.3, chunk=960, config=None)
    streams = []
    monkeypatch.setitem(sys.modules, "sounddevice", _fake_sounddevice(sim, streams))
    code = cli(["track", "--tracker", str(example_tracker("simulated")), "--source", "sound",
                "--device", "1", "--no-igtl", "--json", "--quiet", "--duration", "0.2",
                "--log", str(tmp_path / "log.h5")])
    d = json.loads(capsys.readouterr().out)
    assert code == 0 and streams[0].device == 1 and streams[0].channels == spec.n_channels
    assert d["source"] == "sound" and d["n_samples"] > 150
    assert d["status_counts"] == converged_only(d["n_samples"])
    assert d["audio_blocks_dropped"] == 0


def test_cli_sound_and_devices_without_sounddevice(cli, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "sounddevice", None)
    code = cli(["track", "--tracker", str(example_tracker("simulated")), "--source", "sound",
                "--no-igtl"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "pip install sounddevice" in err[0]
    # devices lists serial and network sources too: without sounddevice it says why sound
    # cards are not listed instead of failing
    assert cli(["devices", "--json"]) == 0
    cap = capsys.readouterr()
    d = json.loads(cap.out)
    assert d["sound"]["available"] is False and d["n_devices"] == 0
    assert "pip install sounddevice" in d["sound"]["reason"]
    assert "pip install sounddevice" in cap.err
    # sound needs the wiring of a tracker file
    assert cli(["track", "--source", "sound", "--no-igtl"]) == 2
    assert "--tracker" in capsys.readouterr().err


def test_cli_devices_lists_inputs(cli, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "sounddevice", _fake_sounddevice(None, []))
    assert cli(["devices", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["n_devices"] == 1
    assert d["devices"][0] == {"index": 1, "name": "8-in USB interface",
                               "max_input_channels": 10, "default_samplerate": 96000.0,
                               "hostapi": "ALSA"}


def test_cli_track_two_sensor_tracker_sim_log_and_replay(cli, capsys, tmp_path):
    tracker = example_tracker("simulated-2")
    code = cli(["track", "--tracker", str(tracker), "--duration", "0.1", "--fast", "--no-igtl",
                "--log", str(tmp_path / "log.csv"), "--save-raw", str(tmp_path / "raw.h5"),
                "--json", "--quiet"])
    d = json.loads(capsys.readouterr().out)
    assert code == 0 and d["n_samples"] == 149
    assert d["sensors_tracked"] == ["Probe", "Reference"]
    assert d["status_counts"] == converged_only(2 * 149)
    for name in ("Probe", "Reference"):
        assert d["sensors"][name]["truth"]["position_error_mm_rms"] < 0.05
    rows = (tmp_path / "log.csv").read_text().splitlines()
    assert rows[0].startswith("time_s,sensor,x_m")
    assert [r.split(",")[1] for r in rows[1:5]] == ["Probe", "Reference"] * 2
    assert len(rows) == 1 + 2 * 149
    code = cli(["track", "--tracker", str(tracker), "--source", "replay",
                str(tmp_path / "raw.h5"), "--fast", "--no-igtl", "--json", "--quiet",
                "--log", str(tmp_path / "log.h5")])
    d2 = json.loads(capsys.readouterr().out)
    assert code == 0 and d2["n_samples"] == 149
    assert d2["sensors"]["Reference"]["truth"]["position_error_mm_rms"] < 0.05
    import h5py

    with h5py.File(tmp_path / "log.h5") as f:
        assert f.attrs["version"] == 2 and list(f.attrs["sensors"]) == ["Probe", "Reference"]
        assert f["sensors/Reference/poses"].shape == (149, 4, 4)
    # a recording of another layout is refused
    code = cli(["track", "--tracker", str(example_tracker("simulated")), "--source", "replay",
                str(tmp_path / "raw.h5"), "--fast", "--no-igtl"])
    assert code == 2 and "channel layout" in capsys.readouterr().err


def test_cli_tracker_conflicting_options(cli, capsys):
    code = cli(["track", "--tracker", str(example_tracker("simulated")), "--preset",
                "concentric", "--no-igtl"])
    assert code == 2 and "--preset" in capsys.readouterr().err


def test_example_tracker_is_toml_with_documented_sections():
    doc = tomllib.loads(example_tracker("simulated").read_text())
    assert set(doc) == {"format", "version", "adc", "source", "demodulation", "sensors",
                        "filter", "simulation"}


def test_cli_replay_without_tracker_uses_the_recordings_layout(cli, capsys, tmp_path):
    from openemt.live import default_model, default_trajectory
    from openemt.signal import ChannelLayout, RawSignalConfig, simulate_raw, write_raw

    lay = ChannelLayout(sensor_channels=(5, 3, 4), reference_channels=(0, 2, 1))
    raw = simulate_raw(default_model(), default_trajectory, 0.05, RawSignalConfig(layout=lay),
                       seed=1)
    write_raw(raw, tmp_path / "swapped.h5")
    code = cli(["track", "--source", "replay", str(tmp_path / "swapped.h5"), "--fast",
                "--no-igtl", "--json", "--quiet"])
    d = json.loads(capsys.readouterr().out)
    assert code == 0 and d["status_counts"] == converged_only(d["n_samples"])
    assert d["truth"]["position_error_mm_rms"] < 0.05


def test_igtl_metadata_key(tracker_dir):
    assert read_tracker(_write(tracker_dir, GOOD)).metadata is True
    off = GOOD.replace("[igtl]", "[igtl]\nmetadata = false")
    assert read_tracker(_write(tracker_dir, off)).metadata is False
    with pytest.raises(InputError, match=r"`igtl.metadata` to be true or false, got str .no."):
        read_tracker(_write(tracker_dir, GOOD.replace("[igtl]", '[igtl]\nmetadata = "no"')))
