"""docs/calibration.md#a-start-model-for-your-coils: the start model written from a drawing, as
the page shows it, is read and checked, and a reference calibration from it reaches the
simulated tracker's accuracy."""

from __future__ import annotations

import json
import re
from pathlib import Path

from openemt.cli import main

DOC = Path(__file__).resolve().parents[1] / "docs" / "calibration.md"


def test_the_start_model_of_the_page_calibrates(tmp_path, monkeypatch, capsys):
    text = DOC.read_text()
    section = text[text.index('<a id="a-start-model-for-your-coils"></a>'):]
    start = json.loads(re.search(r"```json\n(.*?)```", section, re.DOTALL).group(1))
    monkeypatch.chdir(tmp_path)
    Path("start.json").write_text(json.dumps(start))
    assert main(["info", "start.json", "--json"]) == 0
    capsys.readouterr()
    assert main(["simulate", "--preset", "concentric", "--reference", "robot", "--n-poses",
                 "80", "--snr-db", "80", "--seed", "1", "-o", "robot.h5", "--json"]) == 0
    capsys.readouterr()
    assert main(["calibrate", "robot.h5", "--mode", "reference", "--from", "start.json",
                 "--holdout", "0.2", "--seed", "0", "-o", "cal.json", "--json"]) == 0
    held = json.loads(capsys.readouterr().out)["holdout"]
    assert held["n"] == 16
    assert held["trans_rms_mm"] < 0.2 and held["rot_rms_deg"] < 0.1
