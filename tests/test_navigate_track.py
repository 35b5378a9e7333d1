"""The tracker file's ``tip`` key: a sensor's stream shows its tool tip (``pose @ tip`` of a
pivot calibration), scored against the tip of the simulated truth."""

import json
import shutil

import numpy as np
import pytest

from openemt._errors import InputError
from openemt.live import TrackingPipeline, TrackLog, example_tracker, read_tracker
from openemt.live._session import tracker_backend, tracker_sensors
from openemt.navigate import TOOL_FORMAT


def _tracker(tmp_path, tip_line):
    src = example_tracker("simulated-2")
    shutil.copy(src.parent / "concentric.json", tmp_path / "concentric.json")
    text = src.read_text().replace('name = "Probe"\n', f'name = "Probe"\n{tip_line}\n', 1)
    (tmp_path / "t.toml").write_text(text)
    return tmp_path / "t.toml"


def test_tip_key_streams_the_tool_tip(tmp_path):
    T = np.eye(4)
    T[:3, 3] = [0.0, 0.01, 0.15]
    (tmp_path / "tip.json").write_text(json.dumps(
        {"format": TOOL_FORMAT, "version": 1, "kind": "pivot", "tip_transform": T.tolist(),
         "tip_mm": (1e3 * T[:3, 3]).tolist()}))
    with_tip = read_tracker(_tracker(tmp_path, 'tip = "tip.json"'))
    np.testing.assert_array_equal(with_tip.sensors[0].tip, T)
    assert with_tip.sensors[1].tip is None
    plain = read_tracker(example_tracker("simulated-2"))
    logs, summaries = [], []
    for spec in (plain, with_tip):
        log = TrackLog()
        p = TrackingPipeline(tracker_backend(spec, "sim", realtime=False, duration=0.05),
                             sensors=tracker_sensors(spec), log=log)
        p.run()
        logs.append(log)
        summaries.append(p.summary().to_dict())
    a, b = logs[0].arrays("Probe"), logs[1].arrays("Probe")
    ok = a["status"] == 0
    assert ok.sum() > 50
    np.testing.assert_allclose(b["poses"][ok], a["poses"][ok] @ T, atol=1e-12)
    np.testing.assert_array_equal(logs[0].arrays("Reference")["poses"],
                                  logs[1].arrays("Reference")["poses"])
    # scored against the truth's tip: the error stays the sensor's (rotation noise x 150 mm)
    err = [s["sensors"]["Probe"]["truth"]["position_error_mm_rms"] for s in summaries]
    assert err[1] < 0.05 and err[0] < 0.05


def test_tip_key_refusals(tmp_path):
    with pytest.raises(InputError, match=r"sensors\[0\]\.tip.*missing"):
        read_tracker(_tracker(tmp_path, 'tip = "nowhere.json"'))
    (tmp_path / "other.json").write_text(json.dumps({"format": "openemt.registration"}))
    with pytest.raises(InputError, match="pivot calibration"):
        read_tracker(_tracker(tmp_path, 'tip = "other.json"'))
