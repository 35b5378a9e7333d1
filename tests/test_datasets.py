"""The bundled data registry: names, paths, checksums, and the CLI listing."""

import json
import shutil

import pytest

from openemt import datasets
from openemt._errors import InputError
from openemt.cli import main


def test_registry_lists_the_bundled_folder():
    assert datasets.names() == ["cal_9_15_premo_cmu"]
    folder = datasets.path("cal_9_15_premo_cmu")
    assert (folder / "output" / "XYZ_hr_cal.mat").is_file()
    assert len(sorted(folder.glob("so*_se*_*.dat"))) == 21


def test_checksums_hold():
    checks = datasets.verify("cal_9_15_premo_cmu")
    assert len(checks) == 28
    assert set(checks.values()) == {"ok"}


def test_verify_detects_a_changed_file(tmp_path, monkeypatch):
    entry = datasets.info("cal_9_15_premo_cmu")
    copy = tmp_path / entry.name
    shutil.copytree(entry.path, copy)
    shutil.copy(entry.checksum_file, tmp_path / entry.checksum_file.name)
    (copy / "README.orig").write_text("edited\n")
    (copy / "extra.txt").write_text("x\n")
    (copy / "local_cal_options.m").unlink()
    monkeypatch.setattr(datasets, "_HERE", tmp_path)
    checks = datasets.verify(entry.name)
    assert checks["README.orig"] == "changed"
    assert checks["local_cal_options.m"] == "missing"
    assert checks["extra.txt"] == "unrecorded"


def test_unknown_name_is_an_input_error():
    with pytest.raises(InputError, match="expected a bundled data set name"):
        datasets.path("nope")


def test_cli_lists_and_verifies(capsys):
    assert main(["datasets", "--verify", "--json", "--quiet"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["ok"] is True
    assert out["datasets"][0]["files_checked"] == 28
    assert main(["datasets", "nope"]) == 2
