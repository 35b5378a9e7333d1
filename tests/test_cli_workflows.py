"""The commands are their library workflows: the workflow called from Python gives what the
command prints with --json and writes the same files."""

import json

import h5py
import numpy as np

from openemt.cli import main
from openemt.datasets import DatasetsOptions, check_datasets
from openemt.io import ImportOptions, import_files, read_dataset
from openemt.simulate import SimulateOptions, write_simulation


def _json(capsys, argv):
    assert main(argv + ["--json", "--quiet"]) == 0
    return json.loads(capsys.readouterr().out)


def test_simulate_workflow_is_the_command(tmp_path, capsys):
    res = write_simulation(SimulateOptions(output=tmp_path / "a.h5", pattern="sd", seed=3,
                                           snr_db=60.0, truth_calibration=tmp_path / "a.json"))
    cli = _json(capsys, ["simulate", "-o", str(tmp_path / "b.h5"), "--pattern", "sd", "--seed",
                         "3", "--snr-db", "60", "--truth-calibration", str(tmp_path / "b.json")])
    got = res.to_dict()
    assert {k: v for k, v in got.items() if k not in ("path", "truth_calibration")} == \
        {k: v for k, v in cli.items() if k not in ("path", "truth_calibration")}
    assert got["n_samples"] == 86 * 6 and res.lines()[0].startswith("simulated 516 samples")
    a, b = read_dataset(tmp_path / "a.h5"), read_dataset(tmp_path / "b.h5")
    assert np.array_equal(a.couplings, b.couplings) and np.array_equal(a.poses, b.poses)


def test_ndi_session_imports_through_the_workflow(tmp_path, capsys):
    sim = write_simulation(SimulateOptions(output=tmp_path / "s.tsv", format="ndi",
                                           reference="optical", n_poses=12, seed=2))
    assert sim.to_dict()["tools"] and "truth_calibration" not in sim.to_dict()
    res = import_files(ImportOptions(format="ndi", files=(str(tmp_path / "s.tsv"),),
                                     output=str(tmp_path / "em.h5"), tool="10"))
    cli = _json(capsys, ["import", "ndi", str(tmp_path / "s.tsv"), "-o",
                         str(tmp_path / "em2.h5"), "--tool", "10"])
    assert res.to_dict()["n_samples"] == cli["n_samples"] == 12
    with h5py.File(tmp_path / "em.h5") as f, h5py.File(tmp_path / "em2.h5") as g:
        assert np.array_equal(f["poses"][()], g["poses"][()])
    assert res.lines()[0] == f"imported 12 poses from 1 files -> {tmp_path / 'em.h5'}"


def test_datasets_workflow_flags_a_problem_with_exit_status_1(tmp_path, monkeypatch, capsys):
    import openemt.datasets as ds

    ok = check_datasets(DatasetsOptions(verify=True))
    assert ok.ok and ok.exit_status == 0
    monkeypatch.setattr(ds, "verify", lambda name: {"a.dat": "changed"})
    bad = check_datasets(DatasetsOptions(verify=True))
    assert not bad.ok and bad.exit_status == 1 and "PROBLEMS" in bad.lines()[-1]
    assert main(["datasets", "--verify", "--quiet"]) == 1
