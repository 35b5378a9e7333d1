"""Option and command typos: one error line naming the misspelt word and its closest match,
after the usage line of the command it was given to; exit 2, before any work."""

from __future__ import annotations

import pytest

from openemt.cli import main


@pytest.mark.parametrize("argv, usage, message", [
    (["solve", "x.h5", "--calibraton", "cal.json", "-o", "p.h5"], "usage: openemt solve",
     "error: unrecognized option --calibraton (did you mean --calibration?)"),
    (["solve", "x.h5", "--hemisphre", "+x"], "usage: openemt solve",
     "error: unrecognized option --hemisphre (did you mean --hemisphere?)"),
    (["solve", "x.h5", "-c", "c.json", "-o", "p.h5", "--hemisphere=-x", "--max-iterz=3"],
     "usage: openemt solve", "error: unrecognized option --max-iterz (did you mean --max-iter?)"),
    (["correct", "fit", "p.csv", "--methd", "auto", "-o", "c.json"], "usage: openemt correct fit",
     "error: unrecognized option --methd (did you mean --method?)"),
    (["calibrat", "x.h5"], "usage: openemt [-h]", "(did you mean calibrate?)"),
    (["bench", "speeed"], "usage: openemt bench", "(did you mean speed?)"),
    (["info", "x.h5", "--zzzzzz"], "usage: openemt info", "error: unrecognized option --zzzzzz"),
])
def test_misspelt_option_or_command(argv, usage, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(usage), err
    last = err.strip().splitlines()[-1]
    assert last.startswith("error: ") and message in last, err
    assert list(tmp_path.iterdir()) == []


def test_valid_prefix_and_negative_values_are_not_typos(capsys, tmp_path):
    # argparse's unique prefixes and negative numbers stay valid: the error is about the file
    assert main(["solve", str(tmp_path / "x.h5"), "--calib", str(tmp_path / "c.json"),
                 "-o", str(tmp_path / "p.h5"), "--max-iter", "-3"]) == 2
    assert "missing file" in capsys.readouterr().err


def test_calibrate_without_output_says_nothing_is_written(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["simulate", "--preset", "concentric", "--reference", "robot", "--n-poses", "40",
                 "--seed", "1", "-o", "robot.h5", "--quiet"]) == 0
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["calibrate", "robot.h5", "--mode", "reference"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == ("note: the calibration was not written: no -o given (add -o CAL.json to "
                       "keep it)")
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    # bad input stays one error line, without the note
    assert main(["calibrate", "missing.h5", "--mode", "reference"]) == 2
    assert capsys.readouterr().err.count("\n") == 1
